"""A global, dense-free measure of how well an extrinsic aligns a scan with its image: the mean
image edge strength under the projected LiDAR occluding contours (depth discontinuities), read
from the image's edge map blurred at a scale ``σ``. A correct extrinsic puts contours on edges
(Levinson & Thrun's edge alignment; koide3's tool uses NID the same way); the blur widens the
basin, so a pyramid of ``σ`` from tens of pixels down to one or two finds the peak from far away.

Stage 4's global coarse search (:mod:`calib.refine.global_search`) climbs this score, and
``check`` compares it around a given extrinsic. Every frame's contours and blurred edge maps are
stacked, so one call scores ``C`` candidate extrinsics over all frames at once.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from calib.data.types import Frame
from calib.errors import DataError
from calib.features import depth_discontinuities
from calib.match.edge_matcher import image_edges

__all__ = ["SCORE_KINDS", "EdgeAlignment", "contour_points", "edge_strength"]

SCORE_KINDS = ("magnitude", "orientation")


def edge_strength(image: np.ndarray, blur_px: float = 1.0) -> np.ndarray:
    """Grey gradient magnitude of an RGB image, ``(H, W)`` float32 in [0, 1] (1 at and above the
    99th percentile)."""
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)
    if blur_px > 0:
        grey = cv2.GaussianBlur(grey, (0, 0), blur_px)
    magnitude = np.hypot(cv2.Sobel(grey, cv2.CV_32F, 1, 0), cv2.Sobel(grey, cv2.CV_32F, 0, 1))
    return np.clip(magnitude / max(float(np.percentile(magnitude, 99)), 1e-6), 0.0, 1.0)


def contour_points(points: np.ndarray, limit: int, rng: np.random.Generator) -> np.ndarray:
    """``(M, 3)`` occluding-contour points of a scan (the nearer side of each depth
    discontinuity, :func:`calib.features.depth_discontinuities`), at most ``limit`` of them drawn
    at random."""
    nearer, _ = depth_discontinuities(points)
    if len(nearer) > limit:
        nearer = rng.choice(nearer, limit, replace=False)
    return np.asarray(points[np.sort(nearer), :3], np.float64)


class EdgeAlignment:
    """Edge-alignment score of extrinsics over a set of frames sharing one ``K``.

    Args:
        frames: the frames. max_points: contour points kept per frame. seed: their draw.
        kind: the edge map, ``magnitude`` or ``orientation`` (module docstring).
    """

    def __init__(
        self, frames: Sequence[Frame], max_points: int = 1500, seed: int = 0, kind: str = "magnitude"
    ) -> None:
        if not frames:
            raise DataError("frames", "edge alignment needs at least one frame")
        if kind not in SCORE_KINDS:
            raise DataError("kind", f"edge alignment kind must be one of {SCORE_KINDS}, got {kind!r}")
        self.K = torch.as_tensor(frames[0].K, dtype=torch.float64)
        self.size = frames[0].image_size
        rng = np.random.default_rng(seed)
        clouds = [contour_points(f.points, max_points, rng) for f in frames]
        count = max(1, max(len(c) for c in clouds))
        self.points = torch.zeros(len(frames), count, 3, dtype=torch.float64)
        self.mask = torch.zeros(len(frames), count, dtype=torch.bool)
        for k, cloud in enumerate(clouds):
            self.points[k, : len(cloud)] = torch.from_numpy(cloud)
            self.mask[k, : len(cloud)] = True
        self.contours = [len(c) for c in clouds]
        self.edges = [
            edge_strength(f.image) if kind == "magnitude" else image_edges(f.image)[0] for f in frames
        ]
        self._maps: dict[float, torch.Tensor] = {}

    def maps(self, sigma_px: float) -> torch.Tensor:
        """``(F, 1, H, W)`` edge maps blurred by ``σ`` and renormalised to a peak of 1 (of ``|·|``:
        the orientation map is signed)."""
        key = round(float(sigma_px), 3)
        if key not in self._maps:
            blurred = []
            for e in self.edges:
                b = cv2.GaussianBlur(e, (0, 0), sigma_px) if sigma_px > 0 else e
                blurred.append(b / max(float(np.abs(b).max()), 1e-6))
            self._maps[key] = torch.from_numpy(np.stack(blurred))[:, None].float()
        return self._maps[key]

    def per_frame(self, T_cam_lidar: torch.Tensor, sigma_px: float) -> torch.Tensor:
        """``(C, F)`` mean blurred edge strength under each frame's contour points for each of
        the ``(C, 4, 4)`` (or one ``(4, 4)``) extrinsics; points outside the image or behind the
        camera count as 0."""
        T = torch.as_tensor(T_cam_lidar, dtype=torch.float64)
        T = T[None] if T.ndim == 2 else T
        H, W = self.size
        q = torch.einsum("cij,fnj->cfni", T[:, :3, :3], self.points) + T[:, None, None, :3, 3]
        z = q[..., 2]
        uvw = q @ self.K.T
        u = uvw[..., 0] / z.clamp_min(1e-3)
        v = uvw[..., 1] / z.clamp_min(1e-3)
        grid = torch.stack([2 * u / (W - 1) - 1, 2 * v / (H - 1) - 1], -1).float()  # (C, F, N, 2)
        sampled = F.grid_sample(
            self.maps(sigma_px), grid.permute(1, 0, 2, 3), align_corners=True, padding_mode="zeros"
        )[:, 0]  # (F, C, N)
        sampled = torch.where((z.permute(1, 0, 2) > 0.5) & self.mask[:, None], sampled.double(), 0.0)
        counts = self.mask.sum(1).clamp_min(1).double()
        return (sampled.sum(2) / counts[:, None]).T

    def __call__(self, T_cam_lidar: torch.Tensor, sigma_px: float) -> torch.Tensor:
        """``(C,)`` the score over all frames (their mean)."""
        return self.per_frame(T_cam_lidar, sigma_px).mean(1)
