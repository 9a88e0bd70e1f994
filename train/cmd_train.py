"""``supportnet train`` and ``supportnet train-flow``: registered with the ``supportnet`` command
line through the ``supportnet.commands`` entry point (``pyproject.toml``), so the CLI never
imports ``train`` (imports go one way: ``calib`` ← ``supportnet`` ← ``train``). Heavy modules are
imported inside each command."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from calib.errors import ConfigError
from supportnet.cli.options import Overwrite

__all__ = ["register"]

Accelerator = Annotated[
    str | None,
    typer.Option(help="auto (a GPU where there is one), cpu, gpu [default: the config's]."),
]
Devices = Annotated[
    str | None, typer.Option(help="How many devices (or which: '0,1'); -1: all [default: the config's].")
]
Precision = Annotated[
    str | None,
    typer.Option(help="Lightning precision: 32-true, 16-mixed, bf16-mixed (GPUs) [default: the config's]."),
]


def _with_trainer(
    overrides: list[str] | None, accelerator: str | None, devices: str | None, precision: str | None
) -> list[str]:
    """The ``key.sub=value`` overrides with the trainer flags after them (flags win), each flag
    checked first (:class:`ConfigError` naming it: ``--accelerator tpu``, ``--devices abc``)."""
    from train.train_config import accelerator_value, devices_value, precision_value

    flags = {"accelerator": accelerator, "devices": devices, "precision": precision}
    checks = {"accelerator": accelerator_value, "devices": devices_value, "precision": precision_value}
    for key, value in flags.items():
        if value is not None:
            try:
                checks[key](value)
            except ValueError as exc:
                raise ConfigError(f"--{key}", f"{exc} (got {value!r})") from None
    return [*(overrides or []), *(f"trainer.{k}={v}" for k, v in flags.items() if v is not None)]


def _checked_here(config, flags: dict[str, str | None]):
    """``config`` if this machine can run its trainer settings, else :class:`ConfigError` naming
    the flag (or the ``trainer.`` key of the config or an override), before any data is read or
    any training starts."""
    from train.train_config import trainer_problem_here

    found = trainer_problem_here(config.trainer)
    if found is None:
        return config
    field, problem = found
    raise ConfigError(f"--{field}" if flags.get(field) is not None else f"trainer.{field}", problem)


def train(
    config: Annotated[
        Path | None, typer.Option(help="Training config (default: the packaged train.yaml).")
    ] = None,
    overrides: Annotated[
        list[str] | None,
        typer.Argument(help="key.sub=value overrides, e.g. trainer.max_epochs=5 data.batch_size=16."),
    ] = None,
    accelerator: Accelerator = None,
    devices: Devices = None,
    precision: Precision = None,
    overwrite: Overwrite = False,
) -> None:
    """Train the support predictor (Lightning) on offline maps: checkpoints, logs, learning curves."""
    from train.fit import run_train
    from train.train_config import load_train_config

    flags = {"accelerator": accelerator, "devices": devices, "precision": precision}
    loaded = load_train_config(config, _with_trainer(overrides, accelerator, devices, precision))
    run_train(_checked_here(loaded, flags), overwrite)


def train_flow(
    config: Annotated[
        Path | None, typer.Option(help="Training config (default: the packaged train_flow.yaml).")
    ] = None,
    overrides: Annotated[
        list[str] | None,
        typer.Argument(help="key.sub=value overrides, e.g. trainer.max_epochs=5 model.iterations=4."),
    ] = None,
    accelerator: Accelerator = None,
    devices: Devices = None,
    precision: Precision = None,
    overwrite: Overwrite = False,
) -> None:
    """Train the learned flow matcher (Lightning) on calibrated sequences: random extrinsic errors
    and the flow they cause; checkpoints, logs, learning curves."""
    from train.fit import run_train_flow
    from train.train_config import FlowTrainConfig, load_train_config

    flags = {"accelerator": accelerator, "devices": devices, "precision": precision}
    loaded = load_train_config(
        config, _with_trainer(overrides, accelerator, devices, precision), FlowTrainConfig
    )
    run_train_flow(_checked_here(loaded, flags), overwrite)


def register(app: typer.Typer) -> None:
    """Add ``train`` and ``train-flow`` to ``app``."""
    app.command()(train)
    app.command("train-flow")(train_flow)
