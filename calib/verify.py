"""Is an extrinsic right? A check without ground truth (``supportnet check``).

The evidence is where the scan's occluding contours fall in the image. Three kinds of 3D samples
are taken from each scan once, under the extrinsic ``T`` being checked (they are points of the
scene, so any other extrinsic moves them as it moves the scan):

- *vertical edges*: depth jumps between neighbouring returns of a scan line
  (:func:`calib.features.depth_discontinuities`), placed midway between the two returns at the
  nearer range; read against the horizontal image gradient ``|∂I/∂u|``;
- *horizontal edges*: depth jumps between vertically neighbouring returns (the top or bottom of an
  object, one return per ring in each narrow azimuth column), and silhouettes against no return
  (the sky), placed half a ring spacing above the last return; read against ``|∂I/∂v|``.

A scan line is the stored order (KITTI's Velodyne scans; the real-fixture converters put others
in that order). The score of an extrinsic, per frame, is the mean blurred, normalised directional
edge strength under its samples (half each kind); a correct extrinsic puts contours on edges
(Levinson & Thrun's edge alignment, with the directions kept apart so texture of the wrong
orientation does not count).

The check then asks three questions of the data:

1. **Is there a better extrinsic near ``T``?** A bounded pattern search (rotation within
   ``max_rotation_deg``, translation within ``max_translation_m``) climbs the score from ``T``,
   coarse to fine over blur scales given as view angles (so every camera is treated alike), to
   ``T*``, the suggested correction.
2. **Is it better on data it was not fitted to?** The samples fall into image blocks (a grid of
   cells, per frame) split in two checkerboard folds; the search runs on one fold and the gain
   ``S(T*) − S(T)`` is measured on the other, both ways. The gain's ``z`` is its sum over blocks
   divided by the standard error from the blocks' scatter (blocks, not points, because
   neighbouring samples of one edge are not independent): climbing overfits, held-out blocks do
   not, so at a correct ``T`` the held-out ``z`` stays near or below zero.
3. **How small an error can this data show?** Around ``T*`` the score is probed along each of
   the six axes (both signs) with a ladder of sizes; the smallest size whose score drop reaches
   ``detect_z`` block standard errors is the detectable error in that direction, and the worst
   direction of rotation (°) and of translation (cm) is reported. It comes from the data: the
   score's sensitivity against its block-to-block scatter.

Verdict: ``bad`` when the held-out gain is significant (``z ≥ z_bad``) and the correction exceeds
what the data can resolve (``size ≥ 1``, with ``size`` the correction's rotation and translation
divided by the detectable error, the larger of the two); ``good`` when the held-out gain is
not significant (``z < z_good``) or the correction is within what the data can resolve
(``size < 1``); ``suspect`` in between. The thresholds were set on synthetic worlds (see
``benchmarks/bench_check.py``) and validated on the real fixtures.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence as FrameList
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field, PositiveFloat

from calib.data.extrinsic_file import rigid_problem
from calib.data.types import Frame
from calib.errors import DataError, NumericalError
from calib.features import depth_discontinuities
from calib.geometry import calibration_error, se3_exp

__all__ = [
    "CHECK_SCHEMA_VERSION",
    "CheckConfig",
    "CheckResult",
    "ContourScore",
    "FrameCheck",
    "check_extrinsic",
    "horizontal_edges",
    "vertical_edges",
]

CHECK_SCHEMA_VERSION = 1
"""Version of the ``check.json`` layout."""

Verdict = Literal["good", "suspect", "bad"]


class CheckConfig(BaseModel):
    """Parameters of :func:`check_extrinsic` (every angle is a view angle, so a camera's focal
    length turns it into pixels)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    frames: int = Field(10, ge=1, description="frames used, spread evenly over the sequence")
    view_margin: float = Field(0.15, ge=0, description="contours are taken this far outside the image")
    max_samples: int = Field(4000, ge=10, description="samples of each kind kept per frame")
    min_samples: int = Field(20, ge=1, description="a kind with fewer samples in a frame is left out")
    sigmas_deg: tuple[PositiveFloat, ...] = Field(
        (0.5, 0.25, 0.12), min_length=1, description="blur scales of the search, coarse to fine"
    )
    eval_sigma_deg: PositiveFloat = Field(0.25, description="blur scale of the gain and the probes")
    depth_m: float = Field(10.0, gt=0, description="typical depth: translation step = rotation step x this")
    max_rotation_deg: float = Field(3.0, gt=0, description="the search stays within this of T")
    max_translation_m: float = Field(0.3, gt=0, description="the search stays within this of T")
    blocks: tuple[int, int] = Field((8, 4), description="image cells (across, down) per frame")
    z_bad: float = Field(3.0, gt=0, description="held-out gain z at and above which T is bad")
    z_good: float = Field(2.0, gt=0, description="held-out gain z below which T is good")
    detect_z: float = Field(3.0, gt=0, description="score drop, in block standard errors, that is detected")
    probe_deg: tuple[PositiveFloat, ...] = Field(
        (0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.7, 1.0, 1.5, 2.0, 3.0), description="rotation probe ladder"
    )
    probe_cm: tuple[PositiveFloat, ...] = Field(
        (1.0, 2.0, 3.0, 5.0, 7.0, 10.0, 15.0, 20.0, 30.0, 50.0, 100.0),
        description="translation probe ladder",
    )

    def model_post_init(self, __context: object) -> None:
        if self.z_good > self.z_bad:
            raise ValueError(f"z_good ({self.z_good}) must not exceed z_bad ({self.z_bad})")
        if min(self.blocks) < 1:
            raise ValueError(f"blocks must be positive, got {self.blocks}")


# -- contour samples -----------------------------------------------------------------------------


def _spherical(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    azimuth = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0]))
    elevation = np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))
    return azimuth, elevation, np.linalg.norm(xyz, axis=1)


def _points(azimuth: np.ndarray, elevation: np.ndarray, rng: np.ndarray) -> np.ndarray:
    a, e = np.radians(azimuth), np.radians(elevation)
    return np.column_stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)]) * rng[:, None]


def horizontal_edges(points_lidar: np.ndarray) -> np.ndarray:
    """Samples of the image's *vertical* edges: each depth jump along a scan line (stored order),
    midway in azimuth between its two returns, at the nearer range. ``(M, 3)`` LiDAR frame."""
    xyz = np.asarray(points_lidar, np.float64)[:, :3]
    nearer, farther = depth_discontinuities(xyz)
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
) -> tuple[np.ndarray, np.ndarray, float]:
    """Samples of the image's *horizontal* edges.

    The scan is cut into azimuth columns ``column_deg`` wide; in each, returns closer than
    ``same_ring_deg`` in elevation count as one ring (the first is kept), and consecutive rings
    are vertical neighbours when less than ``max_gap_deg`` apart. A jump in range between them
    (more than ``max(min_jump_m, rel_jump · nearer)``) whose two sides each continue a surface
    (their outer neighbours within ``surface_tol``) is an occluding contour, sampled midway in
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
    ring = order[first]  # one return per ring and column, by elevation within each column
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
    k = k[below & above]
    a_nearer = rng[a[k]] < rng[b[k]]
    nearer = np.where(a_nearer, a[k], b[k])
    farther = np.where(a_nearer, b[k], a[k])
    contours = _points(azimuth[nearer], 0.5 * (elevation[nearer] + elevation[farther]), rng[nearer])
    top = np.percentile(elevation, 99.5)
    last = np.nonzero(np.concatenate([~neighbours, [True]]))[0]
    last = last[last > 0]
    sky = ring[last[smooth[last - 1] & (e[last] < top - 2 * spacing)]]
    silhouettes = _points(azimuth[sky], elevation[sky] + 0.5 * spacing, rng[sky])
    return contours, silhouettes, spacing


def _in_view(points: np.ndarray, T: np.ndarray, K: np.ndarray, size: tuple[int, int], margin: float):
    q = np.asarray(points[:, :3], np.float64) @ T[:3, :3].T + T[:3, 3]
    z = q[:, 2]
    uvw = q @ K.T
    u, v = uvw[:, 0] / np.maximum(z, 1e-3), uvw[:, 1] / np.maximum(z, 1e-3)
    H, W = size
    return (
        (z > 0.5)
        & (u > -margin * W)
        & (u < (1 + margin) * W)
        & (v > -margin * H)
        & (v < (1 + margin) * H)
    )


def _directional_edges(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``|∂I/∂u|`` and ``|∂I/∂v|`` of the grey image (σ = 1 px first), each in [0, 1] (1 at and
    above its 99th percentile)."""
    grey = cv2.GaussianBlur(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32), (0, 0), 1.0)
    out = []
    for dx, dy in ((1, 0), (0, 1)):
        g = np.abs(cv2.Sobel(grey, cv2.CV_32F, dx, dy))
        out.append(np.clip(g / max(float(np.percentile(g, 99)), 1e-6), 0.0, 1.0))
    return out[0], out[1]


KINDS = ("vertical edges", "horizontal edges")
"""What each kind of sample marks in the image (see the module docstring)."""


class ContourScore:
    """Edge alignment of the contour samples of ``frames`` (one shared ``K``), taken under ``T``.

    Attributes:
        counts: per frame ``{kind: samples}`` (vertical edges, horizontal edges, silhouettes).
        weights: per kind ``(F, N)`` float64: the sample's share of the score (0 for padding or a
            kind left out), so that the score is a weighted sum.
        block: per kind ``(F, N)`` int64: the sample's image block (unique over frames and kinds).
    """

    def __init__(self, frames: FrameList[Frame], T: np.ndarray, config: CheckConfig, seed: int = 0) -> None:
        if not frames:
            raise DataError("frames", "the check needs at least one frame")
        K = frames[0].K
        if any(not np.allclose(f.K, K) or f.image_size != frames[0].image_size for f in frames):
            raise DataError("frames", "have different intrinsics or image sizes; check one camera at a time")
        rng = np.random.default_rng(seed)
        self.K = torch.as_tensor(K, dtype=torch.float64)
        self.focal = float(K[0, 0])
        self.size = frames[0].image_size
        self.counts: list[dict[str, int]] = []
        samples: list[tuple[np.ndarray, np.ndarray]] = []
        self._edges = []
        for frame in frames:
            keep = _in_view(frame.points, T, K, self.size, config.view_margin)
            xyz = np.asarray(frame.points[keep, :3], np.float64)
            h = horizontal_edges(xyz)
            v, sky, _ = vertical_edges(xyz)
            self.counts.append({"vertical_edges": len(h), "horizontal_edges": len(v), "silhouettes": len(sky)})
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
        H, W = self.size
        cu = (uv[..., 0] / W * grid[0]).floor().clamp(0, grid[0] - 1).long()
        cv = (uv[..., 1] / H * grid[1]).floor().clamp(0, grid[1] - 1).long()
        frame = torch.arange(self.points.shape[1])[None, :, None]
        kind = torch.arange(2)[:, None, None]
        return (((frame * 2 + kind) * grid[0] + cu[0]) * grid[1] + cv[0]).long()

    def _project(self, T: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``uv (C, 2, F, N, 2)`` and depth ``(C, 2, F, N)`` of the samples under ``T (C, 4, 4)``."""
        q = torch.einsum("cij,kfnj->ckfni", T[:, :3, :3], self.points) + T[:, None, None, None, :3, 3]
        z = q[..., 2]
        uvw = q @ self.K.T
        return uvw[..., :2] / z.clamp_min(1e-3)[..., None], z

    def maps(self, sigma_px: float) -> list[torch.Tensor]:
        """Per kind ``(F, 1, H, W)`` directional edge maps blurred by ``σ`` (peak 1)."""
        key = round(float(sigma_px), 3)
        if key not in self._maps:
            kinds = []
            for j in range(2):
                blurred = []
                for edges in self._edges:
                    b = cv2.GaussianBlur(edges[j], (0, 0), sigma_px)
                    blurred.append(b / max(float(b.max()), 1e-6))
                kinds.append(torch.from_numpy(np.stack(blurred))[:, None].float())
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

    def score(self, T: torch.Tensor | np.ndarray, sigma_px: float, mask: torch.Tensor | None = None) -> torch.Tensor:
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


def _gain_z(differences: torch.Tensor) -> tuple[float, float]:
    """Sum of per-block differences ``(..., B)`` and its ``z`` (the sum over the standard error
    of a sum of ``B`` exchangeable blocks, ``√(B/(B−1) · Σ (d − d̄)²)``)."""
    d = differences
    B = d.shape[-1]
    total = d.sum(-1)
    if B < 2:
        return float(total), 0.0
    se = torch.sqrt(B / (B - 1) * ((d - d.mean(-1, keepdim=True)) ** 2).sum(-1)).clamp_min(1e-12)
    return total, total / se


def _steps(rotation: float, translation: float) -> torch.Tensor:
    """``(12, 6)`` ± one step along each twist axis (translation first)."""
    steps = torch.zeros(12, 6, dtype=torch.float64)
    for axis in range(6):
        size = translation if axis < 3 else rotation
        steps[2 * axis, axis], steps[2 * axis + 1, axis] = size, -size
    return steps


def _offsets(T_start: torch.Tensor, T: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rotation angle (rad) and translation (m) of ``T_start⁻¹ · T`` for ``T (C, 4, 4)``."""
    E = torch.linalg.inv(T_start) @ T
    cos = ((E[:, 0, 0] + E[:, 1, 1] + E[:, 2, 2] - 1) / 2).clamp(-1, 1)
    return torch.arccos(cos), E[:, :3, 3].norm(dim=1)


def _climb(
    score: ContourScore, T_start: torch.Tensor, config: CheckConfig, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """Pattern search from ``T_start`` coarse to fine over ``config.sigmas_deg``: take the best of
    the 12 neighbouring moves while it raises the score, halve the steps when none does, stop at
    a quarter of the level's first step; never leave the bounds around ``T_start``."""
    T = T_start
    max_r, max_t = math.radians(config.max_rotation_deg), config.max_translation_m
    for sigma_deg in config.sigmas_deg:
        sigma = score.sigma_px(sigma_deg)
        rotation = math.radians(sigma_deg)
        translation = rotation * config.depth_m
        best = float(score.score(T, sigma, mask)[0])
        smallest = rotation / 4
        for _ in range(200):
            if rotation < smallest:
                break
            candidates = se3_exp(_steps(rotation, translation)) @ T
            values = score.score(candidates, sigma, mask)
            angle, shift = _offsets(T_start, candidates)
            values = torch.where((angle > max_r) | (shift > max_t), -1.0, values)
            k = int(values.argmax())
            if float(values[k]) > best:
                T, best = candidates[k], float(values[k])
            else:
                rotation, translation = rotation / 2, translation / 2
    return T


def _folds(score: ContourScore, config: CheckConfig) -> torch.Tensor:
    """``(2, F, N)`` mask of checkerboard fold 0 of the image blocks (fold 1 is its complement)."""
    b = score.block
    cv = b % config.blocks[1]
    cu = (b // config.blocks[1]) % config.blocks[0]
    frame = b // (config.blocks[0] * config.blocks[1] * 2)
    return ((cu + cv + frame) % 2 == 0).double()


def _held_out_gain(score: ContourScore, T: torch.Tensor, config: CheckConfig) -> tuple[float, float, list]:
    """Cross-fitted gain of the search: climb on one fold, measure ``S(T*) − S(T)`` on the other,
    both ways; returns the gain (relative to ``S(T)``), its ``z`` over the held-out blocks, and the
    two fold-wise extrinsics."""
    fold = _folds(score, config)
    sigma = score.sigma_px(config.eval_sigma_deg)
    diffs, found = [], []
    for train in (fold, 1.0 - fold):
        held = 1.0 - train
        T_fold = _climb(score, T, config, train)
        found.append(T_fold)
        sums, _ = score.block_sums(torch.stack([T, T_fold]), sigma, held)
        diffs.append(sums[1] - sums[0])
    d = torch.cat(diffs)
    base = float(score.score(T, sigma)[0])
    total, z = _gain_z(d)
    # each fold's sums are normalised by its own weight: the two halves are averaged
    return float(total) / 2 / max(base, 1e-12), float(z), found


def _detectable(score: ContourScore, T_best: torch.Tensor, config: CheckConfig) -> dict:
    """Smallest probe, per axis and sign, whose score drop from ``T_best`` reaches ``detect_z``
    block standard errors; the worst direction of rotation and of translation."""
    sigma = score.sigma_px(config.eval_sigma_deg)
    ladders = (np.asarray(config.probe_cm) / 100.0, np.radians(config.probe_deg))
    twists, keys = [], []
    for axis in range(6):
        ladder = ladders[axis >= 3]
        for sign in (1.0, -1.0):
            for size in ladder:
                t = torch.zeros(6, dtype=torch.float64)
                t[axis] = sign * size
                twists.append(t)
                keys.append((axis, sign, size))
    probes = T_best @ se3_exp(torch.stack(twists))  # right: the probe's error against T_best is the twist
    sums, _ = score.block_sums(torch.cat([T_best[None], probes]), sigma)
    _, z = _gain_z(sums[:1] - sums[1:])
    z = z.numpy()
    per_axis: dict[str, float | None] = {}
    names = ("x", "y", "z")
    for axis in range(6):
        worst = 0.0
        for sign in (1.0, -1.0):
            rows = [i for i, k in enumerate(keys) if k[0] == axis and k[1] == sign]
            sizes = np.array([keys[i][2] for i in rows])
            zs = z[rows]
            hit = np.nonzero(zs >= config.detect_z)[0]
            if len(hit) == 0:
                worst = math.inf
                continue
            i = hit[0]
            if i == 0:
                found = sizes[0]
            else:  # linear between the last probe below and the first at or above
                z0, z1 = zs[i - 1], zs[i]
                found = sizes[i - 1] + (config.detect_z - z0) / max(z1 - z0, 1e-9) * (sizes[i] - sizes[i - 1])
            worst = max(worst, float(found))
        unit = 100.0 if axis < 3 else math.degrees(1.0)
        name = ("translation_" if axis < 3 else "rotation_") + names[axis % 3]
        per_axis[name] = None if math.isinf(worst) else worst * unit
    rotation = [per_axis[f"rotation_{n}"] for n in names]
    translation = [per_axis[f"translation_{n}"] for n in names]
    return {
        "rotation_deg": None if None in rotation else max(rotation),
        "translation_cm": None if None in translation else max(translation),
        "per_axis": per_axis,
    }


# -- result ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FrameCheck:
    """One frame of a check: its name, contour samples, and its score under ``T`` and ``T*``."""

    index: int
    name: str
    samples: dict[str, int]
    score: float
    best_score: float

    @property
    def alignment(self) -> float:
        """``S(T) / S(T*)``: 1 when ``T`` aligns this frame as well as the best extrinsic found."""
        return self.score / self.best_score if self.best_score > 0 else 0.0

    def to_dict(self) -> dict:
        return {
            "index": self.index,
            "name": self.name,
            "samples": self.samples,
            "score": self.score,
            "best_score": self.best_score,
            "alignment": self.alignment,
        }


@dataclass(frozen=True)
class CheckResult:
    """What :func:`check_extrinsic` found.

    Attributes:
        verdict: ``good``, ``suspect`` or ``bad``.
        T_cam_lidar: ``(4, 4)`` the extrinsic checked.
        suggested_T_cam_lidar: ``(4, 4)`` ``T*``, the best extrinsic found near it.
        correction: ``T*`` against ``T`` (``E = T⁻¹ · T*``, DESIGN.md's error convention).
        score, best_score: the score under ``T`` and ``T*`` over all frames.
        gain: held-out ``(S(T*) − S(T)) / S(T)``; gain_z: its ``z`` over held-out blocks.
        detectable: the smallest error this data shows (``rotation_deg``, ``translation_cm``, per
            axis; ``None`` where even the largest probe is not seen).
        size: the correction over the detectable error (the larger of rotation and translation).
        frames: per frame.
        reasons: why the verdict, in words.
    """

    verdict: Verdict
    T_cam_lidar: np.ndarray
    suggested_T_cam_lidar: np.ndarray
    score: float
    best_score: float
    gain: float
    gain_z: float
    detectable: dict
    size: float | None
    frames: list[FrameCheck]
    reasons: list[str]
    reference_T_cam_lidar: np.ndarray | None = None
    runtime_s: float = 0.0
    config: dict = field(default_factory=dict)

    @property
    def correction(self):
        return calibration_error(self.suggested_T_cam_lidar, self.T_cam_lidar)

    @property
    def alignment(self) -> float:
        return self.score / self.best_score if self.best_score > 0 else 0.0

    def to_dict(self) -> dict:
        reference = None
        if self.reference_T_cam_lidar is not None:
            reference = {
                "T_cam_lidar": np.asarray(self.reference_T_cam_lidar).tolist(),
                "error": calibration_error(self.T_cam_lidar, self.reference_T_cam_lidar).to_dict(),
                "suggested_error": calibration_error(
                    self.suggested_T_cam_lidar, self.reference_T_cam_lidar
                ).to_dict(),
            }
        return {
            "schema_version": CHECK_SCHEMA_VERSION,
            "verdict": self.verdict,
            "reasons": self.reasons,
            "T_cam_lidar": np.asarray(self.T_cam_lidar).tolist(),
            "score": self.score,
            "best_score": self.best_score,
            "alignment": self.alignment,
            "held_out_gain": self.gain,
            "held_out_gain_z": self.gain_z,
            "detectable_error": self.detectable,
            "correction_size": self.size,
            "suggested_T_cam_lidar": np.asarray(self.suggested_T_cam_lidar).tolist(),
            "suggested_correction": self.correction.to_dict(),
            "frames": [f.to_dict() for f in self.frames],
            "reference": reference,
            "runtime_s": self.runtime_s,
            "config": self.config,
        }


def _size(correction, detectable: dict) -> float | None:
    """The correction over the detectable error: the larger of rotation and translation (a
    part the data cannot resolve at all counts 0)."""
    parts = []
    if detectable["rotation_deg"]:
        parts.append(correction.rotation_deg / detectable["rotation_deg"])
    if detectable["translation_cm"]:
        parts.append(correction.translation_cm / detectable["translation_cm"])
    return max(parts) if parts else None


def check_extrinsic(
    frames: FrameList[Frame], T_cam_lidar: np.ndarray, config: CheckConfig | None = None, seed: int = 0
) -> CheckResult:
    """Check ``T_cam_lidar (4, 4)`` on ``frames`` (one camera) without ground truth (see the
    module docstring).

    Raises:
        DataError: ``T_cam_lidar`` is not rigid, or the frames do not share one camera.
        NumericalError: the scans show too few contours in the image to check anything.
    """
    start = time.perf_counter()
    config = config if config is not None else CheckConfig()
    T_np = np.asarray(T_cam_lidar, np.float64)
    problem = rigid_problem(T_np)
    if problem is not None:
        raise DataError("extrinsic", problem)
    score = ContourScore(frames, T_np, config, seed)
    T = torch.as_tensor(T_np)
    T_best = _climb(score, T, config)
    gain, gain_z, _ = _held_out_gain(score, T, config)
    detectable = _detectable(score, T_best, config)
    sigma = score.sigma_px(config.eval_sigma_deg)
    both = torch.stack([T, T_best])
    totals = score.score(both, sigma)
    per_frame = score.per_frame(both, sigma)
    correction = calibration_error(T_best.numpy(), T_np)
    size = _size(correction, detectable)
    reasons = []
    if gain_z >= config.z_bad and size is not None and size >= 1.0:
        verdict: Verdict = "bad"
        reasons.append(
            f"an extrinsic {correction} away aligns held-out contours better (gain z = {gain_z:.1f} "
            f"≥ {config.z_bad:g}), {size:.1f}x the smallest error this data shows"
        )
    elif gain_z < config.z_good or size is None or size < 1.0:
        verdict = "good"
        if gain_z < config.z_good:
            reasons.append(f"no nearby extrinsic aligns held-out contours better (gain z = {gain_z:.1f})")
        else:
            reasons.append(
                f"the best nearby extrinsic is within what this data resolves ({correction} away)"
            )
    else:
        verdict = "suspect"
        reasons.append(
            f"an extrinsic {correction} away aligns held-out contours somewhat better "
            f"(gain z = {gain_z:.1f}, between {config.z_good:g} and {config.z_bad:g})"
        )
    if detectable["rotation_deg"] is None or detectable["translation_cm"] is None:
        reasons.append("some directions are not observed in this data at all (see detectable_error)")
    checks = [
        FrameCheck(
            index=int(f.index),
            name=f.name,
            samples=score.counts[k],
            score=float(per_frame[0, k]),
            best_score=float(per_frame[1, k]),
        )
        for k, f in enumerate(frames)
    ]
    return CheckResult(
        verdict=verdict,
        T_cam_lidar=T_np,
        suggested_T_cam_lidar=T_best.numpy(),
        score=float(totals[0]),
        best_score=float(totals[1]),
        gain=gain,
        gain_z=gain_z,
        detectable=detectable,
        size=size,
        frames=checks,
        reasons=reasons,
        reference_T_cam_lidar=frames[0].calibration.T_cam_lidar,
        runtime_s=time.perf_counter() - start,
        config=config.model_dump(mode="json"),
    )
