"""Options shared by several commands, declared once."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from calib.errors import ConfigError
from calib.seeds import check_seed

if TYPE_CHECKING:  # the CLI imports torch only when a command runs
    from calib.refine.passes import TimeOffsetConfig

__all__ = ["Camera", "Milliseconds", "Overwrite", "Rig", "in_range", "seed_of", "time_offset_setting"]

Overwrite = Annotated[
    bool,
    typer.Option("--overwrite", help="Replace an existing result that supportnet wrote (nothing else)."),
]

Camera = Annotated[
    str | None,
    typer.Option(
        help="Camera where the dataset has several: a KITTI index (0-3; default 2, the left colour "
        "camera), a ROS bag's image topic (default: its only one; or its topics as "
        "image=TOPIC,cloud=TOPIC,info=TOPIC,max_gap_ms=MS, any of them) or a nuScenes channel "
        "(default CAM_FRONT).",
    ),
]

SequenceName = Annotated[
    str | None,
    typer.Option(
        "--sequence", help="Sequence (KITTI odometry), drive (KITTI raw) or scene (nuScenes: name or token)."
    ),
]

Rig = Annotated[
    list[Path] | None,
    typer.Option(
        help="Another camera of --data's rig (a dataset of one camera and the same scans, paired by "
        "position; repeat for each): the cameras together, their extrinsics taken as right relative "
        "to each other; the extrinsic is --data's camera's (README: Several cameras: a rig).",
    ),
]


RigCameraOption = Annotated[
    list[str] | None,
    typer.Option(
        "--rig-camera",
        help="Another camera of --data's own dataset in its rig (as --camera names it, e.g. a "
        "nuScenes channel; repeat for each): calibrated or checked together as --rig's.",
    ),
]


def Milliseconds(option: str, help: str) -> object:  # noqa: N802 (used as a type, like Camera)
    """An optional ``float`` option in milliseconds, -1000 to 1000 (``--camera-offset-ms``)."""
    return Annotated[float | None, typer.Option(option, help=help, callback=in_range(option, -1000, 1000))]


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


def time_offset_setting(text: str, base: TimeOffsetConfig) -> TimeOffsetConfig:
    """``--time-offset``: ``off``, ``estimate`` or ``fixed:MS`` (milliseconds, -1000 to 1000)
    applied to the config's ``time_offset`` group."""
    if text in ("off", "estimate"):
        return base.model_copy(update={"mode": text})
    if text.startswith("fixed:"):
        try:
            ms = float(text.removeprefix("fixed:"))
        except ValueError:
            ms = float("nan")
        if not -1000 <= ms <= 1000:  # False for NaN
            raise ConfigError(
                "--time-offset", f"fixed:MS takes milliseconds from -1000 to 1000, got {text!r}"
            )
        return base.model_copy(update={"mode": "fixed", "initial_s": ms / 1000})
    raise ConfigError("--time-offset", f"{text!r} is not off, estimate or fixed:MS")
