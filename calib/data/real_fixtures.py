"""The real fixtures in ``../shared/realdata`` turned into layouts the readers support.

The data stay where they are (their licence forbids copying them into the project); these
helpers write small converted copies into a folder the caller owns (a temporary one).
"""

from __future__ import annotations

import os
import pickle
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from calib.data import Frame, open_dataset
from calib.data.io import format_kv_line, read_kv_file, read_pcd_fields, write_bin

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
    "real_scenes",
    "realdata_root",
    "scanline_order",
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


def scanline_order(points_lidar: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """``(N,)`` indices putting a scan stored in firing order (every laser of a column, then the
    next column: nuScenes, PJLab) into scan-line order (ring by ring, each by azimuth), the order
    KITTI's Velodyne scans are stored in and :func:`calib.features.depth_discontinuities` reads
    neighbours from when it gets no ring."""
    xyz = np.asarray(points_lidar, np.float64)
    return np.lexsort((np.arctan2(xyz[:, 1], xyz[:, 0]), np.asarray(ring)))


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
    (cropped scan) and 000114 (full scan), the six nuScenes cameras and the three PJLab scenes
    (scans in scan-line order)."""
    realdata, workdir = Path(realdata), Path(workdir)
    fixtures = [
        CheckFixture("kitti-raw-0928", realdata / AMZ_DRIVE, "0"),
        CheckFixture("kitti-raw-0928-more", realdata / AMZ_DRIVE_MORE, "0"),
        CheckFixture("kitti-object-000008", kitti_object_from_mmdet(realdata, workdir / "kitti_000008")),
        CheckFixture("kitti-object-000114", kitti_object_from_cvml(realdata, workdir / "kitti_000114")),
    ]
    for camera in NUSCENES_CAMERAS:
        folder = custom_from_nuscenes(realdata, camera, workdir / f"nuscenes_{camera.lower()}")
        fixtures.append(CheckFixture(f"nuscenes-{camera.lower().replace('_', '-')}", folder))
    for scene in PJLAB_SCENES:
        folder = custom_from_pjlab_scanlines(realdata, scene, workdir / f"pjlab_{scene}")
        fixtures.append(CheckFixture(f"pjlab-{scene}", folder))
    return fixtures
