"""Stage 2 interface: a matcher turns a frame and an extrinsic into cross-modal correspondences.

Each visible LiDAR point ``p_i`` projects to ``u_i = π(T_cam_lidar · p_i)``; the matcher predicts
where it really lies in the RGB image, ``ũ_i = u_i + f_i`` (CMRNext's flow from the projected
LiDAR image to the RGB image). Stages 3 and 4 read only :class:`Correspondences`, so any matcher
(the training-free :class:`~calib.match.edge_matcher.EdgeMatcher`, a learned flow network) plugs in.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from calib.data.types import Frame

__all__ = ["Correspondences", "Matcher", "WorkingView", "working_view"]


@dataclass(frozen=True)
class Correspondences:
    """2D–3D correspondences of one frame under one extrinsic.

    Attributes:
        index: ``(N,)`` int64 indices into the frame's points.
        points_lidar: ``(N, 3)`` float64 points in the LiDAR frame.
        uv: ``(N, 2)`` float64 sub-pixel projections ``π(T · p)`` under the extrinsic used.
        uv_matched: ``(N, 2)`` float64 matched image locations ``ũ``.
        confidence: ``(N,)`` float32 in [0, 1], how sharply the match is determined.
        image_size: ``(H, W)`` of the frame's image.
    """

    index: np.ndarray
    points_lidar: np.ndarray
    uv: np.ndarray
    uv_matched: np.ndarray
    confidence: np.ndarray
    image_size: tuple[int, int]

    def __post_init__(self) -> None:
        n = len(self.index)
        shapes = {"points_lidar": (n, 3), "uv": (n, 2), "uv_matched": (n, 2), "confidence": (n,)}
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"{name} must be {shape}, got {getattr(self, name).shape}")

    def __len__(self) -> int:
        return len(self.index)

    @property
    def residual(self) -> np.ndarray:
        """``f = ũ − u``, ``(N, 2)`` pixels."""
        return self.uv_matched - self.uv

    @classmethod
    def concatenate(cls, parts: Sequence[Correspondences]) -> Correspondences:
        """One frame's correspondences from several matchings (of one image size), in order."""
        if not parts or any(p.image_size != parts[0].image_size for p in parts):
            raise ValueError("concatenate needs at least one part, all of one image size")
        return cls(
            *(
                np.concatenate([getattr(p, name) for p in parts])
                for name in ("index", "points_lidar", "uv", "uv_matched", "confidence")
            ),
            parts[0].image_size,
        )

    def subset(self, mask: np.ndarray) -> Correspondences:
        """The correspondences selected by a boolean mask or an index array."""
        return Correspondences(
            self.index[mask],
            self.points_lidar[mask],
            self.uv[mask],
            self.uv_matched[mask],
            self.confidence[mask],
            self.image_size,
        )


class Matcher(Protocol):
    """Anything that predicts image-plane residuals for the projected points of a frame."""

    name: str

    def match(self, frame: Frame, T_cam_lidar: np.ndarray) -> Correspondences:
        """Correspondences of ``frame`` under ``T_cam_lidar (4, 4)`` (called from several threads
        at once by :func:`match_frames`)."""
        ...


def match_frames(matcher: Matcher, frames: Sequence[Frame], T_cam_lidar: np.ndarray) -> list[Correspondences]:
    """``matcher.match`` of every frame under ``T_cam_lidar (4, 4)`` (a rig's ``T_rig_lidar``
    where the frames' cameras sit in one: each frame matched under its camera's extrinsic), as
    many at once as the machine has cores (the edge matcher's numpy and OpenCV work runs outside
    Python's lock). The edge matcher is bound by memory traffic: on this project's 2-core machine
    two threads match ten full-resolution frames 1.24x as fast as one, and two processes gain the
    same."""

    def one(frame: Frame) -> Correspondences:
        return matcher.match(frame, frame.calibration.camera_extrinsic(T_cam_lidar))

    workers = min(len(frames), os.cpu_count() or 1)
    if workers <= 1:
        return [one(frame) for frame in frames]
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(one, frames))


@dataclass(frozen=True)
class WorkingView:
    """A frame's image at the resolution a matcher works in.

    Attributes:
        image: ``(h, w, 3)`` uint8, resampled (area) where the frame's focal length is longer.
        K: ``(3, 3)`` intrinsics of ``image``.
        scale: ``(2,)`` exact per-axis factors (x, y) of the resize.
    """

    image: np.ndarray
    K: np.ndarray
    scale: np.ndarray

    def to_frame(self, uv: np.ndarray) -> np.ndarray:
        """``(N, 2)`` working pixels → the frame's pixels (pixel centres map onto pixel centres)."""
        return (uv + 0.5) / self.scale - 0.5


def working_view(frame: Frame, focal_px: float) -> WorkingView:
    """The frame's image resampled so that its focal length is at most ``focal_px``, so a matcher's
    pixel parameters (or a network's receptive field) mean the same angles on every camera."""
    H, W = frame.image_size
    factor = min(1.0, focal_px / float(frame.K[0, 0]))
    size = (max(1, round(H * factor)), max(1, round(W * factor)))
    # pixel centres: u' = (u + 0.5) s' − 0.5 with the exact per-axis factor s' of the resize
    scale = np.array([size[1] / W, size[0] / H])
    K = frame.K.copy()
    K[:2] *= scale[:, None]
    K[:2, 2] += 0.5 * scale - 0.5
    if size == (H, W):
        return WorkingView(frame.image, K, scale)
    return WorkingView(cv2.resize(frame.image, size[::-1], interpolation=cv2.INTER_AREA), K, scale)
