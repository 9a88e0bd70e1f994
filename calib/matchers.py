"""Stage 2 matchers by name (``--matcher``), so every command builds and refuses them alike."""

from __future__ import annotations

from calib.edge_matcher import EdgeMatcher, EdgeMatcherConfig
from calib.errors import SupportnetError
from calib.matching import Matcher

__all__ = ["build_matcher"]


def build_matcher(name: str, edge: EdgeMatcherConfig) -> Matcher:
    """The matcher ``name`` (``edge``; ``flow`` once the learned matcher exists)."""
    if name == "edge":
        return EdgeMatcher(edge)
    if name == "flow":
        raise SupportnetError("--matcher flow: the learned flow matcher is not built yet; use --matcher edge")
    raise SupportnetError(f"--matcher {name}: unknown matcher (edge or flow)")
