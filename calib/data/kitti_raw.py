"""KITTI raw layout: a drive folder with ``image_0X/data/*.png``, ``velodyne_points/data/*.bin``,
optional ``timestamps.txt`` in each, and the date's ``calib_cam_to_cam.txt`` and
``calib_velo_to_cam.txt`` (in the drive folder, its ``calibration/`` subfolder, or the date folder
above it). A date folder holding ``*_sync`` drives is accepted too; ``sequence`` picks the drive.

Transform: ``calib_velo_to_cam.txt`` gives ``[R | T]`` = LiDAR -> unrectified camera 0;
``R_rect_00`` rectifies camera 0; ``P_rect_0X`` maps the rectified camera-0 frame into image X.
So ``T_camX_lidar = T_camX_rect0 · R_rect_00 · [R | T]`` with ``T_camX_rect0`` the offset in
``P_rect_0X`` and ``K = P_rect_0X[:, :3]``. Camera 2 (left colour) by default; where only one
camera folder exists (e.g. a grayscale ``image_00`` only) that camera is used and a note says so;
``camera`` (``--camera``) picks another of ``image_00..03``.
Without ``timestamps.txt`` frames are assumed at 10 Hz (noted).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.data.io import IMAGE_SUFFIXES, SCAN_SUFFIXES, kv_matrix, read_kv_file
from calib.data.types import (
    Calibration,
    FileSequence,
    choose_kitti_camera,
    list_files,
    pair_by_stem,
    paired_timestamps,
    shift_from_projection,
)
from calib.errors import DataError

__all__ = ["is_kitti_raw", "read_kitti_raw", "read_kitti_raw_timestamps"]


def _is_drive(path: Path) -> bool:
    return (path / "velodyne_points").is_dir()


def is_kitti_raw(path: Path) -> bool:
    return _is_drive(path) or any(_is_drive(p) for p in path.glob("*_sync"))


def _drive_matches(drive: Path, sequence: str) -> bool:
    return drive.name == sequence or f"_drive_{sequence}_" in drive.name


def _resolve_drive(path: Path, sequence: str | None) -> Path:
    if _is_drive(path):
        if sequence is not None and not _drive_matches(path, sequence):
            raise DataError(path, f"is drive {path.name}, not {sequence!r}; leave out --sequence")
        return path
    drives = sorted(p for p in path.glob("*_sync") if _is_drive(p))
    if sequence is not None:
        chosen = [d for d in drives if _drive_matches(d, sequence)]
        if len(chosen) != 1:
            raise DataError(path, f"no drive {sequence!r} (have: {', '.join(d.name for d in drives)})")
        return chosen[0]
    if len(drives) != 1:
        raise DataError(path, f"holds drives {', '.join(d.name for d in drives)}; pick one with --sequence")
    return drives[0]


def _find_calib(drive: Path, name: str) -> Path:
    for folder in (drive, drive / "calibration", drive.parent):
        if (folder / name).is_file():
            return folder / name
    raise DataError(drive, f"no {name} in the drive folder, its calibration/ or its parent")


def read_kitti_raw_timestamps(path: Path) -> np.ndarray:
    """``timestamps.txt`` lines ``YYYY-MM-DD hh:mm:ss.fffffffff`` -> seconds since the epoch."""
    lines = [ln.strip() for ln in path.read_text().splitlines() if ln.strip()]
    try:
        stamps = np.array([np.datetime64(ln.replace(" ", "T"), "ns") for ln in lines])
    except ValueError as exc:
        raise DataError(path, f"time stamps do not parse ({exc})") from None
    seconds = stamps.astype(np.int64).astype(np.float64) * 1e-9
    seconds[np.isnat(stamps)] = np.nan  # reported by the reader as a problem
    return seconds


def cameras(drive: Path) -> list[int]:
    """Indices of the ``image_0N/data`` folders of a drive."""
    names = (p.name.removeprefix("image_") for p in drive.glob("image_*") if (p / "data").is_dir())
    return sorted(int(n) for n in names if n.isdigit())


def read_kitti_raw(path: Path, sequence: str | None = None, camera: int | str | None = None) -> FileSequence:
    """Read one KITTI raw drive (see the module docstring for the transform).

    Args:
        camera: index of the ``image_0N`` folder (``None``: 2, the left colour camera, or the only
            camera present, noted); one that is absent is refused with the list of those present.
    """
    drive = _resolve_drive(Path(path), sequence)
    notes: list[str] = []
    camera = choose_kitti_camera(cameras(drive), camera, drive, notes, lambda c: f"image_{c:02d}")
    cam_path = _find_calib(drive, "calib_cam_to_cam.txt")
    velo_path = _find_calib(drive, "calib_velo_to_cam.txt")
    cam_values, velo_values = read_kv_file(cam_path), read_kv_file(velo_path)
    key = f"P_rect_{camera:02d}"
    K, T_camX_rect0 = shift_from_projection(kv_matrix(cam_values, key, (3, 4), cam_path), cam_path, key)
    R_rect = np.eye(4)
    R_rect[:3, :3] = kv_matrix(cam_values, "R_rect_00", (3, 3), cam_path)
    T_cam0_lidar = np.eye(4)
    T_cam0_lidar[:3, :3] = kv_matrix(velo_values, "R", (3, 3), velo_path)
    T_cam0_lidar[:3, 3] = kv_matrix(velo_values, "T", (3, 1), velo_path)[:, 0]
    size = cam_values.get(f"S_rect_{camera:02d}")
    image_size = (int(size[1]), int(size[0])) if isinstance(size, np.ndarray) and size.size == 2 else None
    calibration = Calibration(
        K=K,
        T_cam_lidar=T_camX_rect0 @ R_rect @ T_cam0_lidar,
        image_size=image_size,
        source=f"{cam_path}, {velo_path}",
    )
    image_dir = drive / f"image_{camera:02d}" / "data"
    scan_dir = drive / "velodyne_points" / "data"
    if not scan_dir.is_dir():
        raise DataError(scan_dir, "folder not found")
    all_images = list_files(image_dir, IMAGE_SUFFIXES)
    images, scans, problems = pair_by_stem(
        all_images, list_files(scan_dir, SCAN_SUFFIXES), image_dir, scan_dir
    )
    times = paired_timestamps(
        image_dir.parent / "timestamps.txt", all_images, images, notes, read_kitti_raw_timestamps, problems
    )
    return FileSequence(
        name=drive.name,
        layout="kitti_raw",
        image_paths=images,
        scan_paths=scans,
        calibration=calibration,
        timestamps=times,
        notes=notes,
        problems=problems,
        camera=f"{camera:02d}",
    )
