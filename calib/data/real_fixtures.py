"""The real fixtures in ``../shared/realdata`` turned into layouts the readers support.

The data stay where they are (their licence forbids copying them into the project); these
helpers write small converted copies into a folder the caller owns (a temporary one).
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from calib.data import Frame, open_dataset
from calib.data.io import format_kv_line, read_kv_file, read_pcd_fields, scanline_order, write_bin
from calib.data.nuscenes import TABLES

__all__ = [
    "AMZ_DRIVE",
    "AMZ_DRIVE_MORE",
    "NUSCENES_CAMERAS",
    "PJLAB_SCENES",
    "CheckFixture",
    "check_fixtures",
    "custom_from_nuscenes",
    "custom_from_pjlab",
    "custom_from_pjlab_scanlines",
    "kitti_object_from_cvml",
    "kitti_object_from_mmdet",
    "nuscenes_from_mmdet",
    "real_scenes",
    "realdata_root",
]

AMZ_DRIVE = "amz_kitti_raw_0928/data/0928-KITTI-dataset"
AMZ_DRIVE_MORE = "amz_kitti_raw_0928_more/data/0928-KITTI-dataset"
CVML_KITTI = "cvml_kitti_object_000114/projections/lidar_camera_projection/data"
NUSCENES = "mmdet3d_demo/demo/data/nuscenes"
NUSCENES_CAMERAS = (
    "CAM_FRONT",
    "CAM_FRONT_RIGHT",
    "CAM_BACK_RIGHT",
    "CAM_BACK",
    "CAM_BACK_LEFT",
    "CAM_FRONT_LEFT",
)
MMDET_KITTI = "mmdet3d_demo/demo/data/kitti"
PJLAB = "sensorscalib_pjlab/lidar2camera/auto_calib_v2.0/data/ours"
PJLAB_SCENES = ("1", "2", "3")


def realdata_root() -> Path | None:
    """``$SUPPORTNET_REALDATA``, else the first ``../shared/realdata`` above the working
    directory or this package; ``None`` when absent."""
    if env := os.environ.get("SUPPORTNET_REALDATA"):
        return Path(env) if Path(env).is_dir() else None
    for start in (Path.cwd(), Path(__file__).resolve().parent):
        for folder in (start, *start.parents):
            candidate = folder.parent / "shared" / "realdata"
            if candidate.is_dir():
                return candidate
    return None


def kitti_object_from_mmdet(realdata: Path, out: Path) -> Path:
    """Write mmdet3d's KITTI frame 000008 as a KITTI object split (``calib/000008.txt`` with
    ``P2``, ``R0_rect``, ``Tr_velo_to_cam`` from its pickle). Returns the split folder."""
    src = Path(realdata) / MMDET_KITTI
    with open(src / "000008.pkl", "rb") as handle:
        info = pickle.load(handle)["data_list"][0]
    out = Path(out)
    for sub in ("calib", "image_2", "velodyne"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    cams = info["images"]
    text = "".join(format_kv_line(f"P{i}", np.array(cams[f"CAM{i}"]["cam2img"])[:3]) for i in range(4))
    text += format_kv_line("R0_rect", np.array(cams["R0_rect"])[:3, :3])
    text += format_kv_line("Tr_velo_to_cam", np.array(info["lidar_points"]["Tr_velo_to_cam"])[:3])
    (out / "calib" / "000008.txt").write_text(text)
    shutil.copyfile(src / "000008.png", out / "image_2" / "000008.png")
    shutil.copyfile(src / "000008.bin", out / "velodyne" / "000008.bin")
    return out


def custom_from_pjlab(realdata: Path, scene: str, out: Path) -> Path:
    """Write one PJLab scene (distorted 1920x1200 image, binary-compressed PCD, ``calib.txt``
    with K, D and LiDAR->camera T) as a custom folder. Returns the folder."""
    src = Path(realdata) / PJLAB / scene
    values = read_kv_file(src / "calib.txt")
    T = np.eye(4)
    T[:3, :] = np.asarray(values["T"]).reshape(3, 4)
    out = Path(out)
    (out / "camera").mkdir(parents=True, exist_ok=True)
    (out / "lidar").mkdir(exist_ok=True)
    image = next(p for p in src.iterdir() if p.suffix in (".png", ".jpg"))
    shutil.copyfile(image, out / "camera" / f"000000{image.suffix}")
    shutil.copyfile(src / "calib.pcd", out / "lidar" / "000000.pcd")
    spec = {
        "K": np.asarray(values["K"]).reshape(3, 3).tolist(),
        "distortion": np.asarray(values["D"]).tolist(),
        "T_cam_lidar": T.tolist(),
    }
    (out / "calibration.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
    return out


def real_scenes(realdata: Path, workdir: Path) -> list[tuple[str, Frame, np.ndarray | None]]:
    """Every real fixture frame as ``(name, frame, ring or None)``, read through the readers."""
    scenes = []
    with open_dataset(realdata / AMZ_DRIVE) as seq:
        scenes += [(f"kitti-raw {f.name}", f, None) for f in seq]
    with open_dataset(kitti_object_from_mmdet(realdata, workdir / "kitti_object")) as seq:
        scenes += [(f"kitti-object {f.name}", f, None) for f in seq]
    for scene in PJLAB_SCENES:
        with open_dataset(custom_from_pjlab(realdata, scene, workdir / f"pjlab{scene}")) as seq:
            ring = read_pcd_fields(seq.scan_paths[0])[0]["ring"].astype(np.int64)
            scenes.append((f"pjlab {scene}", seq[0], ring))
    return scenes


def kitti_object_from_cvml(realdata: Path, out: Path) -> Path:
    """Link cvml's KITTI object frame 000114 (full scan, colour camera 2, KITTI object file
    formats under other names) into a KITTI object split. Returns the split folder."""
    src = Path(realdata) / CVML_KITTI
    out = Path(out)
    names = {
        "calib/000114.txt": "000114_calib.txt",
        "image_2/000114.png": "000114_image.png",
        "velodyne/000114.bin": "000114.bin",
    }
    for target, source in names.items():
        (out / target).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src / source, out / target)
    return out


def custom_from_nuscenes(realdata: Path, camera: str, out: Path) -> Path:
    """Write one camera of the mmdet3d nuScenes sample as a custom folder: its 1600x900 JPEG, the
    LIDAR_TOP scan (``x, y, z, intensity`` of the five stored columns, put in scan-line order by
    the fifth, the ring) and ``calibration.yaml`` with the pickle's ``cam2img`` as ``K``.

    ``T_cam_lidar`` is the pickle's ``lidar2cam``, as the nuScenes devkit projects: the rig's
    static calibration ``cam2ego⁻¹ · lidar2ego`` with the ego motion between the sweep's stamp and
    the camera's folded in (0.5 to 43 ms, up to 40 cm here), the sweep being motion-compensated
    to its stamp. Returns the folder."""
    src = Path(realdata) / NUSCENES
    if camera not in NUSCENES_CAMERAS:
        raise ValueError(f"unknown nuScenes camera {camera!r}; one of {', '.join(NUSCENES_CAMERAS)}")
    pickle_path = next(src.glob("*.pkl"))
    with open(pickle_path, "rb") as handle:
        info = pickle.load(handle)["data_list"][0]
    cam = info["images"][camera]
    scan = np.fromfile(src / Path(info["lidar_points"]["lidar_path"]).name, np.float32).reshape(-1, 5)
    scan = scan[scanline_order(scan[:, :3], scan[:, 4].astype(np.int64))]
    out = Path(out)
    (out / "camera").mkdir(parents=True, exist_ok=True)
    (out / "lidar").mkdir(exist_ok=True)
    shutil.copyfile(src / Path(cam["img_path"]).name, out / "camera" / "000000.jpg")
    write_bin(out / "lidar" / "000000.bin", scan[:, :4])
    spec = {
        "K": np.asarray(cam["cam2img"], np.float64)[:3, :3].tolist(),
        "T_cam_lidar": np.asarray(cam["lidar2cam"], np.float64).tolist(),
    }
    (out / "calibration.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
    return out


def nuscenes_from_mmdet(realdata: Path, out: Path) -> Path:
    """Write the mmdet3d nuScenes sample in the devkit's layout (``v1.0-mini/`` tables, one scene
    of one sample, and ``samples/``), as the nuScenes reader takes it. The pickle holds each
    sensor's ``cam2ego`` / ``lidar2ego``, the car's pose at the sweep's stamp and each camera's
    ``lidar2cam`` with the car's motion up to its exposure folded in; the car's pose at each
    camera's time is what makes that chain (``T_world_ego(t_cam) = T_world_ego(t_lidar) ·
    T_ego_lidar · lidar2cam⁻¹ · cam2ego⁻¹``), so the devkit's projection of the written tables is
    the pickle's. Returns the data root."""
    from scipy.spatial.transform import Rotation

    src = Path(realdata) / NUSCENES
    with open(next(src.glob("*.pkl")), "rb") as handle:
        info = pickle.load(handle)["data_list"][0]
    out = Path(out)
    tables: dict[str, list[dict]] = {name: [] for name in TABLES}

    def record(T: np.ndarray, **fields: object) -> dict:
        x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
        return {**fields, "translation": T[:3, 3].tolist(), "rotation": [w, x, y, z]}

    sample = "sample0"
    tables["scene"].append(
        {
            "token": "scene0",
            "name": "scene-mmdet3d",
            "nbr_samples": 1,
            "first_sample_token": sample,
            "last_sample_token": sample,
        }
    )
    tables["sample"].append(
        {
            "token": sample,
            "timestamp": round(info["timestamp"] * 1e6),
            "prev": "",
            "next": "",
            "scene_token": "scene0",
        }
    )
    T_world_ego = np.asarray(info["ego2global"], np.float64)
    T_ego_lidar = np.asarray(info["lidar_points"]["lidar2ego"], np.float64)
    sensors = [
        (
            "LIDAR_TOP",
            "lidar",
            info["lidar_points"]["lidar_path"],
            info["timestamp"],
            T_ego_lidar,
            None,
            T_world_ego,
        )
    ]
    for camera in NUSCENES_CAMERAS:
        cam = info["images"][camera]
        T_ego_cam = np.asarray(cam["cam2ego"], np.float64)
        lidar2cam = np.asarray(cam["lidar2cam"], np.float64)
        T_world_ego_cam = T_world_ego @ T_ego_lidar @ np.linalg.inv(lidar2cam) @ np.linalg.inv(T_ego_cam)
        intrinsic = np.asarray(cam["cam2img"], np.float64)[:3, :3].tolist()
        sensors.append(
            (camera, "camera", cam["img_path"], cam["timestamp"], T_ego_cam, intrinsic, T_world_ego_cam)
        )
    for channel, modality, file, stamp, T_ego_sensor, intrinsic, T_world in sensors:
        tables["sensor"].append({"token": f"sensor_{channel}", "channel": channel, "modality": modality})
        tables["calibrated_sensor"].append(
            record(
                T_ego_sensor,
                token=f"calib_{channel}",
                sensor_token=f"sensor_{channel}",
                camera_intrinsic=intrinsic or [],
            )
        )
        stamp_us = round(stamp * 1e6)
        tables["ego_pose"].append(record(T_world, token=f"ego_{channel}", timestamp=stamp_us))
        filename = f"samples/{channel}/{Path(file).name}"
        (out / filename).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src / Path(file).name, out / filename)
        tables["sample_data"].append(
            {
                "token": f"data_{channel}",
                "sample_token": sample,
                "ego_pose_token": f"ego_{channel}",
                "calibrated_sensor_token": f"calib_{channel}",
                "timestamp": stamp_us,
                "fileformat": "pcd" if modality == "lidar" else "jpg",
                "is_key_frame": True,
                "height": 0 if modality == "lidar" else 900,
                "width": 0 if modality == "lidar" else 1600,
                "filename": filename,
                "prev": "",
                "next": "",
            }
        )
    (out / "v1.0-mini").mkdir(parents=True, exist_ok=True)
    for name, records in tables.items():
        (out / "v1.0-mini" / f"{name}.json").write_text(json.dumps(records, indent=1))
    return out


def custom_from_pjlab_scanlines(realdata: Path, scene: str, out: Path) -> Path:
    """:func:`custom_from_pjlab` with the scan written as ``.bin`` in scan-line order (by its
    ``ring`` field; the PCD is stored in firing order), for methods that read neighbours along
    scan lines from the stored order. Per-point times are dropped."""
    out = custom_from_pjlab(realdata, scene, out)
    pcd = out / "lidar" / "000000.pcd"
    fields = read_pcd_fields(pcd)[0]
    points = np.column_stack([fields[k] for k in ("x", "y", "z", "intensity")]).astype(np.float32)
    points = points[scanline_order(points[:, :3], fields["ring"].astype(np.int64))]
    write_bin(out / "lidar" / "000000.bin", points[np.isfinite(points).all(1)])
    pcd.unlink()
    return out


@dataclass(frozen=True)
class CheckFixture:
    """One real dataset as ``open_dataset`` takes it: ``path``, with ``camera`` (or ``None``)."""

    name: str
    path: Path
    camera: str | None = None


def check_fixtures(realdata: Path, workdir: Path) -> list[CheckFixture]:
    """Every real fixture with a reference extrinsic, one dataset each, converted where needed
    into ``workdir``: the two KITTI raw 2011_09_28 folders (grey camera 0), KITTI object 000008
    (cropped scan) and 000114 (full scan), the six nuScenes cameras (through the nuScenes reader:
    each camera's points at its exposure, the static extrinsic) and the three PJLab scenes (scans
    in scan-line order)."""
    realdata, workdir = Path(realdata), Path(workdir)
    fixtures = [
        CheckFixture("kitti-raw-0928", realdata / AMZ_DRIVE, "0"),
        CheckFixture("kitti-raw-0928-more", realdata / AMZ_DRIVE_MORE, "0"),
        CheckFixture("kitti-object-000008", kitti_object_from_mmdet(realdata, workdir / "kitti_000008")),
        CheckFixture("kitti-object-000114", kitti_object_from_cvml(realdata, workdir / "kitti_000114")),
    ]
    nuscenes = nuscenes_from_mmdet(realdata, workdir / "nuscenes")
    for camera in NUSCENES_CAMERAS:
        fixtures.append(CheckFixture(f"nuscenes-{camera.lower().replace('_', '-')}", nuscenes, camera))
    for scene in PJLAB_SCENES:
        folder = custom_from_pjlab_scanlines(realdata, scene, workdir / f"pjlab_{scene}")
        fixtures.append(CheckFixture(f"pjlab-{scene}", folder))
    return fixtures
