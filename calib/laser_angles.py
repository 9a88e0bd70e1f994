"""Each laser's angle error, measured from a scan's own geometry (no camera, no target).

A spinning LiDAR reports every return along its laser's nominal direction; the beam went along a
slightly different one (the factory calibration's residual). A return at range ``r`` then lies
``r·ε`` off along the elevation direction for an elevation error ``ε``, and ``r·cos θ·η`` along the
sweep for an azimuth error ``η``. Two surfaces show it without ground truth:

- **Elevation, from the ground.** Each line that meets a flat ground reports it at its own height:
  ``Δz = −r·ε·cos θ`` (``θ`` the elevation). A plane fitted to the scan's ground takes the lines'
  common part (and the road's tilt); what each line departs from it is its ``ε`` plus the road's
  own shape, which changes slowly from line to line (a crown, a slope) where the lasers' errors
  do not: :func:`high_pass` keeps the part that changes from one line to the next.
- **Azimuth, from vertical surfaces.** Two neighbouring lines meet a wall along the same
  horizontal profile ``ρ(a)``, each read at its own true azimuth: ``ρ_{k+1}(a) − ρ_k(a) =
  ρ'(a)·(η_{k+1} − η_k)``, a least-squares slope over the wall's oblique stretches.

Neither recovers the lasers' mean error: the mean elevation error is a tilt of the whole scan, the
mean azimuth error a turn about its axis, both part of any extrinsic. ``benchmarks/
bench_laser_angles.py`` measures real KITTI's HDL-64 with these, checked against the synthetic
worlds' known errors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from calib.features import scan_lines

__all__ = ["LaserAngles", "high_pass", "laser_angle_errors"]


@dataclass(frozen=True)
class LaserAngles:
    """A scan's laser angle errors per scan line (:func:`~calib.features.scan_lines` order).

    Attributes:
        line_elevation_deg: ``(L,)`` median nominal elevation of each line.
        elevation_deg: ``(L,)`` each line's elevation error (NaN where the line meets too little
            ground) less what the ground plane's fitted height cannot tell from it (a constant and a
            term in ``tan θ``); the road's shape is in it too (:func:`high_pass`).
        azimuth_step_deg: ``(L-1,)`` ``η_{k+1} − η_k``, the azimuth error of each line less the
            one before it (NaN where the two meet too few oblique vertical surfaces).
    """

    line_elevation_deg: np.ndarray
    elevation_deg: np.ndarray
    azimuth_step_deg: np.ndarray


def high_pass(values: np.ndarray, size: int = 5) -> np.ndarray:
    """``values (..., L)`` less their running median over ``size`` lines (NaN stay NaN): the part
    that changes from line to line."""
    values = np.asarray(values, np.float64)
    window = (1,) * (values.ndim - 1) + (size,)
    smooth = ndimage.median_filter(np.nan_to_num(values), size=window, mode="nearest")
    return values - smooth


def laser_angle_errors(
    points_lidar: np.ndarray,
    ground_range_m: tuple[float, float] = (4.0, 40.0),
    min_ground: int = 50,
    min_pairs: int = 200,
) -> LaserAngles | None:
    """Each line's elevation and azimuth error as this scan shows them (module docstring).

    Args:
        points_lidar: ``(N, 3+)`` a scan stored line by line (LiDAR frame, z up).
        ground_range_m: horizontal distances the ground plane is fitted over.
        min_ground: ground returns a line needs for its elevation error.
        min_pairs: returns on oblique vertical surfaces a pair of lines needs for its step.

    Returns:
        the errors, or ``None`` for a scan not stored line by line.
    """
    points = np.asarray(points_lidar)
    line = scan_lines(points)
    if line is None:
        return None
    xyz = points[:, :3].astype(np.float64)
    rho = np.hypot(xyz[:, 0], xyz[:, 1])
    elevation = np.arctan2(xyz[:, 2], rho)
    azimuth = np.arctan2(xyz[:, 1], xyz[:, 0])
    bounds = np.concatenate([[0], np.cumsum(np.bincount(line))])  # lines are contiguous runs
    runs = [np.arange(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    line_elevation = np.array([np.degrees(np.median(elevation[run])) for run in runs])
    ground_z, ground = _ground(xyz, rho, ground_range_m)
    # Δz = −r ε cos θ, so ε = −Δz / (r cos θ) for each ground return
    eps = np.full(len(xyz), np.nan)
    r_cos = np.linalg.norm(xyz[ground], axis=1) * np.cos(elevation[ground])
    eps[ground] = -(xyz[ground, 2] - ground_z[ground]) / r_cos
    elevation_error = np.array(
        [
            np.degrees(np.median(eps[run][ground[run]])) if ground[run].sum() >= min_ground else np.nan
            for run in runs
        ]
    )
    # the plane's height is fitted, not known: a height off by δh reads as ε = δh·tan(−θ)/h, and a
    # mean error as a constant, so both are taken out (least squares over the lines on the ground)
    seen = np.isfinite(elevation_error)
    if seen.sum() > 2:
        basis = np.column_stack([np.ones(seen.sum()), np.tan(-np.radians(line_elevation[seen]))])
        elevation_error[seen] -= basis @ np.linalg.lstsq(basis, elevation_error[seen], rcond=None)[0]
    above = xyz[:, 2] > np.median(ground_z[ground]) + 0.4 if ground.any() else np.ones(len(xyz), bool)
    by_azimuth = [run[np.argsort(azimuth[run])] for run in runs]
    steps = np.array(
        [
            _azimuth_step(lower, upper, azimuth, rho, above, min_pairs)
            for lower, upper in zip(by_azimuth[:-1], by_azimuth[1:], strict=True)
        ]
    )
    return LaserAngles(line_elevation, elevation_error, steps)


def _ground(xyz: np.ndarray, rho: np.ndarray, range_m: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The ground plane's height under every return ``(N,)`` and which returns lie on it ``(N,)``:
    a plane ``z = a x + b y + c`` fitted to the lowest returns within ``range_m``, its inliers
    narrowed from 50 to 8 cm."""
    near = (rho > range_m[0]) & (rho < range_m[1])
    candidate = near & (xyz[:, 2] < np.percentile(xyz[near, 2], 40)) if near.any() else near
    A = np.column_stack([xyz[:, 0], xyz[:, 1], np.ones(len(xyz))])
    inlier = candidate.copy()
    coef = np.zeros(3)
    for tol in (0.5, 0.2, 0.08):
        if inlier.sum() < 3:
            return A @ coef, np.zeros(len(xyz), bool)
        coef = np.linalg.lstsq(A[inlier], xyz[inlier, 2], rcond=None)[0]
        inlier = candidate & (np.abs(A @ coef - xyz[:, 2]) < tol)
    return A @ coef, inlier


def _azimuth_step(
    lower: np.ndarray,
    upper: np.ndarray,
    azimuth: np.ndarray,
    rho: np.ndarray,
    above: np.ndarray,
    min_pairs: int,
) -> float:
    """``η_upper − η_lower`` (°) of two neighbouring lines (indices sorted by azimuth): ``upper``'s
    horizontal distance against ``lower``'s interpolated at the same azimuth, regressed on
    ``lower``'s slope ``dρ/da`` where the surface is continuous, above the ground and oblique to
    the rays (slope at least ``0.2 ρ`` per radian); a robust (Huber) slope, NaN with too few."""
    if len(lower) < 4 or len(upper) < 1:
        return np.nan
    a, r = azimuth[lower], rho[lower]
    j = np.clip(np.searchsorted(a, azimuth[upper]), 2, len(lower) - 2)
    step, wide = a[j] - a[j - 1], a[j + 1] - a[j - 2]
    slope = (r[j + 1] - r[j - 2]) / np.where(wide > 0, wide, 1.0)
    t = (azimuth[upper] - a[j - 1]) / np.where(step > 0, step, 1.0)
    interpolated = r[j - 1] + t * (r[j] - r[j - 1])
    difference = rho[upper] - interpolated
    usable = (
        (step > 0)
        & (step < np.radians(0.5))
        & (wide < np.radians(1.0))
        & (np.abs(r[j] - r[j - 1]) < 0.05 * np.minimum(r[j], r[j - 1]))  # one surface between them
        & (np.abs(r[j + 1] - r[j - 2]) < 0.1 * r[j - 2])
        & above[upper]
        & above[lower[j]]
        & (np.abs(difference) < 0.02 * interpolated + 0.05)
        & (np.abs(slope) > 0.2 * interpolated)
    )
    if usable.sum() < min_pairs:
        return np.nan
    s, d = slope[usable], difference[usable]
    weight = np.ones(len(s))
    for _ in range(5):  # Huber IRLS at 1.5 median absolute residuals
        estimate = np.sum(weight * s * d) / np.sum(weight * s * s)
        residual = np.abs(d - s * estimate)
        c = 1.5 * np.median(residual) + 1e-12
        weight = np.minimum(1.0, c / np.maximum(residual, 1e-12))
    return float(np.degrees(estimate))
