"""Stage 4, between the global coarse stage and the dense passes: maximise the contour score
(:class:`calib.match.contours.ContourScore`) over all six parameters at once, coarse to fine over
blur scales.

A pattern search moves one axis at a time and crawls along the valley where a rotation
compensates a translation (at depth ``z`` a lateral shift ``t`` looks like a rotation ``t / z``);
here L-BFGS-B follows the score's gradient (autograd through the bilinear lookup) in all six
directions together. Parameters are the twist ``ξ`` of ``T = T₀ · exp(ξ)`` (the error convention
of :func:`calib.geometry.calibration_error`), scaled so that one unit moves a point at ``depth_m``
by one blur scale; box bounds keep each level within ``max_rotation_deg`` / ``max_translation_m``
of its start. The samples are re-taken under each level's start (points that enter the view),
and a level whose result scores lower than its start is undone, so the score can only rise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, PositiveFloat
from scipy.optimize import minimize

from calib.data.types import Frame
from calib.errors import ConfigError
from calib.geometry import se3_exp
from calib.match.contours import ContourConfig, ContourScore

__all__ = ["ContourRefineConfig", "ContourRefineResult", "contour_refine"]


class ContourRefineConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    enabled: bool = Field(
        False, description="run it before the dense passes (after the global coarse stage, if enabled)"
    )
    sigmas_deg: tuple[PositiveFloat, ...] = Field(
        (1.0, 0.5, 0.25, 0.12), min_length=1, description="blur scales (view angles), coarse to fine"
    )
    depth_m: float = Field(10.0, gt=0, description="a translation unit is a rotation unit x this")
    max_rotation_deg: float = Field(3.0, gt=0, description="each level stays within this of its start")
    max_translation_m: float = Field(0.25, gt=0, description="each level stays within this of its start")
    max_iterations: int = Field(100, ge=1, description="L-BFGS-B iterations per level")
    contours: ContourConfig = Field(ContourConfig(max_samples=6000), description="the contour samples")


@dataclass(frozen=True)
class ContourRefineResult:
    """``T_cam_lidar (4, 4)`` after the last level; ``levels``: per blur scale the score before and
    after and the score evaluations it took."""

    T_cam_lidar: np.ndarray
    levels: list[dict]


def _level(score: ContourScore, T0: torch.Tensor, sigma_deg: float, config: ContourRefineConfig):
    """One blur scale: ``(T, score before, score after, evaluations)``."""
    sigma_px = score.sigma_px(sigma_deg)
    unit = math.radians(sigma_deg)
    scale = torch.tensor([unit * config.depth_m] * 3 + [unit] * 3, dtype=torch.float64)
    bound_t = config.max_translation_m / float(scale[0])
    bound_r = math.radians(config.max_rotation_deg) / unit

    def negative_score(x: np.ndarray) -> tuple[float, np.ndarray]:
        xi = torch.tensor(x, dtype=torch.float64, requires_grad=True)
        value = -score.score((T0 @ se3_exp(xi * scale))[None], sigma_px)[0]
        value.backward()
        return float(value.detach()), xi.grad.numpy().copy()

    before = -negative_score(np.zeros(6))[0]
    found = minimize(
        negative_score,
        np.zeros(6),
        jac=True,
        method="L-BFGS-B",
        bounds=[(-bound_t, bound_t)] * 3 + [(-bound_r, bound_r)] * 3,
        options={"maxiter": config.max_iterations},
    )
    after = -float(found.fun)
    if after <= before:
        return T0, before, before, int(found.nfev)
    return T0 @ se3_exp(torch.as_tensor(found.x) * scale), before, after, int(found.nfev)


def contour_refine(
    frames: Sequence[Frame], T_init: np.ndarray, config: ContourRefineConfig | None = None
) -> ContourRefineResult:
    """Climb the contour score from ``T_init (4, 4)`` over ``frames`` (one shared ``K``).

    Raises:
        NumericalError: the scans show too few contours in the image.
        ConfigError: the frames are a rig's cameras (this experimental score has one camera).
    """
    if any(f.calibration.T_cam_rig is not None for f in frames):
        raise ConfigError(
            "contour.enabled", "the contour score has one camera: turn it off to calibrate a rig"
        )
    config = config if config is not None else ContourRefineConfig()
    T = torch.as_tensor(np.asarray(T_init, np.float64))
    levels = []
    for sigma_deg in config.sigmas_deg:
        score = ContourScore(frames, T.numpy(), config.contours)
        T, before, after, evaluations = _level(score, T, sigma_deg, config)
        T = T.detach()
        levels.append(
            {"sigma_deg": sigma_deg, "score_before": before, "score_after": after, "evaluations": evaluations}
        )
    return ContourRefineResult(T.numpy(), levels)
