"""Stage 2 interface: a matcher turns a frame and an extrinsic into cross-modal correspondences.

Each visible LiDAR point ``p_i`` projects to ``u_i = π(T_cam_lidar · p_i)``; the matcher predicts
where it really lies in the RGB image, ``ũ_i = u_i + f_i`` (CMRNext's flow from the projected
LiDAR image to the RGB image). Stages 3 and 4 read only :class:`Correspondences`, so any matcher
(the training-free :class:`~calib.edge_matcher.EdgeMatcher`, a learned flow network) plugs in.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from calib.data.types import Frame

__all__ = ["Correspondences", "Matcher"]


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
        """Correspondences of ``frame`` under ``T_cam_lidar (4, 4)``."""
        ...
