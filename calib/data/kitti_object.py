"""KITTI object layout: ``calib/*.txt``, ``image_2/*.png``, ``velodyne/*.bin`` (optionally under
``training/`` or ``testing/``), one calibration file per frame (frames come from different drives).

Transform (KITTI devkit ``readme.txt``): ``x = P2 · R0_rect · Tr_velo_to_cam · X``. So
``T_cam2_lidar = T_cam2_rect0 · R0_rect · Tr_velo_to_cam`` with ``T_cam2_rect0`` the offset in
``P2`` and ``K = P2[:, :3]``. Frames are indexed, not timed: 10 Hz is assumed (noted).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.data.io import IMAGE_SUFFIXES, SCAN_SUFFIXES, kv_matrix, read_kv_file
from calib.data.types import (
    Calibration,
    FileSequence,
    assumed_timestamps,
    choose_kitti_camera,
    list_files,
    pair_by_stem,
    shift_from_projection,
)
from calib.errors import DataError

__all__ = ["is_kitti_object", "read_kitti_object", "read_kitti_object_calib"]


def _root(path: Path) -> Path | None:
    for candidate in (path, path / "training", path / "testing"):
        if (candidate / "calib").is_dir() and (candidate / "velodyne").is_dir():
            return candidate
    return None


def is_kitti_object(path: Path) -> bool:
    return _root(path) is not None


def read_kitti_object_calib(path: Path, camera: int = 2) -> Calibration:
    """One ``calib/NNNNNN.txt`` -> :class:`Calibration` of camera ``camera``."""
    values = read_kv_file(path)
    K, T_camX_rect0 = shift_from_projection(kv_matrix(values, f"P{camera}", (3, 4), path), path, f"P{camera}")
    R0 = np.eye(4)
    R0[:3, :3] = kv_matrix(values, "R0_rect", (3, 3), path)
    Tr = np.eye(4)
    Tr[:3, :] = kv_matrix(values, "Tr_velo_to_cam", (3, 4), path)
    return Calibration(K=K, T_cam_lidar=T_camX_rect0 @ R0 @ Tr, source=str(path))


def cameras(root: Path) -> list[int]:
    """Indices of the ``image_N`` folders of a split."""
    names = (p.name.removeprefix("image_") for p in root.glob("image_*") if p.is_dir())
    return sorted(int(n) for n in names if n.isdigit())


def read_kitti_object(path: Path, camera: int | str | None = None) -> FileSequence:
    """Read a KITTI object split (see the module docstring for the transform).

    Args:
        camera: index of the ``image_N`` folder (``None``: 2, or the only camera present).
    """
    root = _root(Path(path))
    if root is None:
        raise DataError(path, "not a KITTI object layout (no calib/ and velodyne/)")
    notes: list[str] = []
    camera = choose_kitti_camera(cameras(root), camera, root, notes, lambda c: f"image_{c}")
    image_dir, scan_dir = root / f"image_{camera}", root / "velodyne"
    if not image_dir.is_dir():
        raise DataError(image_dir, "folder not found")
    images, scans, problems = pair_by_stem(
        list_files(image_dir, IMAGE_SUFFIXES), list_files(scan_dir, SCAN_SUFFIXES), image_dir, scan_dir
    )
    calibrations = [read_kitti_object_calib(root / "calib" / f"{p.stem}.txt", camera) for p in images]
    if not calibrations:
        raise DataError(root, "no frames with both an image and a scan")
    times = assumed_timestamps(len(images), notes, "KITTI object frames")
    distinct = {c.T_cam_lidar.tobytes() for c in calibrations}
    if len(distinct) > 1:
        notes.append(f"{len(distinct)} different calibrations across frames (one per drive)")
    return FileSequence(
        name=root.name,
        layout="kitti_object",
        image_paths=images,
        scan_paths=scans,
        calibration=calibrations[0],
        calibrations=calibrations,
        timestamps=times,
        notes=notes,
        problems=problems,
        camera=str(camera),
    )
