"""LiDAR odometry with KISS-ICP, and the drift of a trajectory against ground truth."""

from __future__ import annotations

from collections.abc import Iterable
from collections.abc import Sequence as FrameList

import numpy as np

from calib.data.types import Frame
from calib.motion import ScanMotion, motions_from_poses

__all__ = ["SequenceMotions", "drift", "lidar_odometry", "scan_motions", "sensor_range"]


def sensor_range(scans: list[np.ndarray], percentile: float = 99.5) -> float:
    """The range a sensor actually sees, for KISS-ICP's ``max_range`` (whose default voxel size is
    a hundredth of it): a vineyard's rows end within 25 m, where a 100 m setting would give 1 m
    voxels that blur posts and canopy (measured: 4.5 cm against 0.9 cm median error per frame).

    Args:
        scans: a few ``(N, 3+)`` point clouds in the LiDAR frame.

    Returns:
        The ``percentile`` of their ranges, rounded up to a whole metre.
    """
    ranges = np.concatenate([np.linalg.norm(np.asarray(s)[:, :3], axis=1) for s in scans])
    if not len(ranges):
        raise ValueError("no points to take the sensor range from")
    return float(np.ceil(np.percentile(ranges, percentile)))


def lidar_odometry(
    scans: Iterable[np.ndarray],
    point_times: Iterable[np.ndarray | None] | None = None,
    max_range_m: float = 100.0,
    min_range_m: float = 2.0,
    voxel_size_m: float | None = None,
) -> np.ndarray:
    """Poses ``T_lidar0_lidar`` of each scan relative to the first, by KISS-ICP.

    Args:
        scans: ``(N, 3+)`` point clouds in the LiDAR frame, in time order.
        point_times: optional per-point times per scan (KISS-ICP deskews with them).
        voxel_size_m: map voxel size; ``None`` leaves KISS-ICP's loader its default, ``max_range / 100``.

    Returns:
        ``(F, 4, 4)``; the first is the identity.
    """
    import tempfile

    import yaml
    from kiss_icp.config import load_config
    from kiss_icp.kiss_icp import KissICP

    settings = {
        "data": {"max_range": max_range_m, "min_range": min_range_m, "deskew": point_times is not None},
        "mapping": {"voxel_size": voxel_size_m} if voxel_size_m else {},
    }
    with tempfile.NamedTemporaryFile("w", suffix=".yaml") as f:  # KISS-ICP's own loader fills defaults
        yaml.safe_dump(settings, f)
        f.flush()
        config = load_config(f.name)
    odometry = KissICP(config)
    times = iter(point_times) if point_times is not None else None
    poses = []
    for scan in scans:
        t = next(times) if times is not None else None
        stamps = np.zeros(len(scan)) if t is None else (t - t.min()) / max(np.ptp(t), 1e-9)
        odometry.register_frame(np.asarray(scan[:, :3], dtype=np.float64), stamps)
        poses.append(odometry.last_pose.copy())
    return np.stack(poses)


def _above_ground(points_lidar: np.ndarray, clearance_m: float = 0.3) -> np.ndarray:
    """``(N,)`` bool: points more than ``clearance_m`` above the scan's lowest (5th percentile)
    height, the LiDAR's z pointing up. A rotating LiDAR lays the same rings on flat ground at every
    pose, and they hold a short odometry run still: on the synthetic vineyard KISS-ICP reads
    −0.1 to 0.2 m/s for 1.19 with them, 1.0–1.2 without."""
    z = points_lidar[:, 2]
    return z > np.percentile(z, 5) + clearance_m


def scan_motions(
    seq: FrameList[Frame],
    positions: Iterable[int],
    neighbours: int = 3,
    max_gap_s: float = 0.25,
    deskew_rounds: int = 1,
) -> tuple[list[ScanMotion] | None, str]:
    """The LiDAR's motion around each scan at ``positions`` of ``seq``: KISS-ICP over the scans
    from ``neighbours`` before to ``neighbours`` after it (one run per stretch of overlapping
    windows), and the geodesics ``neighbours`` scans either side
    (:func:`~calib.motion.motions_from_poses` with that span: one scan's registration error is
    spread over several).

    Scans with per-point times are deskewed, and a short run deskews its first scans badly:
    KISS-ICP deskews each scan with the motion it registered the scan before, none for the first,
    so its first steps register distorted scans and misread the speed (synthetic urban at 8 m/s,
    ten scans: 10.0-10.8 m/s at the start). So each of ``deskew_rounds`` runs KISS-ICP again on
    the scans deskewed with the last run's motions, which deskews every scan from the start
    (seeds 303, 4, 5: median speed error 0.58 / 0.93 / 0.84 m/s, after one round 0.18 / 0.26 /
    0.18, after two 0.10 / 0.29 / 0.08; seed 302, a street whose facades hardly constrain the
    forward motion, 0.72 -> 0.67).

    Args:
        seq: frames in time order (a :class:`~calib.data.types.Sequence` or a list).
        positions: which frames need their motion.
        max_gap_s: neighbours farther apart in time are not one drive.
        deskew_rounds: KISS-ICP runs on scans deskewed by the previous run (with per-point times).

    Returns:
        One :class:`~calib.motion.ScanMotion` per position and ``""``; or ``None`` and why not.
    """
    positions = [int(i) for i in positions]
    if len(seq) < 2:
        return None, "a single frame shows no motion"
    stretches: list[list[int]] = []  # [first, last] scans of each odometry run
    for i in sorted(positions):
        first, last = max(i - neighbours, 0), min(i + neighbours, len(seq) - 1)
        if stretches and first <= stretches[-1][1] + 1:
            stretches[-1][1] = last
        else:
            stretches.append([first, last])
    found: dict[int, ScanMotion] = {}
    for first, last in stretches:
        frames = [seq[j] for j in range(first, last + 1)]
        stamps = [f.scan_stamp for f in frames]
        if any(t is None for t in stamps):
            return None, "the frames have no time stamps"
        gaps = np.diff(stamps)
        if not ((gaps > 0) & (gaps <= max_gap_s)).all():
            return (
                None,
                f"frames {first}-{last} are not consecutive scans (stamp gaps up to {gaps.max():.3g} s)",
            )
        above = [_above_ground(f.points) for f in frames]
        scans = [f.points[keep] for f, keep in zip(frames, above, strict=True)]
        times = [
            None if f.point_times is None else f.point_times[keep]
            for f, keep in zip(frames, above, strict=True)
        ]
        timed = all(t is not None for t in times)
        max_range_m = sensor_range(scans)
        poses = lidar_odometry(scans, times if timed else None, max_range_m=max_range_m)
        motions = motions_from_poses(poses, np.asarray(stamps), span=neighbours)
        for _ in range(deskew_rounds if timed else 0):
            deskewed = [
                motion.deskew(scan[:, :3].astype(np.float64), t)
                for motion, scan, t in zip(motions, scans, times, strict=True)
            ]
            poses = lidar_odometry(deskewed, None, max_range_m=max_range_m)
            motions = motions_from_poses(poses, np.asarray(stamps), span=neighbours)
        found.update({first + k: m for k, m in enumerate(motions)})
    return [found[i] for i in positions], ""


class SequenceMotions:
    """:func:`scan_motions` of one sequence, remembered by position: the runs and supports of one
    ``supportnet calibrate`` use the same sequence, and LiDAR odometry runs once around each scan.

    Args:
        seq, neighbours, deskew_rounds: as :func:`scan_motions`.
    """

    def __init__(self, seq: FrameList[Frame], neighbours: int = 3, deskew_rounds: int = 1) -> None:
        self.seq, self.neighbours, self.deskew_rounds = seq, neighbours, deskew_rounds
        self._found: dict[int, ScanMotion] = {}

    def __call__(self, positions: Iterable[int]) -> tuple[list[ScanMotion] | None, str]:
        """As :func:`scan_motions` on ``positions``, the motions found before reused."""
        positions = [int(i) for i in positions]
        missing = sorted({i for i in positions if i not in self._found})
        if missing:
            found, why = scan_motions(self.seq, missing, self.neighbours, deskew_rounds=self.deskew_rounds)
            if found is None:
                return None, why
            self._found.update(zip(missing, found, strict=True))
        return [self._found[i] for i in positions], ""


def drift(estimate: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    """End-point drift of a trajectory against ground truth, both taken relative to their first pose.

    Args:
        estimate, reference: ``(F, 4, 4)`` poses.

    Returns:
        ``path_m`` (ground-truth length), ``end_error_m``, ``drift_percent`` (end error over path
        length), ``rotation_drift_deg`` (end rotation error) and ``mean_error_m`` (mean position
        error over all frames).
    """
    est = np.linalg.inv(estimate[0]) @ estimate
    ref = np.linalg.inv(reference[0]) @ reference
    path = float(np.linalg.norm(np.diff(ref[:, :3, 3], axis=0), axis=1).sum())
    errors = np.linalg.norm(est[:, :3, 3] - ref[:, :3, 3], axis=1)
    R = est[-1, :3, :3].T @ ref[-1, :3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)))
    return {
        "path_m": path,
        "end_error_m": float(errors[-1]),
        "drift_percent": float(100 * errors[-1] / path) if path > 0 else float("nan"),
        "rotation_drift_deg": float(angle),
        "mean_error_m": float(errors.mean()),
    }
