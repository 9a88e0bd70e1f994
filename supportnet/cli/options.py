"""Options shared by several commands, declared once."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated

import typer

from calib.errors import ConfigError
from calib.seeds import check_seed

__all__ = ["Camera", "Overwrite", "in_range", "seed_of"]

Overwrite = Annotated[
    bool,
    typer.Option("--overwrite", help="Replace an existing result that supportnet wrote (nothing else)."),
]

Camera = Annotated[
    str | None,
    typer.Option(
        help="Camera where the dataset has several: a KITTI index (0-3; default 2, the left colour "
        "camera) or a ROS bag's image topic (default: its only one).",
    ),
]


def in_range(option: str, low: float, high: float) -> Callable[[float | None], float | None]:
    """A typer callback passing a value in ``[low, high]`` (or ``None``) and refusing anything
    else, NaN and infinity included, with one line naming ``option`` (a ConfigError, exit 2)."""

    def check(value: float | None) -> float | None:
        if value is None or low <= value <= high:  # False for NaN
            return value
        raise ConfigError(option, f"must be from {low:g} to {high:g}, got {value}")

    return check


def seed_of(option: str = "--seed") -> Callable[[int], int]:
    """A typer callback refusing a seed outside ``[0, 2³²)`` with one line naming ``option``."""
    return lambda value: check_seed(value, option)
