"""Stage 2 matchers by name (``--matcher``), so every command builds and refuses them alike."""

from __future__ import annotations

from pathlib import Path

from calib.errors import SupportnetError
from calib.match.correspondences import Matcher
from calib.match.edge_matcher import EdgeMatcher, EdgeMatcherConfig
from calib.refine.passes import CalibrateConfig

__all__ = ["build_matcher", "coarse_matcher"]


def build_matcher(name: str, edge: EdgeMatcherConfig, flow_model: Path | None = None) -> Matcher:
    """The matcher ``name``: ``edge`` (training-free) or ``flow`` (the learned one, from
    ``flow_model`` or, when ``None``, the shipped model)."""
    if name == "edge":
        return EdgeMatcher(edge)
    if name == "flow":
        from supportnet.runtime.flow_matcher import SHIPPED_FLOW_MODEL, FlowMatcher

        return FlowMatcher(flow_model or SHIPPED_FLOW_MODEL)
    raise SupportnetError(f"--matcher {name}: unknown matcher (edge or flow)")


def coarse_matcher(config: CalibrateConfig) -> Matcher | None:
    """The learned flow matcher where ``config.flow_coarse_passes`` asks for its passes, else ``None``."""
    return build_matcher("flow", config.edge, config.flow_model) if config.flow_coarse_passes else None
