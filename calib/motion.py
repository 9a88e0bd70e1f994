"""The LiDAR's motion around a scan, to move its points to another time (deskewing, time offset).

A scan's points are measured over its sweep, each in the LiDAR frame of its own time
``t_L + τ_i``, and the camera exposes at ``t_L + δt``. Between two odometry poses the LiDAR is
taken to move along the SE(3) geodesic, at a constant body twist ``ξ = log(T_a⁻¹ T_b) / (t_b − t_a)``
(piecewise-geodesic interpolation). A spline would give the motion a continuous acceleration,
but over the ±50 ms that a sweep and a camera offset span a car or a tractor changes its twist
by a few per cent, below what the residuals resolve, and the geodesic needs only the two poses
either side of the stamp. With ``T_L0_L(t) = exp(t ξ)`` (``ξ`` the twist before the stamp for
``t < 0``, after it for ``t ≥ 0``), a point ``p`` measured at ``τ`` lies at

    ``q = T_L0_L(τ) p``               in the LiDAR frame at the stamp (deskewed), and
    ``p(t) = T_L0_L(t)⁻¹ q``          in the LiDAR frame at time ``t``,

whose derivative is ``dp(t)/dt = −ξ^ p(t) = −(ω × p(t) + v)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from calib.geometry import se3_exp, se3_log

__all__ = ["ScanMotion", "mean_twist", "motions_from_poses", "sweep_times", "twist_spread"]


@dataclass(frozen=True)
class ScanMotion:
    """Body twists ``(v, ω)`` (m/s, rad/s, in the LiDAR frame; translation first, as
    :func:`~calib.geometry.se3_exp`) of the LiDAR before and after a scan's stamp.

    Attributes:
        before: ``(6,)`` over the interval that ends at the stamp.
        after: ``(6,)`` over the interval that starts at it.
    """

    before: np.ndarray
    after: np.ndarray

    def __post_init__(self) -> None:
        for name in ("before", "after"):
            twist = np.asarray(getattr(self, name), np.float64)
            if twist.shape != (6,) or not np.isfinite(twist).all():
                raise ValueError(f"ScanMotion.{name} must be a finite (6,) twist, got {twist.tolist()}")
            object.__setattr__(self, name, twist)

    @classmethod
    def still(cls) -> ScanMotion:
        """A LiDAR that does not move."""
        return cls(np.zeros(6), np.zeros(6))

    def twist(self, t: np.ndarray | float) -> np.ndarray:
        """``(*, 6)`` the twist in force at times ``t (*)`` (seconds from the stamp)."""
        t = np.asarray(t, np.float64)
        return np.where(t[..., None] < 0, self.before, self.after)

    def pose(self, t: np.ndarray | float) -> np.ndarray:
        """``T_L0_L(t) (*, 4, 4)``: the LiDAR at times ``t (*)`` in its frame at the stamp."""
        t = np.asarray(t, np.float64)
        return se3_exp(torch.from_numpy(t[..., None] * self.twist(t))).numpy()

    def deskew(self, points_lidar: np.ndarray, times: np.ndarray) -> np.ndarray:
        """``q = T_L0_L(τ) p``: points measured at their own times, in the LiDAR frame at the stamp.

        Args:
            points_lidar: ``(N, 3)``. times: ``(N,)`` seconds from the stamp.
        """
        T = self.pose(times)
        return np.einsum("nij,nj->ni", T[:, :3, :3], points_lidar) + T[:, :3, 3]

    def at(self, points_stamp: np.ndarray, t: float) -> np.ndarray:
        """``p(t) = T_L0_L(t)⁻¹ q``: points of the stamp's frame ``(N, 3)`` in the LiDAR frame at ``t``."""
        T = self.pose(t)
        return (points_stamp - T[:3, 3]) @ T[:3, :3]


def motions_from_poses(T_world_lidar: np.ndarray, stamps: np.ndarray, span: int = 1) -> list[ScanMotion]:
    """Piecewise-geodesic twists of a trajectory, one :class:`ScanMotion` per pose.

    With ``span = 1`` the twist after pose ``i`` is the geodesic to pose ``i + 1``; a longer span
    takes it to pose ``i + span`` instead, which averages odometry noise over that many steps
    (a pose error ``σ`` gives a speed error ``σ / (span Δt)``) at the cost of smoothing turns.
    The first pose's twist before it is the one after it, and the last's after it the one before.

    Args:
        T_world_lidar: ``(F, 4, 4)`` poses (odometry or ground truth), ``F ≥ 2``.
        stamps: ``(F,)`` strictly increasing times in seconds.
        span: poses between the two ends of each geodesic (shortened near the ends).

    Raises:
        ValueError: fewer than two poses, or stamps that do not increase.
    """
    T = np.asarray(T_world_lidar, np.float64)
    stamps = np.asarray(stamps, np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or len(T) < 2 or stamps.shape != (len(T),):
        raise ValueError(f"need (F, 4, 4) poses, F >= 2, and (F,) stamps; got {T.shape} and {stamps.shape}")
    gaps = np.diff(stamps)
    if not (gaps > 0).all():
        raise ValueError(f"stamps must increase strictly, got gaps {gaps.tolist()}")
    if span < 1:
        raise ValueError(f"span must be at least 1, got {span}")

    def twist(a: int, b: int) -> np.ndarray:
        relative = np.linalg.inv(T[a]) @ T[b]
        return se3_log(torch.from_numpy(relative)).numpy() / (stamps[b] - stamps[a])

    last = len(T) - 1
    motions = []
    for i in range(len(T)):
        after = twist(i, min(i + span, last)) if i < last else None
        before = twist(max(i - span, 0), i) if i > 0 else after
        motions.append(ScanMotion(before, after if after is not None else before))
    return motions


def _scan_twists(motions: list[ScanMotion]) -> np.ndarray:
    """``(F, 6)`` each scan's body twist ``(v, ω)``: the mean of its two sides."""
    return np.stack([(m.before + m.after) / 2 for m in motions])


def mean_twist(motions: list[ScanMotion]) -> np.ndarray:
    """``(6,)`` the scans' mean body twist ``(v, ω)``, each scan's taken as the mean of its two sides."""
    return _scan_twists(motions).mean(0)


def twist_spread(motions: list[ScanMotion]) -> tuple[float, float]:
    """How much the motion differs between scans: the RMS distance of each scan's velocity
    (m/s) and angular velocity (rad/s) from their means, each scan's twist taken as the mean of
    its two sides.

    A time offset moves every scan's points by ``δt`` times its twist; the part common to all
    scans is a fixed transform that the extrinsic absorbs, so only this spread tells ``δt`` apart.
    """
    twists = _scan_twists(motions)
    deviation = twists - twists.mean(0)
    speed = float(np.sqrt((deviation[:, :3] ** 2).sum(1).mean()))
    turn = float(np.sqrt((deviation[:, 3:] ** 2).sum(1).mean()))
    return speed, turn


def sweep_times(
    points_lidar: np.ndarray, period_s: float = 0.1, clockwise: bool = True, stamp_azimuth_deg: float = 0.0
) -> np.ndarray:
    """Per-point times of a rotating LiDAR that records none: from each point's azimuth.

    The head turns once per ``period_s`` (clockwise seen from above: the azimuth ``atan2(y, x)``
    falls) and faces ``stamp_azimuth_deg`` at the scan's stamp (KITTI triggers its cameras as the
    HDL-64 faces forward, 0°), so a point at azimuth ``a`` was measured
    ``∓ wrap(a − a_stamp) / 2π · period`` from the stamp, within half a period either side.

    Args:
        points_lidar: ``(N, 3+)``.

    Returns:
        ``(N,)`` seconds from the stamp, in ``(−period/2, period/2]``.
    """
    azimuth = np.arctan2(points_lidar[:, 1], points_lidar[:, 0]) - np.radians(stamp_azimuth_deg)
    wrapped = np.angle(np.exp(1j * azimuth))  # (−π, π]
    return (-wrapped if clockwise else wrapped) / (2 * np.pi) * period_s
