"""Geometric features of a LiDAR scan that do not depend on the extrinsic."""

from __future__ import annotations

import numpy as np

__all__ = ["depth_discontinuities"]


def depth_discontinuities(
    points_lidar: np.ndarray,
    ring: np.ndarray | None = None,
    min_jump_m: float = 0.5,
    rel_jump: float = 0.1,
    max_azimuth_gap_deg: float = 1.0,
    max_elevation_gap_deg: float = 0.3,
    surface_tol: float = 0.05,
) -> tuple[np.ndarray, np.ndarray]:
    """Foreground points at range discontinuities between neighbouring returns of a scan line.

    Neighbours are consecutive points of a scan line: points sorted by ``(ring, azimuth)`` when
    ``ring`` is given, else taken in stored order (KITTI/Velodyne scans are stored ring by ring)
    and accepted as neighbours only when they are also close in azimuth and elevation. Of a
    neighbouring pair whose ranges differ by more than ``max(min_jump_m, rel_jump · nearer)``,
    the nearer point lies on an occluding contour, which the camera sees as an edge.
    Both points must continue a surface away from the jump (their outer neighbours' ranges
    within ``surface_tol``): isolated returns and foliage, which jump all the time, carry no
    clean image edge.

    Args:
        points_lidar: ``(N, 3)`` or ``(N, 4)`` points.
        ring: ``(N,)`` laser index per point, optional.

    Returns:
        ``nearer (M,)`` and ``farther (M,)`` point indices of each discontinuity: the occluding
        contour seen by the camera lies between the two returns.
    """
    xyz = np.asarray(points_lidar, dtype=np.float64)[:, :3]
    azimuth = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0]))
    horizontal = np.hypot(xyz[:, 0], xyz[:, 1])
    elevation = np.degrees(np.arctan2(xyz[:, 2], horizontal))
    rng = np.linalg.norm(xyz, axis=1)
    order = np.lexsort((azimuth, ring)) if ring is not None else np.arange(len(xyz))
    a, b = order[:-1], order[1:]
    d_az = np.abs((azimuth[b] - azimuth[a] + 180.0) % 360.0 - 180.0)
    neighbours = d_az < max_azimuth_gap_deg
    if ring is not None:
        neighbours &= ring[a] == ring[b]
    else:
        neighbours &= np.abs(elevation[b] - elevation[a]) < max_elevation_gap_deg
    closer = np.minimum(rng[a], rng[b])
    jump = neighbours & (np.abs(rng[a] - rng[b]) > np.maximum(min_jump_m, rel_jump * closer))
    # smooth[k]: order[k] and order[k + 1] are neighbours on one surface
    smooth = neighbours & (np.abs(rng[a] - rng[b]) <= surface_tol * closer)
    k = np.nonzero(jump)[0]
    a_nearer = rng[a[k]] < rng[b[k]]
    before = np.concatenate([[False], smooth])[k]  # order[k - 1] continues order[k]
    after = np.concatenate([smooth, [False]])[k + 1]  # order[k + 2] continues order[k + 1]
    keep = before & after
    nearer = np.where(a_nearer, a[k], b[k])[keep]
    farther = np.where(a_nearer, b[k], a[k])[keep]
    return nearer, farther
