"""The real fixtures in ``../shared/realdata`` turned into layouts the readers support.

The data stay where they are (their licence forbids copying them into the project); these
helpers write small converted copies into a folder the caller owns (a temporary one).
"""

from __future__ import annotations

import os
import pickle
import shutil
from pathlib import Path

import numpy as np
import yaml

from calib.data import Frame, open_dataset
from calib.data.io import format_kv_line, read_kv_file, read_pcd_fields

__all__ = [
    "AMZ_DRIVE",
    "PJLAB_SCENES",
    "custom_from_pjlab",
    "kitti_object_from_mmdet",
    "real_scenes",
    "realdata_root",
]

AMZ_DRIVE = "amz_kitti_raw_0928/data/0928-KITTI-dataset"
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
