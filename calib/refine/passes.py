"""Stage 4 as passes: match with the current estimate, sample, refine, repeat (CMRNext runs its
matcher three times; each pass starts from the last estimate)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from calib.data.types import Frame
from calib.errors import DataError
from calib.geometry import calibration_error
from calib.match.correspondences import Matcher
from calib.match.edge_matcher import EdgeMatcherConfig
from calib.projection import pixel_lookup
from calib.refine.contour_refine import ContourRefineConfig
from calib.refine.global_search import GlobalSearchConfig
from calib.refine.sgis import support_sample, uniform_sample
from calib.refine.solver import RefineConfig, refine_extrinsic
from calib.refine.tracking import OnlineConfig
from calib.support.source import SupportSource
from calib.yaml_io import load_config

__all__ = ["CalibrateConfig", "PassesResult", "SamplingConfig", "draw", "refine_passes"]


class SamplingConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    per_frame: int = Field(2000, ge=6, description="correspondences drawn from each frame per pass")
    floor: float = Field(0.01, ge=0, description="added to every support value (zero stays possible)")
    weight_by_support: bool = Field(True, description="weight each drawn residual by s_i too (Eq. 4)")


class CalibrateConfig(BaseModel):
    """``configs/calibrate.yaml``."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    matcher: Literal["edge", "flow"] = "edge"
    flow_model: Path | None = Field(None, description="the flow matcher's ONNX file (None: the shipped one)")
    edge: EdgeMatcherConfig = EdgeMatcherConfig()
    support_map: Literal["support", "agreement"] = Field(
        "support",
        description="which offline map SGIS reads: the raw Eq. 2 sum (sampled matches measured "
        "closer to the truth) or the density-normalised agreement",
    )
    sampling: SamplingConfig = SamplingConfig()
    refine: RefineConfig = RefineConfig()
    frames: int = Field(10, ge=1, description="frames used, spread evenly over the sequence")
    passes: int = Field(3, ge=1)
    min_update_cm: float = Field(0.01, ge=0, description="stop early when a pass moves less than this")
    min_update_deg: float = Field(0.001, ge=0)
    coarse: GlobalSearchConfig = Field(
        GlobalSearchConfig(), description="the global coarse stage before the dense passes (wide basin)"
    )
    contour: ContourRefineConfig = Field(
        ContourRefineConfig(), description="the contour refinement after the global coarse stage"
    )
    weak_std_cm: float = Field(1.0, gt=0, description="a translation direction with a larger std is weak")
    weak_std_deg: float = Field(0.1, gt=0, description="a rotation direction with a larger std is weak")
    online: OnlineConfig = OnlineConfig()


@dataclass(frozen=True)
class PassesResult:
    """``T_cam_lidar (4, 4)`` and ``covariance (6, 6)`` of the last pass; ``passes`` one dict per
    pass (iterations, cost, correspondences, update); ``correspondences`` used in the last pass."""

    T_cam_lidar: np.ndarray
    covariance: np.ndarray
    passes: list[dict]
    correspondences: int


def draw(
    support: np.ndarray | None, n: int, config: SamplingConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Indices and Eq. 4 weights of ``config.per_frame`` of ``n`` candidates: SGIS on their
    support values ``(n,)``, or uniform when ``support`` is ``None``."""
    if support is None:
        index = uniform_sample(n, config.per_frame, rng)
        return index, np.ones(len(index))
    s = np.asarray(support, np.float64)
    index = support_sample(s, config.per_frame, rng, config.floor)
    return index, (s[index] + config.floor if config.weight_by_support else np.ones(len(index)))


def refine_passes(
    frames: Sequence[Frame],
    T_init: np.ndarray,
    matcher: Matcher,
    support: SupportSource,
    config: CalibrateConfig,
    rng: np.random.Generator,
) -> PassesResult:
    """Refine ``T_init`` over ``frames`` (one shared ``K``) in up to ``config.passes`` passes."""
    K = frames[0].K
    if any(not np.allclose(f.K, K) for f in frames):
        raise DataError("frames", "have different intrinsics and cannot share one refinement")
    T, history = np.asarray(T_init, np.float64), []
    for _ in range(config.passes):
        points, targets, weights = [], [], []
        for frame in frames:
            corr = matcher.match(frame, T)
            support_map = support(frame)
            values = None if support_map is None else pixel_lookup(support_map, corr.uv)
            index, w = draw(values, len(corr), config.sampling, rng)
            points.append(corr.points_lidar[index])
            targets.append(corr.uv_matched[index])
            weights.append(w)
        result = refine_extrinsic(
            np.concatenate(points), np.concatenate(targets), np.concatenate(weights), K, T, config.refine
        )
        update = calibration_error(result.T_cam_lidar, T)
        T = result.T_cam_lidar
        history.append(
            {
                "iterations": result.iterations,
                "cost": result.cost,
                "correspondences": int(sum(len(w) for w in weights)),
                "update": update.to_dict(),
            }
        )
        if update.translation_cm < config.min_update_cm and update.rotation_deg < config.min_update_deg:
            break
    return PassesResult(T, result.covariance, history, history[-1]["correspondences"])


def load_calibrate_config(path: Path | None = None) -> CalibrateConfig:
    """``path`` (default: the packaged ``calibrate.yaml``), validated."""
    return load_config(CalibrateConfig, path, "calibrate.yaml")
