"""Time synchronisation of two motion streams: LiDAR poses interpolated at camera time stamps
(linear in position, slerp in rotation), as MDPCalib pairs its LiDAR and visual odometry."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

__all__ = ["interpolate_poses"]


def interpolate_poses(
    times: np.ndarray, poses: np.ndarray, query: np.ndarray, max_gap_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Poses at ``query`` times from poses at ``times``.

    A query is valid when it lies within ``[times[0], times[-1]]`` and its two neighbouring poses
    are at most ``max_gap_s`` apart (a dropped scan leaves a gap too long to interpolate across).

    Args:
        times: ``(N,)`` strictly increasing seconds. poses: ``(N, 4, 4)`` ``T_world_sensor``.
        query: ``(M,)`` seconds. max_gap_s: the longest interval interpolated across.

    Returns:
        ``(M, 4, 4)`` interpolated poses (identity where invalid) and ``(M,)`` bool valid.
    """
    times, query = np.asarray(times, np.float64), np.asarray(query, np.float64)
    if times.ndim != 1 or poses.shape != (len(times), 4, 4):
        raise ValueError(f"expected times (N,) and poses (N, 4, 4), got {times.shape}, {poses.shape}")
    if len(times) < 2 or np.any(np.diff(times) <= 0):
        raise ValueError("times must hold at least 2 strictly increasing stamps")
    right = np.clip(np.searchsorted(times, query, side="right"), 1, len(times) - 1)
    left = right - 1
    inside = (query >= times[0]) & (query <= times[-1])
    valid = inside & (times[right] - times[left] <= max_gap_s)
    alpha = np.clip((query - times[left]) / (times[right] - times[left]), 0.0, 1.0)
    out = np.tile(np.eye(4), (len(query), 1, 1))
    if valid.any():
        slerp = Slerp(times, Rotation.from_matrix(poses[:, :3, :3]))
        q = np.clip(query[valid], times[0], times[-1])
        out[valid, :3, :3] = slerp(q).as_matrix()
        a = alpha[valid, None]
        out[valid, :3, 3] = (1 - a) * poses[left[valid], :3, 3] + a * poses[right[valid], :3, 3]
    return out, valid
