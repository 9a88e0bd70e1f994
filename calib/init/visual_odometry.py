"""Monocular visual odometry with OpenCV: relative camera motions up to scale.

Corners (Shi–Tomasi) are tracked with pyramidal Lucas–Kanade (forward–backward checked) from a
keyframe to the following frames until their displacement (a high percentile: distant corners
hardly move) reaches ``min_parallax_px``
(frames with too little parallax are skipped); the essential matrix is estimated with RANSAC and
decomposed into ``T_cam_j_cam_i`` with a unit translation.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

__all__ = ["CameraMotion", "VisualOdometryConfig", "visual_odometry"]


class VisualOdometryConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    max_corners: int = Field(1500, ge=8)
    corner_quality: float = Field(0.005, gt=0, le=1)
    corner_distance_px: float = Field(7.0, gt=0)
    min_parallax_px: float = Field(10.0, ge=0, description="flow a keyframe pair needs (see percentile)")
    parallax_percentile: float = Field(
        80.0,
        ge=0,
        le=100,
        description="which percentile of the tracks' flow is the parallax (near ones move)",
    )
    max_skip: int = Field(15, ge=1, description="frames tracked at most before giving up on a keyframe")
    track_error_px: float = Field(0.5, gt=0, description="forward–backward disagreement allowed")
    ransac_threshold_px: float = Field(0.5, gt=0)
    min_inliers: int = Field(60, ge=8)


@dataclass(frozen=True)
class CameraMotion:
    """``T_cam_j_cam_i (4, 4)`` from frame ``i`` to ``j`` with a unit translation."""

    i: int
    j: int
    T: np.ndarray
    inliers: int
    parallax_px: float


def _gray(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image


def _track(prev: np.ndarray, nxt: np.ndarray, corners: np.ndarray, max_error: float) -> np.ndarray:
    """Corners ``(N, 1, 2)`` float32 tracked into ``nxt``; NaN where lost or inconsistent."""
    params = {"winSize": (21, 21), "maxLevel": 3}
    fwd, ok1, _ = cv2.calcOpticalFlowPyrLK(prev, nxt, corners, None, **params)
    back, ok2, _ = cv2.calcOpticalFlowPyrLK(nxt, prev, fwd, None, **params)
    good = (ok1[:, 0] == 1) & (ok2[:, 0] == 1) & (np.linalg.norm((back - corners)[:, 0], axis=1) < max_error)
    out = fwd.copy()
    out[~good] = np.nan
    return out


def visual_odometry(
    images: Iterable[np.ndarray], K: np.ndarray, config: VisualOdometryConfig = VisualOdometryConfig()
) -> list[CameraMotion]:
    """Relative motions between keyframes of an image sequence.

    Args:
        images: ``(H, W, 3)`` uint8 RGB (or ``(H, W)`` gray), undistorted, in time order.
        K: ``(3, 3)`` intrinsics.

    Returns:
        One :class:`CameraMotion` per keyframe pair with enough parallax and inliers; a keyframe
        that finds none within ``max_skip`` frames is replaced by the latest frame.
    """
    motions: list[CameraMotion] = []
    key_index, key_image, corners = 0, None, None
    for index, image in enumerate(images):
        gray = _gray(image)
        if key_image is not None:
            tracked = _track(key_image, gray, corners, config.track_error_px)
            alive = np.isfinite(tracked[:, 0, 0])
            flow = np.linalg.norm((tracked - corners)[alive, 0], axis=1)
            parallax = float(np.percentile(flow, config.parallax_percentile)) if alive.any() else 0.0
            motion = None
            if parallax >= config.min_parallax_px and alive.sum() >= config.min_inliers:
                motion = _relative_pose(corners[alive, 0], tracked[alive, 0], K, config)
            if motion is not None:
                motions.append(CameraMotion(key_index, index, motion[0], motion[1], parallax))
            if motion is not None or index - key_index >= config.max_skip or alive.sum() < config.min_inliers:
                key_image = None
        if key_image is None:
            key_index, key_image = index, gray
            corners = cv2.goodFeaturesToTrack(
                gray, config.max_corners, config.corner_quality, config.corner_distance_px
            )
            if corners is None or len(corners) < config.min_inliers:
                key_image = None
    return motions


def _relative_pose(
    p_i: np.ndarray, p_j: np.ndarray, K: np.ndarray, config: VisualOdometryConfig
) -> tuple[np.ndarray, int] | None:
    """``T_cam_j_cam_i`` (unit translation) and the inlier count, or ``None`` when too few."""
    E, mask = cv2.findEssentialMat(p_i, p_j, K, cv2.RANSAC, 0.999, config.ransac_threshold_px)
    if E is None or E.shape != (3, 3):
        return None
    inliers, R, t, _ = cv2.recoverPose(E, p_i, p_j, K, mask=mask)
    if inliers < config.min_inliers:
        return None
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t.ravel() / np.linalg.norm(t)
    return T, int(inliers)
