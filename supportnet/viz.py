"""Pictures people look at: LiDAR projections coloured by depth on the image."""

from __future__ import annotations

import cv2
import numpy as np
from matplotlib import colormaps

from calib.projection import ProjectedScan

__all__ = ["colourise", "draw_projection"]


def colourise(values: np.ndarray, cmap: str = "viridis") -> np.ndarray:
    """``values (...)`` in [0, 1] (clipped) as ``(..., 3)`` uint8 RGB of a matplotlib colour map."""
    return (colormaps[cmap](np.clip(values, 0, 1))[..., :3] * 255).astype(np.uint8)


def draw_projection(
    image: np.ndarray, projected: ProjectedScan, max_depth: float = 40.0, radius: int | None = None
) -> np.ndarray:
    """The visible points of a scan drawn on ``image (H, W, 3)`` uint8, turbo-coloured by depth
    (near = blue, ``max_depth`` and beyond = red). Returns a new image."""
    out = image.copy()
    colours = colourise(projected.depth / max_depth, "turbo")
    radius = radius if radius is not None else max(1, round(image.shape[1] / 1000))
    for (u, v), colour in zip(np.round(projected.uv).astype(int), colours, strict=True):
        cv2.circle(out, (int(u), int(v)), radius, tuple(int(c) for c in colour), -1)
    return out
