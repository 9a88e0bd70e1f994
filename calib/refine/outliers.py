"""What Stage 4 leaves out on real frames: points too near the sensor (the ego-vehicle, a mount),
points on moving things where consecutive scans show them (:mod:`calib.moving`), whole frames
whose residuals disagree with the others (a frame dominated by moving objects, a blurred or
overexposed image), and single correspondences far off the fitted extrinsic (moving
objects, occlusion halos, edges the LiDAR and the camera do not share).

The robust loss of Eq. 4 already down-weights outliers; these rules remove what it cannot: a
frame whose matches are consistently wrong pulls the estimate however each point is weighted,
and a hard trim after the first fit lets the second fit see only points the model explains.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from calib.moving import MovingConfig

__all__ = ["OutlierConfig", "frame_outliers", "near_points", "trim_points"]

RAYLEIGH_MEDIAN = float(np.sqrt(2 * np.log(2)))
"""Median of the norm of a 2-D residual with unit standard deviation per axis (≈ 1.1774)."""


class OutlierConfig(BaseModel):
    """``outliers:`` in ``calibrate.yaml``."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    min_range_m: float = Field(
        1.5, ge=0, description="points nearer the LiDAR than this are dropped (ego-vehicle, mount)"
    )
    frame_factor: float = Field(
        2.5,
        gt=1,
        description="a frame whose median residual exceeds this times the median over frames "
        "(and frame_floor_px) sits out the pass",
    )
    frame_floor_px: float = Field(3.0, ge=0, description="a frame is never an outlier below this median")
    point_sigmas: float = Field(
        3.0,
        gt=0,
        description="after the first fit, correspondences farther than this many robust standard "
        "deviations (and point_floor_px) from it are dropped and the fit is repeated (0.1 % of "
        "Gaussian residuals pass 3.7)",
    )
    point_floor_px: float = Field(
        2.0, ge=0, description="a correspondence this close to the fit is always kept"
    )
    moving: MovingConfig = Field(
        MovingConfig(),
        description="points on things that move, found from the scans before and after each frame "
        "(calib.moving): an oncoming car seen 5 ms later pulls δt and the translation along the drive",
    )


def near_points(points_lidar: np.ndarray, min_range_m: float) -> np.ndarray:
    """``(N,)`` bool: points of ``points_lidar (N, 3+)`` nearer the LiDAR's origin than ``min_range_m``."""
    return np.linalg.norm(np.asarray(points_lidar)[:, :3], axis=1) < min_range_m


def frame_outliers(medians_px: np.ndarray, factor: float, floor_px: float) -> np.ndarray:
    """``(F,)`` bool: frames whose median residual ``medians_px (F,)`` exceeds both ``factor``
    times the median over the frames and ``floor_px``. At most half the frames are called
    outliers (the median is their reference), and none when fewer than three frames vote."""
    medians = np.asarray(medians_px, np.float64)
    if len(medians) < 3:
        return np.zeros(len(medians), bool)
    return medians > max(factor * float(np.median(medians)), floor_px)


def trim_points(residual_px: np.ndarray, sigmas: float, floor_px: float) -> np.ndarray:
    """``(N,)`` bool, the correspondences to keep: post-fit residual norms ``residual_px (N,)``
    within ``sigmas`` robust standard deviations, or within ``floor_px``.

    The per-axis standard deviation is estimated from the median norm (a 2-D Gaussian's norm has
    median ``σ · √(2 ln 2)``), so the outliers being trimmed do not inflate it.
    """
    r = np.asarray(residual_px, np.float64)
    if len(r) == 0:
        return np.zeros(0, bool)
    sigma = float(np.median(r)) / RAYLEIGH_MEDIAN
    return r <= max(sigmas * sigma, floor_px)
