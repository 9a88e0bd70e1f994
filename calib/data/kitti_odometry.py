"""KITTI odometry layout: ``sequences/NN/{image_2, velodyne, labels, image_labels}``, ``calib.txt``,
``times.txt``, ``poses/NN.txt`` (reader and writer; the synthetic worlds write this layout), and
optionally ``times_lidar.txt``: scan stamps where they differ from the camera's (a supportnet
extension the synthetic worlds write; Stage 1's time sync reads it).

Transform: ``calib.txt`` holds ``Tr`` (LiDAR -> rectified camera 0, already ``T_cam0_lidar``) and
``P0..P3`` (rectified camera 0 -> image X). For camera X (colour camera 2 by default)
``T_camX_lidar = T_camX_rect0 · Tr`` with ``T_camX_rect0`` the offset in ``PX``
(:func:`~calib.data.types.shift_from_projection`), and ``K = PX[:, :3]``. ``poses/NN.txt`` are
camera-0 poses in the first camera-0 frame; they are returned as LiDAR poses,
``T_w_lidar(t) = Tr⁻¹ · T_w_cam0(t) · Tr``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calib.data.extrinsic_file import rigid_problem
from calib.data.io import (
    IMAGE_SUFFIXES,
    SCAN_SUFFIXES,
    atomic_write_text,
    format_kv_line,
    format_row,
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
    choose_kitti_camera,
    list_files,
    optional_paths,
    pair_by_stem,
    paired_timestamps,
    shift_from_projection,
    time_problems,
)
from calib.errors import DataError

__all__ = [
    "KittiOdometryWriter",
    "is_kitti_odometry",
    "read_kitti_odometry",
    "sequence_names",
    "write_kitti_odometry",
]


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
    if sequence is not None and sequence != path.name:
        raise DataError(
            path, f"is sequence {path.name}, not {sequence!r}; leave out --sequence or give the root"
        )
    return path.parent.parent, path, path.name


def _read_poses(path: Path, n: int, Tr: np.ndarray, problems: list[str]) -> np.ndarray | None:
    """LiDAR poses from ``poses/NN.txt``; NaN or non-rigid poses are added to ``problems`` (and
    ``None`` returned) so ``info`` lists them and the other commands refuse the sequence."""
    try:
        rows = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise DataError(path, f"poses do not parse ({exc})") from None
    if rows.shape != (n, 12):
        raise DataError(path, f"expected {n} rows of 12 numbers, got shape {rows.shape}")
    T_w_cam0 = np.tile(np.eye(4), (n, 1, 1))
    T_w_cam0[:, :3, :] = rows.reshape(n, 3, 4)
    bad = np.flatnonzero(~np.isfinite(rows).all(axis=1))
    if bad.size:
        first = bad[0] + 1
        problems.append(f"{path}: {bad.size} pose(s) hold NaN or infinite values (first on line {first})")
        return None
    for i, T in enumerate(T_w_cam0):
        problem = rigid_problem(T)
        if problem is not None:
            problems.append(f"{path}: pose on line {i + 1} is not a rigid transform: {problem}")
            return None
    return np.linalg.inv(Tr) @ T_w_cam0 @ Tr


def _read_class_names(path: Path) -> dict[int, str]:
    """``{id: name}`` from a ``classes.json`` (what the synthetic worlds write), or ``{}``."""
    if not path.is_file():
        return {}
    try:
        return {int(k): str(v) for k, v in json.loads(path.read_text()).items()}
    except (ValueError, AttributeError) as exc:
        raise DataError(path, f"is not a JSON object of class id → name ({exc})") from None


def cameras(seq_dir: Path) -> list[int]:
    """Indices of the ``image_N`` folders of a sequence."""
    names = (p.name.removeprefix("image_") for p in seq_dir.glob("image_*") if p.is_dir())
    return sorted(int(n) for n in names if n.isdigit())


def read_kitti_odometry(
    path: Path, sequence: str | None = None, camera: int | str | None = None
) -> FileSequence:
    """Read one KITTI odometry sequence (see the module docstring for the transform).

    Args:
        camera: index of the ``image_N`` folder (``None``: 2, the left colour camera, or the only
            camera present); one that is absent is refused with the list of those present.
    """
    root, seq_dir, name = _resolve(Path(path), sequence)
    notes: list[str] = []
    camera = choose_kitti_camera(cameras(seq_dir), camera, seq_dir, notes, lambda c: f"image_{c}")
    calib_path = seq_dir / "calib.txt"
    values = read_kv_file(calib_path)
    K, T_camX_cam0 = shift_from_projection(
        kv_matrix(values, f"P{camera}", (3, 4), calib_path), calib_path, f"P{camera}"
    )
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
    times = paired_timestamps(seq_dir / "times.txt", all_images, images, notes, problems=problems)
    lidar_times = _read_lidar_times(seq_dir / "times_lidar.txt", len(all_images), len(images))
    if lidar_times is not None:
        problems += time_problems(lidar_times, seq_dir / "times_lidar.txt", "LiDAR time stamp")
    poses_path = root / "poses" / f"{name}.txt"
    poses = None
    if poses_path.is_file() and len(images) == len(all_images):
        poses = _read_poses(poses_path, len(all_images), Tr, problems)
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
        point_time_paths=optional_paths(seq_dir / "point_times", stems, ".bin"),
        poses=poses,
        class_names=_read_class_names(seq_dir / "classes.json"),
        lidar_timestamps=lidar_times,
        camera=str(camera),
    )


def _read_lidar_times(path: Path, listed: int, paired: int) -> np.ndarray | None:
    """``times_lidar.txt`` (a supportnet extension the synthetic worlds write: scan stamps where
    they differ from ``times.txt``); ``None`` when absent or when frames went unpaired."""
    if not path.is_file() or listed != paired:
        return None
    try:
        times = np.loadtxt(path, dtype=np.float64, ndmin=1)
    except ValueError as exc:
        raise DataError(path, f"does not parse ({exc})") from None
    if len(times) != listed:
        raise DataError(path, f"holds {len(times)} stamps for {listed} frames")
    return times


class KittiOdometryWriter:
    """Writes ``root/sequences/<sequence>`` of the KITTI odometry layout frame by frame.

    Every camera ``P0..P3`` is written as ``K [I | 0]`` and ``Tr`` as the reference ``T_cam_lidar``,
    so reading camera 2 returns exactly the calibration given. Besides the standard files it writes
    ``labels/`` (SemanticKITTI, instance id in the upper 16 bits), ``image_labels/`` (uint16 class
    PNGs) and ``point_times/`` (float32 per-point seconds from the scan stamp) where frames have them.
    """

    def __init__(self, root: Path, sequence: str, calibration: Calibration):
        if calibration.T_cam_lidar is None:
            raise ValueError("the KITTI odometry layout needs a reference T_cam_lidar")
        self.root, self.sequence, self.calibration = Path(root), sequence, calibration
        self.seq_dir = self.root / "sequences" / sequence
        for sub in ("image_2", "velodyne"):
            (self.seq_dir / sub).mkdir(parents=True, exist_ok=True)
        P = np.hstack([calibration.K, np.zeros((3, 1))])
        calib_text = "".join(format_kv_line(f"P{i}", P) for i in range(4))
        calib_text += format_kv_line("Tr", calibration.T_cam_lidar[:3, :])
        atomic_write_text(self.seq_dir / "calib.txt", calib_text)
        self._times: list[float] = []
        self._lidar_times: list[float | None] = []

    def _path(self, folder: str, suffix: str) -> Path:
        (self.seq_dir / folder).mkdir(exist_ok=True)
        return self.seq_dir / folder / f"{len(self._times):06d}{suffix}"

    def add(self, frame: Frame, instances: np.ndarray | None = None) -> None:
        """Append one frame (its ``timestamp`` is the camera time; 10 Hz when missing)."""
        write_image(self._path("image_2", ".png"), frame.image)
        write_bin(self._path("velodyne", ".bin"), frame.points)
        if frame.labels is not None:
            write_label(self._path("labels", ".label"), frame.labels, instances)
        if frame.image_labels is not None:
            write_image(self._path("image_labels", ".png"), frame.image_labels.astype(np.uint16))
        if frame.point_times is not None:
            np.asarray(frame.point_times, np.float32).tofile(self._path("point_times", ".bin"))
        self._lidar_times.append(frame.lidar_timestamp)
        self._times.append(frame.timestamp if frame.timestamp is not None else len(self._times) / 10.0)

    def close(self, poses_lidar: np.ndarray | None = None) -> Path:
        """Write ``times.txt`` and, given ``(len, 4, 4)`` LiDAR poses, ``poses/<sequence>.txt``
        (as camera-0 poses, KITTI's convention). Returns the sequence folder."""
        atomic_write_text(self.seq_dir / "times.txt", "".join(f"{t:.9f}\n" for t in self._times))
        if self._lidar_times and all(t is not None for t in self._lidar_times):
            text = "".join(f"{t:.9f}\n" for t in self._lidar_times)
            atomic_write_text(self.seq_dir / "times_lidar.txt", text)
        if poses_lidar is not None:
            Tr = self.calibration.T_cam_lidar
            T_w_cam0 = Tr @ np.asarray(poses_lidar) @ np.linalg.inv(Tr)
            (self.root / "poses").mkdir(parents=True, exist_ok=True)
            rows = "".join(format_row(T[:3, :]) for T in T_w_cam0)
            atomic_write_text(self.root / "poses" / f"{self.sequence}.txt", rows)
        return self.seq_dir


def write_kitti_odometry(
    root: Path,
    sequence: str,
    frames: list[Frame],
    poses_lidar: np.ndarray | None = None,
) -> Path:
    """Write frames sharing one calibration as ``root/sequences/<sequence>`` (see
    :class:`KittiOdometryWriter`).

    Args:
        poses_lidar: optional ``(len, 4, 4)`` LiDAR poses, stored as camera-0 poses.

    Returns:
        The sequence folder.
    """
    if not frames:
        raise ValueError("no frames to write")
    writer = KittiOdometryWriter(root, sequence, frames[0].calibration)
    for frame in frames:
        writer.add(frame)
    return writer.close(poses_lidar)
