"""Time synchronisation of two motion streams: LiDAR poses interpolated at camera time stamps
(linear in position, slerp in rotation), as MDPCalib pairs its LiDAR and visual odometry; and
the offset between the two streams' clocks from how much each rotates (the angle of a rotation
does not depend on the frame it is seen in, so no extrinsic is needed)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

__all__ = ["StampOffset", "interpolate_poses", "stamp_offset"]


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


@dataclass(frozen=True)
class StampOffset:
    """How much later the camera's stamps run than the LiDAR's clock (see :func:`stamp_offset`).

    Attributes:
        offset_s: the lag ``τ`` at the best match: the camera saw at its stamp ``t`` what the
            LiDAR's poses show at ``t − τ``.
        std_s: its standard deviation from the curvature of the match (``inf`` when flat).
        lags_s, cost: ``(L,)`` the lags tried and the mean squared angle mismatch (rad²) at each.
        pairs: camera motions compared at the best lag.
    """

    offset_s: float
    std_s: float
    lags_s: np.ndarray
    cost: np.ndarray
    pairs: int


CURVATURE_SPAN_S = 0.025
"""The lag's spread is read from the cost's curvature over this many seconds either side of its
minimum (a quarter of a 10 Hz scan period)."""


BOOTSTRAP_DRAWS = 200
"""Resamplings of the camera motions that the lag's spread is read from too."""


def stamp_offset(
    lidar_times: np.ndarray,
    lidar_poses: np.ndarray,
    camera_times: np.ndarray,
    camera_rotations: np.ndarray,
    max_lag_s: float = 0.2,
    step_s: float = 0.001,
    max_gap_s: float = 0.25,
) -> StampOffset:
    """The lag between a camera's and a LiDAR's stamps that makes their rotations agree.

    Each camera motion ``i → j`` turns by an angle ``θ_C``; the LiDAR, interpolated at the
    camera's stamps shifted by ``−τ``, turns by ``θ_L(τ)``. The angle of a rotation is the same in
    every frame, so ``Σ (θ_C − θ_L(τ))²`` needs no extrinsic; it is smallest at the true lag when
    the angular speed changes (turns), and flat on a straight drive. The variance of the minimum
    follows from the cost's curvature and its residual, as for any least-squares estimate.

    Args:
        lidar_times: ``(N,)`` LiDAR stamps. lidar_poses: ``(N, 4, 4)`` ``T_world_lidar``.
        camera_times: ``(M, 2)`` stamps of each camera motion's two frames.
        camera_rotations: ``(M, 3, 3)`` each motion's rotation.
        max_lag_s, step_s: the lags tried, ``−max_lag_s`` to ``max_lag_s``.

    Raises:
        ValueError: shapes that do not match, or fewer than 3 motions comparable at every lag.
    """
    camera_times = np.asarray(camera_times, np.float64)
    if (
        camera_times.ndim != 2
        or camera_times.shape[1] != 2
        or camera_rotations.shape != (len(camera_times), 3, 3)
    ):
        raise ValueError(
            f"expected camera times (M, 2) and rotations (M, 3, 3), got {camera_times.shape} and "
            f"{camera_rotations.shape}"
        )
    theta_camera = np.linalg.norm(Rotation.from_matrix(camera_rotations).as_rotvec(), axis=1)
    lags = np.arange(-max_lag_s, max_lag_s + step_s / 2, step_s)
    angles = np.full((len(lags), len(camera_times)), np.nan)
    for k, lag in enumerate(lags):
        poses, valid = interpolate_poses(lidar_times, lidar_poses, (camera_times - lag).ravel(), max_gap_s)
        poses, valid = poses.reshape(-1, 2, 4, 4), valid.reshape(-1, 2).all(1)
        relative = np.linalg.inv(poses[:, 1, :3, :3]) @ poses[:, 0, :3, :3]
        angles[k, valid] = np.linalg.norm(Rotation.from_matrix(relative[valid]).as_rotvec(), axis=1)
    usable = np.isfinite(angles).all(0)  # the same motions at every lag
    if usable.sum() < 3:
        raise ValueError(
            f"only {int(usable.sum())} camera motions lie inside the LiDAR's stamps at every lag"
        )
    mismatch = angles[:, usable] - theta_camera[usable]
    cost = (mismatch**2).mean(1)
    best = int(np.argmin(cost))
    std = np.inf
    near = np.abs(lags - lags[best]) <= CURVATURE_SPAN_S
    if 0 < best < len(lags) - 1 and near.sum() >= 5:
        # d²(mean r²)/dτ² of a parabola over ±CURVATURE_SPAN_S: the cost interpolates noisy poses
        # linearly, so it kinks at every LiDAR stamp, and a three-point difference read such a
        # kink as a sharp minimum on a straight drive (1 ms claimed, 100 ms off)
        curvature = 2 * np.polyfit(lags[near] - lags[best], cost[near], 2)[0]
        n = int(usable.sum())
        if curvature > 0:  # var(τ) = σ² / (Σ (dr/dτ)²) with Σ (dr/dτ)² = n · curvature / 2
            std = float(np.sqrt(cost[best] / (n * curvature / 2)))
            # and at least the spread of the minimum over the motions resampled: a cost with
            # another minimum about as deep (a drive that barely turns) moves it there
            rng = np.random.default_rng(0)
            draws = rng.integers(0, n, (BOOTSTRAP_DRAWS, n))
            minima = lags[np.argmin(np.stack([(mismatch[:, d] ** 2).mean(1) for d in draws]), axis=1)]
            std = max(std, float(np.subtract(*np.percentile(minima, [84.135, 15.865])) / 2))
    return StampOffset(float(lags[best]), std, lags, cost, int(usable.sum()))
