"""Stage 4's global coarse stage: where the dense matcher cannot reach (its capture range is about
a dozen pixels), climb the edge-alignment score (:class:`calib.match.edge_alignment.EdgeAlignment`)
coarse to fine over a pyramid of blur scales ``σ``. At the coarsest scale a dense grid of rotations
around each start (the initial extrinsic, and the learned matcher's answer with ``start: both``) is
scored; its best ``starts`` cells are climbed over all six parameters, and each of them is carried
through every finer scale. The answer is the hypothesis that scores best at the finest scale. Each
scale's steps scale with ``σ``, a translation step moving the contours at their median depth as far
as a rotation step (``depth_m: null``); a move is taken only when the score rises.

Why this shape (synthetic urban at KITTI's scale from 8° / 40 cm, README): at 16 px the score
rates poses 50–130 cm off above the truth on some scenes, so a search that starts there runs off;
at 8 px the truth outscores every answer found, but its basin is narrow, so the first scale is a
dense grid (13³ rotations, ±7.6°) at 8 px rather than a sparse one at 16 px. Which hypothesis is
right often shows only at the finer scales, hence all are carried. Searching rotation alone first
lets it absorb a translation error it cannot undo later, so every scale searches all six.
It runs once per edge map in ``scores`` (:data:`calib.match.edge_alignment.SCORE_KINDS`: which one
finds the basin depends on the scene); the dense passes then keep the answer they align best.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, PositiveFloat

from calib.data.types import Frame
from calib.geometry import se3_exp, twist_steps
from calib.match.edge_alignment import SCORE_KINDS, EdgeAlignment

__all__ = ["GlobalSearchConfig", "GlobalSearchResult", "global_search"]

REFERENCE_FOCAL_PX = 721.0
"""Pixel sizes of the config are for a KITTI-like focal length; other cameras scale them."""


class GlobalSearchConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    enabled: bool = Field(
        True,
        description="run the global coarse stage before the dense passes (they go on from its answer "
        "only when their first pass ends better aligned there than from the initial extrinsic)",
    )
    start: Literal["initial", "flow", "both"] = Field(
        "initial",
        description="where the search starts: the initial extrinsic (beside the learned matcher's "
        "coarse passes), those passes' answer (after them), or both (begun from the initial beside "
        "them, their answer joining when they end; the initial alone where there are none)",
    )
    scores: tuple[Literal[SCORE_KINDS], ...] = Field(  # type: ignore[valid-type]
        SCORE_KINDS, min_length=1, description="edge maps searched, each giving the dense passes a start"
    )
    sigmas_px: tuple[PositiveFloat, ...] = Field(
        (8.0, 4.0, 2.0), min_length=1, description="blur scales, coarse to fine (px at f = 721)"
    )
    grid: int = Field(13, ge=1, le=21, description="rotations per axis of the coarsest level's grid")
    grid_spacing: float = Field(2.0, gt=0, description="grid spacing in steps of the coarsest scale")
    starts: int = Field(8, ge=1, description="best grid cells climbed and carried through every scale")
    depth_m: PositiveFloat | None = Field(
        10.0,
        description="typical depth: translation step = rotation step x this (None: the median depth of "
        "the contour points under the start, so a translation step moves them as far as a rotation step)",
    )
    max_translation_m: float = Field(1.0, gt=0, description="translation never leaves the start by more")
    contour_points: int = Field(1200, ge=10, description="contour points per frame")
    view_margin_deg: float = Field(
        15.0, ge=0, description="contour points drawn within the start's view widened by this"
    )
    surround: float = Field(
        3.0, ge=0, description="each edge map less its blur this many times wider (texture scores 0)"
    )
    max_iterations: int = Field(40, ge=1, description="climbing moves per scale")


@dataclass(frozen=True)
class GlobalSearchResult:
    """``T_cam_lidar (4, 4)`` after the search; ``levels``: per scale the score before and after."""

    T_cam_lidar: np.ndarray
    levels: list[dict]


@dataclass
class _Climb:
    """One pattern search's state: the pose, its score, the start it came from (translation never
    leaves it by more than ``max_translation_m``), its depth (translation step = rotation step x
    this), the current rotation step and the moves made at this scale."""

    T: torch.Tensor
    best: float
    origin: torch.Tensor
    depth_m: float
    rotation: float = 0.0
    moves: int = 0


def _climb(
    score: EdgeAlignment, sigma: float, climbs: list[_Climb], rotation: float, config: GlobalSearchConfig
) -> None:
    """Pattern search, in place, from each of ``climbs`` at scale ``sigma`` with a first rotation
    step of ``rotation`` (radians): each takes the best of its 12 neighbouring moves while that
    raises its score, halves its steps when none does, and stops at a quarter of the first step.
    The climbs are independent; every round scores the moves of all climbs still going in one
    call (one call of 8 x 12 poses costs about what one of 12 does)."""
    for climb in climbs:
        climb.rotation, climb.moves = rotation, 0
    smallest = rotation / 4
    while going := [c for c in climbs if c.rotation >= smallest and c.moves < config.max_iterations]:
        for climb in going:
            climb.moves += 1
        steps = torch.cat([twist_steps(c.rotation, c.rotation * c.depth_m) for c in going])
        candidates = se3_exp(steps) @ torch.stack([c.T for c in going]).repeat_interleave(12, dim=0)
        values = score(candidates, sigma)
        origins = torch.stack([c.origin for c in going]).repeat_interleave(12, dim=0)
        offset = (torch.linalg.inv(origins) @ candidates)[:, :3, 3].norm(dim=1)
        values = torch.where(offset > config.max_translation_m, -1.0, values)
        for climb, moves, scored in zip(going, candidates.split(12), values.split(12), strict=True):
            k = int(scored.argmax())
            if float(scored[k]) > climb.best:
                climb.T, climb.best = moves[k], float(scored[k])
            else:
                climb.rotation /= 2


def _rotation_grid(cells: int, spacing: float) -> torch.Tensor:
    """``(cells³, 6)`` twists of pure rotation on a cubic grid of ``spacing`` radians centred on zero."""
    offsets = (torch.arange(cells, dtype=torch.float64) - (cells - 1) / 2) * spacing
    twists = torch.zeros(cells**3, 6, dtype=torch.float64)
    twists[:, 3:] = torch.cartesian_prod(offsets, offsets, offsets)
    return twists


def _grid_climbs(
    score: EdgeAlignment,
    sigma: float,
    grid: torch.Tensor,
    origins: list[torch.Tensor],
    config: GlobalSearchConfig,
) -> list[_Climb]:
    """The best ``config.starts`` cells of the rotation ``grid (G, 4, 4)`` around each origin, as
    climbs from it at its depth."""
    climbs = []
    for origin in origins:
        depth_m = config.depth_m if config.depth_m is not None else score.median_depth(origin)
        cells = grid @ origin
        best = score(cells, sigma).topk(min(config.starts, len(cells))).indices
        climbs += [_Climb(cells[i], 0.0, origin, depth_m) for i in best]
    return climbs


def _as_starts(T: np.ndarray) -> list[torch.Tensor]:
    """``(4, 4)`` or ``(S, 4, 4)`` extrinsics as a list of float64 ``(4, 4)`` tensors."""
    return list(torch.as_tensor(np.asarray(T, np.float64)).reshape(-1, 4, 4))


def global_search(
    frames: list[Frame],
    T_init: np.ndarray,
    config: GlobalSearchConfig | None = None,
    kind: str = "magnitude",
    later: Callable[[], np.ndarray] | None = None,
) -> GlobalSearchResult:
    """Climb the edge-alignment score with the edge map ``kind`` over ``frames`` (one shared
    ``K``, or a rig's cameras: ``T_init`` is then ``T_rig_lidar``, steps in the first camera's
    pixels) from ``T_init``: one extrinsic ``(4, 4)``, or ``(S, 4, 4)`` starts searched together
    (each its own grid, best ``starts`` cells and depth; the answer the best at the finest scale
    of them all). ``later``, if given, returns more such starts; it is called once the first
    ones' grids are scored (so a search can begin while another stage computes its answer), and
    their grids join the search. Contour points are drawn within the first start's view."""
    config = config if config is not None else GlobalSearchConfig()
    origins = _as_starts(T_init)
    score = EdgeAlignment(
        frames,
        config.contour_points,
        kind=kind,
        view=(origins[0].numpy(), config.view_margin_deg),
        surround=config.surround,
    )
    focal = float(frames[0].K[0, 0])
    climbs: list[_Climb] = []
    levels = []
    for level, sigma_ref in enumerate(config.sigmas_px):
        sigma = sigma_ref * focal / REFERENCE_FOCAL_PX
        rotation = sigma / focal  # one σ of image motion, radians
        if level == 0:  # a grid of rotations around each start, its best cells the hypotheses
            grid = se3_exp(_rotation_grid(config.grid, config.grid_spacing * rotation))
            climbs = _grid_climbs(score, sigma, grid, origins, config)
            if later is not None:
                more = _as_starts(later())
                climbs += _grid_climbs(score, sigma, grid, more, config)
                origins += more
        scores = score(torch.stack([c.T for c in climbs]), sigma)
        for climb, value in zip(climbs, scores, strict=True):
            climb.best = float(value)
        before = float(scores.max())
        _climb(score, sigma, climbs, rotation, config)
        levels.append({"sigma_px": sigma, "score_before": before, "score_after": max(c.best for c in climbs)})
    answer = max(climbs, key=lambda c: c.best)
    start_scores = score(torch.stack(origins), sigma)
    if answer.best < float(start_scores.max()):  # the search can only help
        return GlobalSearchResult(origins[int(start_scores.argmax())].numpy(), levels)
    return GlobalSearchResult(answer.T.numpy(), levels)
