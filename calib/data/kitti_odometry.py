"""KITTI odometry layout: ``sequences/NN/{image_2, velodyne, labels, image_labels}``, ``calib.txt``,
``times.txt``, ``poses/NN.txt`` (reader and writer; the synthetic worlds write this layout).

Transform: ``calib.txt`` holds ``Tr`` (LiDAR -> rectified camera 0, already ``T_cam0_lidar``) and
``P0..P3`` (rectified camera 0 -> image X). For camera X (colour camera 2 by default)
``T_camX_lidar = T_camX_rect0 · Tr`` with ``T_camX_rect0`` the offset in ``PX``
(:func:`~calib.data.types.shift_from_projection`), and ``K = PX[:, :3]``. ``poses/NN.txt`` are
camera-0 poses in the first camera-0 frame; they are returned as LiDAR poses,
``T_w_lidar(t) = Tr⁻¹ · T_w_cam0(t) · Tr``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.data.io import (
    IMAGE_SUFFIXES,
    SCAN_SUFFIXES,
    atomic_write_text,
    format_kv_line,
    kv_matrix,
    read_kv_file,
    write_bin,
    write_image,
    write_label,
)
from calib.data.types import (
    Calibration,
    FileSequence,
    Frame,
    list_files,
    optional_paths,
    pair_by_stem,
    paired_timestamps,
    shift_from_projection,
)
from calib.errors import DataError

__all__ = ["is_kitti_odometry", "read_kitti_odometry", "write_kitti_odometry", "sequence_names"]


def is_kitti_odometry(path: Path) -> bool:
    return (path / "sequences").is_dir() or ((path / "calib.txt").is_file() and (path / "velodyne").is_dir())


def sequence_names(root: Path) -> list[str]:
    return sorted(p.name for p in (root / "sequences").iterdir() if p.is_dir())


def _resolve(path: Path, sequence: str | None) -> tuple[Path, Path, str]:
    """(dataset root, sequence folder, sequence name) for a root or a ``sequences/NN`` folder."""
    if (path / "sequences").is_dir():
        names = sequence_names(path)
        if sequence is None:
            if len(names) != 1:
                raise DataError(
                    path, f"holds sequences {', '.join(names) or 'none'}; pick one with --sequence"
                )
            sequence = names[0]
        if sequence not in names:
            raise DataError(path / "sequences" / sequence, f"no such sequence (have: {', '.join(names)})")
        return path, path / "sequences" / sequence, sequence
    return path.parent.parent, path, path.name


def _read_poses(path: Path, n: int, Tr: np.ndarray) -> np.ndarray:
    try:
        rows = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise DataError(path, f"poses do not parse ({exc})") from None
    if rows.shape != (n, 12):
        raise DataError(path, f"expected {n} rows of 12 numbers, got shape {rows.shape}")
    T_w_cam0 = np.tile(np.eye(4), (n, 1, 1))
    T_w_cam0[:, :3, :] = rows.reshape(n, 3, 4)
    return np.linalg.inv(Tr) @ T_w_cam0 @ Tr


def read_kitti_odometry(path: Path, sequence: str | None = None, camera: int = 2) -> FileSequence:
    """Read one KITTI odometry sequence (see the module docstring for the transform)."""
    root, seq_dir, name = _resolve(Path(path), sequence)
    calib_path = seq_dir / "calib.txt"
    values = read_kv_file(calib_path)
    K, T_camX_cam0 = shift_from_projection(kv_matrix(values, f"P{camera}", (3, 4), calib_path))
    Tr = np.eye(4)
    Tr[:3, :] = kv_matrix(values, "Tr", (3, 4), calib_path)
    image_dir, scan_dir = seq_dir / f"image_{camera}", seq_dir / "velodyne"
    for folder in (image_dir, scan_dir):
        if not folder.is_dir():
            raise DataError(folder, "folder not found")
    all_images = list_files(image_dir, IMAGE_SUFFIXES)
    images, scans, problems = pair_by_stem(
        all_images, list_files(scan_dir, SCAN_SUFFIXES), image_dir, scan_dir
    )
    stems = [p.stem for p in images]
    notes: list[str] = []
    times = paired_timestamps(seq_dir / "times.txt", all_images, images, notes)
    poses_path = root / "poses" / f"{name}.txt"
    poses = _read_poses(poses_path, len(all_images), Tr) if poses_path.is_file() and not problems else None
    calibration = Calibration(K=K, T_cam_lidar=T_camX_cam0 @ Tr, source=str(calib_path))
    return FileSequence(
        name=f"{root.name}/{name}",
        layout="kitti_odometry",
        image_paths=images,
        scan_paths=scans,
        calibration=calibration,
        timestamps=times,
        notes=notes,
        problems=problems,
        label_paths=optional_paths(seq_dir / "labels", stems, ".label"),
        image_label_paths=optional_paths(seq_dir / "image_labels", stems, ".png"),
        poses=poses,
    )


def write_kitti_odometry(
    root: Path,
    sequence: str,
    frames: list[Frame],
    poses_lidar: np.ndarray | None = None,
) -> Path:
    """Write frames as ``root/sequences/<sequence>`` of the KITTI odometry layout.

    Every camera ``P0..P3`` is written as ``K [I | 0]`` and ``Tr`` as the frames' reference
    ``T_cam_lidar``, so reading camera 2 returns exactly the calibration given.

    Args:
        frames: frames sharing one calibration with a reference extrinsic, and time stamps.
        poses_lidar: optional ``(len, 4, 4)`` LiDAR poses, stored as camera-0 poses.

    Returns:
        The sequence folder.
    """
    if not frames:
        raise ValueError("no frames to write")
    calibration = frames[0].calibration
    if calibration.T_cam_lidar is None:
        raise ValueError("the KITTI odometry layout needs a reference T_cam_lidar")
    seq_dir = Path(root) / "sequences" / sequence
    for sub in ("image_2", "velodyne"):
        (seq_dir / sub).mkdir(parents=True, exist_ok=True)
    P = np.hstack([calibration.K, np.zeros((3, 1))])
    calib_text = "".join(format_kv_line(f"P{i}", P) for i in range(4))
    calib_text += format_kv_line("Tr", calibration.T_cam_lidar[:3, :])
    atomic_write_text(seq_dir / "calib.txt", calib_text)
    for i, frame in enumerate(frames):
        stem = f"{i:06d}"
        write_image(seq_dir / "image_2" / f"{stem}.png", frame.image)
        write_bin(seq_dir / "velodyne" / f"{stem}.bin", frame.points)
        if frame.labels is not None:
            (seq_dir / "labels").mkdir(exist_ok=True)
            write_label(seq_dir / "labels" / f"{stem}.label", frame.labels)
        if frame.image_labels is not None:
            (seq_dir / "image_labels").mkdir(exist_ok=True)
            write_image(seq_dir / "image_labels" / f"{stem}.png", frame.image_labels.astype(np.uint16))
    times = [f.timestamp if f.timestamp is not None else i / 10.0 for i, f in enumerate(frames)]
    atomic_write_text(seq_dir / "times.txt", "".join(f"{t:.6e}\n" for t in times))
    if poses_lidar is not None:
        Tr = calibration.T_cam_lidar
        T_w_cam0 = Tr @ np.asarray(poses_lidar) @ np.linalg.inv(Tr)
        (Path(root) / "poses").mkdir(parents=True, exist_ok=True)
        rows = "".join(" ".join(f"{v:.12e}" for v in T[:3, :].reshape(-1)) + "\n" for T in T_w_cam0)
        atomic_write_text(Path(root) / "poses" / f"{sequence}.txt", rows)
    return seq_dir
