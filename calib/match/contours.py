"""Occluding contours of a scan against the image's edges: a correspondence-free alignment score.

Samples are taken from each scan once, under a given extrinsic ``T`` (they are points of the
scene, so any other extrinsic moves them as it moves the scan):

- *vertical edges*: depth jumps between neighbouring returns of a scan line
  (:func:`calib.features.depth_discontinuities`), placed midway between the two returns at the
  nearer range; read against the horizontal image gradient ``|∂I/∂u|``;
- *horizontal edges*: depth jumps between vertically neighbouring returns (the top or bottom of an
  object; one return per ring in each narrow azimuth column) and silhouettes against no return
  (the sky), placed half a ring spacing above the last return; read against ``|∂I/∂v|``.

A scan line is the stored order (KITTI's Velodyne scans; the real-fixture converters put others
in that order). The score of an extrinsic, per frame, is the mean blurred, normalised directional
edge strength under its samples, half each kind (Levinson & Thrun's edge alignment, with the two
directions kept apart so that texture of the wrong orientation does not count). Blur scales are
view angles, so every camera is treated alike. Used by the check (:mod:`calib.verify`) and by
Stage 4's contour refinement (:mod:`calib.refine.contour_refine`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence as FrameList

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field, PositiveInt

from calib.data.rig import rig_poses
from calib.data.types import Frame
from calib.errors import DataError, NumericalError
from calib.features import depth_discontinuities

__all__ = ["ContourConfig", "ContourScore", "horizontal_edges", "vertical_edges"]


class ContourConfig(BaseModel):
    """Which contour samples :class:`ContourScore` takes."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    view_margin: float = Field(0.15, ge=0, description="contours are taken this far outside the image")
    max_samples: int = Field(4000, ge=10, description="samples of each kind kept per frame")
    min_samples: int = Field(20, ge=1, description="a kind with fewer samples in a frame is left out")
    both_sides: bool = Field(
        True, description="a contour's far side must continue a surface too (else only its near side)"
    )
    blocks: tuple[PositiveInt, PositiveInt] = Field(
        (8, 4), description="image cells across and down, per frame (the units a bootstrap resamples)"
    )


def _spherical(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    azimuth = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0]))
    elevation = np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))
    return azimuth, elevation, np.linalg.norm(xyz, axis=1)


def _points(azimuth: np.ndarray, elevation: np.ndarray, rng: np.ndarray) -> np.ndarray:
    a, e = np.radians(azimuth), np.radians(elevation)
    return np.column_stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)]) * rng[:, None]


def horizontal_edges(
    points_lidar: np.ndarray,
    min_jump_m: float = 0.5,
    rel_jump: float = 0.1,
    max_azimuth_gap_deg: float = 1.0,
    max_elevation_gap_deg: float = 0.3,
    surface_tol: float = 0.05,
    both_sides: bool = True,
) -> np.ndarray:
    """Samples of the image's *vertical* edges: each depth jump along a scan line (stored order;
    :func:`calib.features.depth_discontinuities`' rule, whose two sides each continue a surface,
    or with ``both_sides=False`` only the nearer side), midway in azimuth between its two returns,
    at the nearer range. ``(M, 3)`` LiDAR frame."""
    xyz = np.asarray(points_lidar, np.float64)[:, :3]
    if len(xyz) < 3:
        return np.zeros((0, 3))
    if both_sides:
        nearer, farther = depth_discontinuities(
            xyz, None, min_jump_m, rel_jump, max_azimuth_gap_deg, max_elevation_gap_deg, surface_tol
        )
    else:
        azimuth, elevation, rng = _spherical(xyz)
        a, b = np.arange(len(xyz) - 1), np.arange(1, len(xyz))
        d_az = np.abs((azimuth[b] - azimuth[a] + 180.0) % 360.0 - 180.0)
        neighbours = (d_az < max_azimuth_gap_deg) & (
            np.abs(elevation[b] - elevation[a]) < max_elevation_gap_deg
        )
        closer = np.minimum(rng[a], rng[b])
        jump = neighbours & (np.abs(rng[a] - rng[b]) > np.maximum(min_jump_m, rel_jump * closer))
        smooth = neighbours & (np.abs(rng[a] - rng[b]) <= surface_tol * closer)
        k = np.nonzero(jump)[0]
        a_nearer = rng[a[k]] < rng[b[k]]
        before = np.concatenate([[False], smooth])[k]  # a[k] continues backwards
        after = np.concatenate([smooth, [False]])[k + 1]  # b[k] continues forwards
        keep = np.where(a_nearer, before, after)
        nearer = np.where(a_nearer, a[k], b[k])[keep]
        farther = np.where(a_nearer, b[k], a[k])[keep]
    azimuth, elevation, rng = _spherical(xyz)
    gap = (azimuth[farther] - azimuth[nearer] + 180.0) % 360.0 - 180.0
    return _points(azimuth[nearer] + 0.5 * gap, elevation[nearer], rng[nearer])


def vertical_edges(
    points_lidar: np.ndarray,
    column_deg: float = 0.4,
    same_ring_deg: float = 0.1,
    max_gap_deg: float = 3.0,
    min_jump_m: float = 0.5,
    rel_jump: float = 0.1,
    surface_tol: float = 0.05,
    both_sides: bool = True,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Samples of the image's *horizontal* edges.

    The scan is cut into azimuth columns ``column_deg`` wide; in each, returns closer than
    ``same_ring_deg`` in elevation count as one ring (the nearest is kept), and consecutive rings
    are vertical neighbours when less than ``max_gap_deg`` apart. A jump in range between them
    (more than ``max(min_jump_m, rel_jump · nearer)``) whose two sides each continue a surface
    (their outer neighbours within ``surface_tol``; ``both_sides=False``: the nearer side) is an
    occluding contour, sampled midway in
    elevation at the nearer range. A column's topmost return that continues a surface below it,
    at least two ring spacings under the scan's top, has nothing above it: a silhouette against
    the sky (or glass), sampled half a ring spacing above it.

    Returns:
        ``contours (M, 3)``, ``silhouettes (S, 3)`` (LiDAR frame) and the median ring spacing (°).
    """
    xyz = np.asarray(points_lidar, np.float64)[:, :3]
    if len(xyz) < 3:
        return np.zeros((0, 3)), np.zeros((0, 3)), 1.0
    azimuth, elevation, rng = _spherical(xyz)
    column = np.floor(azimuth / column_deg).astype(np.int64)
    order = np.lexsort((elevation, column))
    c, e = column[order], elevation[order]
    first = np.concatenate([[True], (c[1:] != c[:-1]) | (e[1:] - e[:-1] >= same_ring_deg)])
    group = np.cumsum(first) - 1  # one group per ring and column, by elevation within a column
    by_range = np.lexsort((rng[order], group))
    # each group's nearest return: a column across an object's side keeps the object, ring after
    # ring, instead of alternating between it and what lies behind
    ring = order[by_range[np.concatenate([[True], group[by_range][1:] != group[by_range][:-1]])]]
    c, e = column[ring], elevation[ring]
    a, b = ring[:-1], ring[1:]  # b is above a
    gap = e[1:] - e[:-1]
    neighbours = (c[1:] == c[:-1]) & (gap < max_gap_deg)
    spacing = float(np.median(gap[neighbours])) if neighbours.any() else 1.0
    closer = np.minimum(rng[a], rng[b])
    jump = neighbours & (np.abs(rng[a] - rng[b]) > np.maximum(min_jump_m, rel_jump * closer))
    smooth = neighbours & (np.abs(rng[a] - rng[b]) <= surface_tol * closer)
    k = np.nonzero(jump)[0]
    below = np.concatenate([[False], smooth])[k]  # ring[k - 1] continues ring[k]
    above = np.concatenate([smooth, [False]])[k + 1]  # ring[k + 2] continues ring[k + 1]
    a_nearer = rng[a[k]] < rng[b[k]]
    keep = below & above if both_sides else np.where(a_nearer, below, above)
    k, a_nearer = k[keep], a_nearer[keep]
    nearer = np.where(a_nearer, a[k], b[k])
    farther = np.where(a_nearer, b[k], a[k])
    contours = _points(azimuth[nearer], 0.5 * (elevation[nearer] + elevation[farther]), rng[nearer])
    top = np.percentile(elevation, 99.5)
    last = np.nonzero(np.concatenate([~neighbours, [True]]))[0]
    last = last[last > 0]
    sky = ring[last[smooth[last - 1] & (e[last] < top - 2 * spacing)]]
    silhouettes = _points(azimuth[sky], elevation[sky] + 0.5 * spacing, rng[sky])
    return contours, silhouettes, spacing


def in_view(
    points: np.ndarray, T: np.ndarray, K: np.ndarray, size: tuple[int, int], margin: float
) -> np.ndarray:
    """``(N,)`` bool: points of ``points (N, 3+)`` at least 0.5 m in front of the camera under ``T``
    whose projection falls inside the ``(H, W)`` image grown by ``margin`` of its size on each side."""
    q = np.asarray(points[:, :3], np.float64) @ T[:3, :3].T + T[:3, 3]
    z = q[:, 2]
    uvw = q @ K.T
    u, v = uvw[:, 0] / np.maximum(z, 1e-3), uvw[:, 1] / np.maximum(z, 1e-3)
    H, W = size
    return (z > 0.5) & (u > -margin * W) & (u < (1 + margin) * W) & (v > -margin * H) & (v < (1 + margin) * H)


def _directional_edges(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``|∂I/∂u|`` and ``|∂I/∂v|`` of the grey image (σ = 1 px first), each in [0, 1] (1 at and
    above its 99th percentile)."""
    grey = cv2.GaussianBlur(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32), (0, 0), 1.0)
    out = []
    for dx, dy in ((1, 0), (0, 1)):
        g = np.abs(cv2.Sobel(grey, cv2.CV_32F, dx, dy))
        out.append(np.clip(g / max(float(np.percentile(g, 99)), 1e-6), 0.0, 1.0))
    return out[0], out[1]


class ContourScore:
    """Edge alignment of the contour samples of ``frames`` (of one camera, or of a rig's cameras:
    each frame then projects through its camera's ``T_cam_rig · T``, with its own ``K``; blur
    scales in pixels are the first frame's), taken under ``T``.

    Attributes:
        counts: per frame ``{kind: samples}`` (vertical edges, horizontal edges, silhouettes).
        points: ``(2, F, N, 3)`` the samples of each kind (vertical edges; horizontal edges and
            silhouettes) per frame, LiDAR frame, zero-padded.
        weights: ``(2, F, N)`` float64: the sample's share of the score (0 for padding or a kind
            left out), so that the score is a weighted sum (total 1).
        block: ``(2, F, N)`` int64: the sample's image block (unique over frames and kinds).
    """

    def __init__(
        self, frames: FrameList[Frame], T: np.ndarray, config: ContourConfig | None = None, seed: int = 0
    ) -> None:
        config = config if config is not None else ContourConfig()
        if not frames:
            raise DataError("frames", "the check needs at least one frame")
        K = frames[0].K
        self._rig = torch.as_tensor(rig_poses(frames))  # (F, 4, 4) T_cam_rig, the identity alone
        if frames[0].calibration.T_cam_rig is None and any(
            not np.allclose(f.K, K) or f.image_size != frames[0].image_size for f in frames
        ):
            raise DataError("frames", "have different intrinsics or image sizes; check one camera at a time")
        rng = np.random.default_rng(seed)
        self.K = torch.stack([torch.as_tensor(f.K, dtype=torch.float64) for f in frames])  # (F, 3, 3)
        self.focal = float(K[0, 0])
        self._blur = [float(f.K[0, 0]) / self.focal for f in frames]
        self.sizes = torch.tensor([f.image_size for f in frames], dtype=torch.float64)  # (F, 2) H, W
        # maps of several sizes (a rig's cameras) share the largest, padded with zeros (outside: 0)
        self.size = tuple(max(f.image_size[a] for f in frames) for a in (0, 1))
        self.counts: list[dict[str, int]] = []
        samples: list[tuple[np.ndarray, np.ndarray]] = []
        self._edges = []
        for frame in frames:
            T_cam = frame.calibration.camera_extrinsic(T)
            keep = in_view(frame.points, T_cam, frame.K, frame.image_size, config.view_margin)
            xyz = np.asarray(frame.points[keep, :3], np.float64)
            h = horizontal_edges(xyz, both_sides=config.both_sides)
            v, sky, _ = vertical_edges(xyz, both_sides=config.both_sides)
            self.counts.append(
                {"vertical_edges": len(h), "horizontal_edges": len(v), "silhouettes": len(sky)}
            )
            kinds = [h, np.concatenate([v, sky])]
            kinds = [
                x[np.sort(rng.choice(len(x), config.max_samples, replace=False))]
                if len(x) > config.max_samples
                else x
                for x in kinds
            ]
            samples.append((kinds[0], kinds[1]))
            self._edges.append(_directional_edges(frame.image))
        n = max(1, max(len(x) for pair in samples for x in pair))
        count = len(frames)
        self.points = torch.zeros(2, count, n, 3, dtype=torch.float64)
        self.weights = torch.zeros(2, count, n, dtype=torch.float64)
        for f, pair in enumerate(samples):
            used = [j for j in range(2) if len(pair[j]) >= config.min_samples]
            for j in used:
                m = len(pair[j])
                self.points[j, f, :m] = torch.from_numpy(pair[j])
                self.weights[j, f, :m] = 1.0 / (len(used) * m)
        used_frames = int((self.weights.sum((0, 2)) > 0).sum())
        if used_frames == 0:
            raise NumericalError(
                f"too few contour samples to check (fewer than {config.min_samples} of each kind per "
                "frame): the scans show no occluding contours in the image, or are not stored scan "
                "line by scan line"
            )
        self.weights /= used_frames
        self.block = self._blocks(T, config.blocks)
        self._maps: dict[float, list[torch.Tensor]] = {}

    def _blocks(self, T: np.ndarray, grid: tuple[int, int]) -> torch.Tensor:
        uv, _ = self._project(torch.as_tensor(T, dtype=torch.float64)[None])
        H, W = self.sizes[:, 0, None], self.sizes[:, 1, None]  # each frame's own
        cu = (uv[..., 0] / W * grid[0]).floor().clamp(0, grid[0] - 1).long()
        cv = (uv[..., 1] / H * grid[1]).floor().clamp(0, grid[1] - 1).long()
        frame = torch.arange(self.points.shape[1])[None, :, None]
        kind = torch.arange(2)[:, None, None]
        return (((frame * 2 + kind) * grid[0] + cu[0]) * grid[1] + cv[0]).long()

    def _project(self, T: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``uv (C, 2, F, N, 2)`` and depth ``(C, 2, F, N)`` of the samples under ``T (C, 4, 4)``."""
        T_cam = self._rig[None] @ T[:, None]  # (C, F, 4, 4) each frame's camera's extrinsic
        KR = self.K @ T_cam[..., :3, :3]  # (C, F, 3, 3)
        Kt = (self.K @ T_cam[..., :3, 3:])[..., 0]  # (C, F, 3)
        # (C, 2, F, N, 3): each frame's samples of both kinds through its camera; w is the depth
        uvw = torch.einsum("kfnj,cfij->ckfni", self.points, KR) + Kt[:, None, :, None]
        z = uvw[..., 2]
        return uvw[..., :2] / z.clamp_min(1e-3)[..., None], z

    def maps(self, sigma_px: float) -> list[torch.Tensor]:
        """Per kind ``(F, 1, H, W)`` directional edge maps blurred by ``σ`` (at the first frame's
        focal length; each frame's by its own) (peak 1)."""
        key = round(float(sigma_px), 3)
        if key not in self._maps:
            kinds = []
            for j in range(2):
                maps = np.zeros((len(self._edges), 1, *self.size), np.float32)
                for edges, scale, out in zip(self._edges, self._blur, maps, strict=True):
                    b = cv2.GaussianBlur(edges[j], (0, 0), sigma_px * scale)
                    out[0, : b.shape[0], : b.shape[1]] = b / max(float(b.max()), 1e-6)
                kinds.append(torch.from_numpy(maps))
            self._maps[key] = kinds
        return self._maps[key]

    def values(self, T: torch.Tensor | np.ndarray, sigma_px: float) -> torch.Tensor:
        """``(C, 2, F, N)`` blurred edge strength under each sample for ``(C, 4, 4)`` (or one
        ``(4, 4)``) extrinsics; 0 outside the image or behind the camera."""
        T = torch.as_tensor(T, dtype=torch.float64)
        T = T[None] if T.ndim == 2 else T
        uv, z = self._project(T)
        H, W = self.size
        grid = torch.stack([2 * uv[..., 0] / (W - 1) - 1, 2 * uv[..., 1] / (H - 1) - 1], -1).float()
        maps = self.maps(sigma_px)
        out = []
        for j in range(2):
            g = grid[:, j].permute(1, 0, 2, 3)  # (F, C, N, 2)
            s = F.grid_sample(maps[j], g, align_corners=True, padding_mode="zeros")[:, 0]  # (F, C, N)
            out.append(s.permute(1, 0, 2).double())
        v = torch.stack(out, 1)
        return torch.where(z > 0.5, v, 0.0)

    def score(
        self, T: torch.Tensor | np.ndarray, sigma_px: float, mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        """``(C,)`` the score (samples weighted by :attr:`weights`, renormalised over ``mask``)."""
        w = self.weights if mask is None else self.weights * mask
        return (self.values(T, sigma_px) * w).sum((1, 2, 3)) / w.sum().clamp_min(1e-12)

    def per_frame(self, T: torch.Tensor | np.ndarray, sigma_px: float) -> torch.Tensor:
        """``(C, F)`` each frame's score."""
        w = self.weights
        return (self.values(T, sigma_px) * w).sum((1, 3)) / w.sum((0, 2)).clamp_min(1e-12)

    def block_sums(self, T: torch.Tensor | np.ndarray, sigma_px: float, mask: torch.Tensor | None = None):
        """``(C, B)`` each block's weighted contribution to the score and ``(B,)`` the block ids."""
        w = self.weights if mask is None else self.weights * mask
        ids, inverse = torch.unique(self.block[w > 0], return_inverse=True)
        contributions = (self.values(T, sigma_px) * w)[:, w > 0] / w.sum().clamp_min(1e-12)
        sums = torch.zeros(contributions.shape[0], len(ids), dtype=torch.float64)
        return sums.index_add_(1, inverse, contributions), ids

    def sigma_px(self, sigma_deg: float) -> float:
        return math.radians(sigma_deg) * self.focal
