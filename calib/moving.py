"""Points on things that move (cars, people), found by looking through them from other scans.

A calibration matches a scan against an image taken ``δt`` later, and moves every point by the
LiDAR's own motion over ``δt``: right for the world, wrong for a car with a motion of its own
(an oncoming car at 8 m/s, camera 5 ms after the scan: 4 cm off, and in the same direction in
every frame, so it pulls ``δt`` and the translation with it). Consecutive scans show those points:
seen from the scans ``k`` before and after (their points carried into this scan's frame by the
LiDAR's motion), a point on a moving car lies where the other scans saw *through*, their returns
in its direction lying beyond it. That free-space test (as Removert's range images do) leaves
alone what another scan did not see (occluded, or out of range): only a farther return
convicts. Each other scan's returns are binned by direction from this scan's centre, each bin
keeping its nearest, and a point is seen through where, in every bin around its own, the other scan's
nearest return lies more than ``margin_m + margin·r`` beyond it (the bins around take in a static
edge's parallax: seen from a few metres away, the wall behind a pole shows beside it).

A car's points are not all convicted, and a few static ones are: an oncoming car is seen
through only from the scan before (the scan after sees it nearer, in front of where it was),
where its lower body meets the road the other scan's returns lie no farther, and parallax
convicts a scattering of static returns (0.1–0.2 % of a vineyard scan, on the ground and the
canopy). So the verdict goes to whole objects: the points above the local ground (each 2 m
cell's lowest return, 0.25 m up) fall into connected clusters of ``voxel_m`` voxels, and a
cluster with ``object_share`` of its points convicted is moving as a whole, the rest stays
(synthetic urban, three scans: 88–96 % of the moving cars' points, 0.1–0.2 % of the static
ones; the vineyard 0–0.02 %).

The camera sees a moving thing where it is at the camera's time, not where the sweep caught it
(a car at 10 m/s, caught 25 ms before the exposure, has moved 25 cm), so the background the LiDAR
saw beside it lies under the car in the image, and the car's foot, in the ground band no cluster
holds, stays. :func:`shadowed` leaves out what lies within ``shadow_deg`` of a moving cluster, as
far as it or farther (synthetic urban, 5 ms, 20 draws from 10 cm / 2°: median 0.75 cm / 0.035°,
δt 0.42 ms off, with 0.25°, one bin either side; 0.57 cm / 0.051°, 0.33 ms with 0.5°; 1.12 cm /
0.034°, 0.12 ms without; draws 0–2 with 1°, which takes more of the street: 1.14 / 0.81 / 1.48
cm; README).

Only where ``δt`` is fitted (:class:`calib.pipeline.Calibrator`): a moving thing is wrong
evidence only when camera and LiDAR see it at different times, and otherwise its edges are as
good as a wall's (urban in sync, 10° / 50 cm: leaving the cars out took the median from 0.86 to
1.16 cm; README).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PositiveFloat
from scipy import ndimage, sparse
from scipy.sparse import csgraph

from calib.data.types import Frame
from calib.features import ring_spacing_deg
from calib.motion import ScanMotion

__all__ = ["MovingConfig", "moving_points", "seen_through", "shadowed", "without_moving"]


class MovingConfig(BaseModel):
    """How :func:`moving_points` tells a moving point from a static one."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    enabled: bool = Field(
        True,
        description="where δt is estimated or held away from 0, and in every online window (its δt "
        "is a running guess), leave out the points the scans around see through (needs "
        "consecutive scans and the LiDAR's motion); offline with δt held at 0 the moving cars "
        "stay: seen at the scan's time they are evidence like any other (synthetic urban in sync, "
        "from 10° / 50 cm: median 0.86 cm with them, 1.16 without, README)",
    )
    scans_apart: int = Field(
        3,
        ge=1,
        description="the other scans: this many before and after (a car moves 2.4 m in 0.3 s at 8 m/s)",
    )
    azimuth_bin_deg: PositiveFloat = Field(0.4, description="bin width along the sweep")
    margin_m: float = Field(0.5, ge=0, description="how far beyond a point the other scan's return must lie")
    margin: float = Field(0.05, ge=0, description="... plus this share of the point's range")
    object_share: float = Field(
        0.3, gt=0, le=1, description="a cluster of points with this share convicted is moving as a whole"
    )
    voxel_m: PositiveFloat = Field(0.3, description="points in touching voxels of this size are one cluster")
    shadow_deg: float = Field(
        0.25,
        ge=0,
        description="also leave out the points within this angle of a moving cluster (seen from the "
        "LiDAR) that lie as far as it or farther: what the camera, at another time, sees the thing cover "
        "(0: none)",
    )
    shadow_slack_m: float = Field(1.0, ge=0, description="... from this much nearer than the cluster on")


def seen_through(
    points_lidar: np.ndarray, others: Sequence[np.ndarray], config: MovingConfig = MovingConfig()
) -> np.ndarray:
    """Which points of a scan lie where another scan saw through (the module docstring's first
    test, point by point).

    Args:
        points_lidar: ``(N, 3+)`` the scan (LiDAR frame at its stamp, deskewed where it can be).
        others: ``(M_k, 3)`` each other scan's points carried into the same frame.

    Returns:
        ``(N,)`` bool.
    """
    xyz = np.asarray(points_lidar, np.float64)[:, :3]
    through = np.zeros(len(xyz), bool)
    if not len(xyz) or not others:
        return through
    bins = _Bins.of_scan(xyz, config)
    here, r = bins.of(xyz)
    for other in others:
        other = np.asarray(other, np.float64)[:, :3]
        nearest = np.full(bins.size, np.inf)
        where, other_r = bins.of(other)
        inside = where >= 0
        np.minimum.at(nearest, where[inside], other_r[inside])
        # the nearest over the bin and those around it: a static edge's parallax stays unconvicted
        nearest = ndimage.minimum_filter(nearest.reshape(bins.shape), size=3, mode="nearest").ravel()
        beyond = nearest[np.maximum(here, 0)] > r + config.margin_m + config.margin * r
        through |= (here >= 0) & beyond & np.isfinite(nearest[np.maximum(here, 0)])
    return through


def moving_points(
    points_lidar: np.ndarray, others: Sequence[np.ndarray], config: MovingConfig = MovingConfig()
) -> np.ndarray:
    """Which points of a scan lie on moving things: the clusters above the ground with
    ``config.object_share`` of their points :func:`seen_through` (module docstring).

    Args:
        points_lidar: ``(N, 3+)`` the scan (LiDAR frame at its stamp, deskewed where it can be).
        others: ``(M_k, 3)`` each other scan's points carried into the same frame.

    Returns:
        ``(N,)`` bool, ``True`` where moving.
    """
    xyz = np.asarray(points_lidar, np.float64)[:, :3]
    through = seen_through(xyz, others, config)
    moving = np.zeros(len(xyz), bool)
    cluster = _clusters(xyz, config.voxel_m) if through.any() else np.full(len(xyz), -1)
    counted = cluster >= 0
    if counted.any():
        size = np.bincount(cluster[counted])
        convicted = np.bincount(cluster[counted], weights=through[counted], minlength=len(size))
        moving[counted] = (convicted >= config.object_share * size)[cluster[counted]]
    return moving


def shadowed(
    points_lidar: np.ndarray, moving: np.ndarray, config: MovingConfig = MovingConfig()
) -> np.ndarray:
    """Which static points lie in a moving thing's shadow: within ``config.shadow_deg`` of its
    points (azimuth and elevation from the LiDAR, rounded up to whole azimuth bins and ring
    spacings either side) and no more than ``config.shadow_slack_m``
    nearer than the nearest of them. The camera sees a moving thing where it is at the camera's
    time, not at each point's time within the sweep (a car at 10 m/s seen 25 ms apart has moved
    25 cm), and with it covers the background the LiDAR saw beside it.

    Args:
        points_lidar: ``(N, 3+)`` the scan. moving: ``(N,)`` bool, :func:`moving_points`.

    Returns:
        ``(N,)`` bool, ``False`` on the moving points themselves.
    """
    xyz = np.asarray(points_lidar, np.float64)[:, :3]
    shadow = np.zeros(len(xyz), bool)
    if config.shadow_deg <= 0 or not moving.any():
        return shadow
    bins = _Bins.of_scan(xyz, config)
    here, r = bins.of(xyz)
    nearest = np.full(bins.size, np.inf)
    on = moving & (here >= 0)
    np.minimum.at(nearest, here[on], r[on])
    size = (
        2 * int(np.ceil(np.radians(config.shadow_deg) / bins.step)) + 1,
        2 * int(np.ceil(config.shadow_deg / config.azimuth_bin_deg)) + 1,
    )
    near = ndimage.minimum_filter(nearest.reshape(bins.shape), size=size, mode=("nearest", "wrap")).ravel()
    at = near[np.maximum(here, 0)]
    return (here >= 0) & ~moving & np.isfinite(at) & (r >= at - config.shadow_slack_m)


def _clusters(xyz: np.ndarray, voxel_m: float, cell_m: float = 2.0, clearance_m: float = 0.25) -> np.ndarray:
    """``(N,)`` the connected cluster of each point above the local ground (``-1``: on it): the
    ground is each ``cell_m`` cell's lowest return, and points more than ``clearance_m`` above it
    in touching ``voxel_m`` voxels (26-neighbourhood) form one cluster."""
    cell = np.floor((xyz[:, :2] - xyz[:, :2].min(0)) / cell_m).astype(np.int64)
    _, which = np.unique(cell, axis=0, return_inverse=True)
    which = which.ravel()
    floor = np.full(which.max() + 1, np.inf)
    np.minimum.at(floor, which, xyz[:, 2])
    above = xyz[:, 2] > floor[which] + clearance_m
    cluster = np.full(len(xyz), -1, np.int64)
    if not above.any():
        return cluster
    # the occupied voxels alone (a grid over a 100 m scan would take gigabytes), linked to their
    # occupied neighbours, then connected components
    voxel = np.floor((xyz[above] - xyz[above].min(0)) / voxel_m).astype(np.int64) + 1
    span = voxel.max(0) + 2
    key = (voxel[:, 0] * span[1] + voxel[:, 1]) * span[2] + voxel[:, 2]
    occupied, member = np.unique(key, return_inverse=True)
    steps = np.array(
        [(a * span[1] + b) * span[2] + c for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)]
    )
    steps = steps[steps > 0]  # each link once
    near = occupied[:, None] + steps[None, :]
    at = np.clip(np.searchsorted(occupied, near), 0, len(occupied) - 1)
    linked = occupied[at] == near
    rows = np.broadcast_to(np.arange(len(occupied))[:, None], near.shape)[linked]
    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, at[linked])), shape=(len(occupied),) * 2)
    _, component = csgraph.connected_components(graph, directed=False)
    cluster[above] = component[member.ravel()]
    return cluster


class _Bins:
    """Directions from the LiDAR's centre binned by azimuth and elevation, over the elevations of
    ``xyz (N, 3)`` (one ring spacing either side)."""

    def __init__(self, azimuth_step: float, elevation_step: float, xyz: np.ndarray):
        elevation = np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1]))
        self.low, self.step = float(elevation.min()) - elevation_step, elevation_step
        self.azimuth_step = azimuth_step
        rows = int(np.ceil((float(elevation.max()) + elevation_step - self.low) / elevation_step)) + 1
        self.shape = (rows, int(np.ceil(2 * np.pi / azimuth_step)))
        self.size = self.shape[0] * self.shape[1]

    @classmethod
    def of_scan(cls, xyz: np.ndarray, config: MovingConfig) -> _Bins:
        """Bins ``config.azimuth_bin_deg`` wide by the scan's own ring spacing (at least 0.1°)."""
        spacing = max(ring_spacing_deg(xyz), 0.1)
        return cls(np.radians(config.azimuth_bin_deg), np.radians(spacing), xyz)

    def of(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each point's flat bin (``-1`` outside the elevation range) and range, ``(N,)`` each."""
        rho = np.hypot(xyz[:, 0], xyz[:, 1])
        row = np.floor((np.arctan2(xyz[:, 2], rho) - self.low) / self.step).astype(np.int64)
        col = np.floor((np.arctan2(xyz[:, 1], xyz[:, 0]) + np.pi) / self.azimuth_step).astype(np.int64)
        col = np.clip(col, 0, self.shape[1] - 1)
        inside = (row >= 0) & (row < self.shape[0])
        return np.where(inside, row * self.shape[1] + col, -1), np.linalg.norm(xyz, axis=1)


def without_moving(
    seq: Sequence[Frame],
    positions: Sequence[int],
    frames: Sequence[Frame],
    stamps: Sequence[np.ndarray],
    motions: Sequence[ScanMotion],
    config: MovingConfig,
    times_of: Callable[[Frame], np.ndarray | None],
    max_gap_s: float = 0.25,
) -> tuple[list[Frame], list[np.ndarray]]:
    """``frames`` (those at ``positions`` of ``seq``) less their :func:`moving_points`, seen from
    the scans ``config.scans_apart`` before and after each, carried by its ``motions`` entry; and
    which points each lost (``(N,)`` bool). A frame without such scans (an end of ``seq``, stamps
    more than ``max_gap_s`` per scan apart, no stamps) keeps its points.

    Args:
        stamps: each frame's points ``(N, 3)`` at its stamp (deskewed; the
            :class:`calib.refine.passes.ScanTiming`'s).
        times_of: a frame's per-point times from its stamp (deskewing the scans around), or ``None``.
    """
    kept, lost = [], []
    for i, frame, stamp, motion in zip(positions, frames, stamps, motions, strict=True):
        t_i = frame.scan_stamp
        others = []
        for j in (i - config.scans_apart, i + config.scans_apart):
            if t_i is None or not 0 <= j < len(seq):
                continue
            other = seq[j]
            t_j = other.scan_stamp
            if t_j is None or not 0 < abs(t_j - t_i) <= max_gap_s * config.scans_apart:
                continue
            # its points at its stamp (deskewed with this frame's motion, near enough), then here
            points = other.points[:, :3].astype(np.float64)
            times = times_of(other)
            points = points if times is None else motion.deskew(points, times)
            T = motion.pose(t_j - t_i)  # T_Li_Lj: the LiDAR at t_j in its frame at t_i
            others.append(points @ T[:3, :3].T + T[:3, 3])
        moving = moving_points(stamp, others, config)
        moving |= shadowed(stamp, moving, config)
        kept.append(_subset(frame, ~moving) if moving.any() else frame)
        lost.append(moving)
    return kept, lost


def _subset(frame: Frame, keep: np.ndarray) -> Frame:
    """``frame`` with the points ``keep (N,)`` selects (and their labels and times)."""
    return replace(
        frame,
        points=frame.points[keep],
        labels=None if frame.labels is None else frame.labels[keep],
        point_times=None if frame.point_times is None else frame.point_times[keep],
    )
