"""``make model`` and ``make flow-model``: the shipped networks, re-made from nothing with fixed
seeds (``python -m train.recipe support`` and ``... flow``).

The support predictor:

1. Synthetic sequences: three of each world to train on, one of each held out (seed 9), at the
   small 624x188 size (``supportnet synth --small``) the shipped models were trained on.
2. Offline support maps of each (Stage 3 under the reference calibration).
3. Training with ``configs/train.yaml`` (its sources are the folders written here).
4. Export to ONNX (checked) as ``supportnet/assets/support_unet.onnx``.
5. Scores of the exported model on the held-out sequences against their offline maps, written
   with the training summary as the model card ``support_unet.json`` beside it.

The flow matcher: the same synthetic sequences (no maps needed), trained with
``configs/train_flow.yaml``, exported as ``supportnet/assets/flow_matcher.onnx`` with its card
``flow_matcher.json`` (held-out endpoint errors by class).

Steps whose output exists are skipped, so an interrupted run continues where it stopped.
"""

from __future__ import annotations

import json
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from calib.support.support_maps import load_maps_config
from export.onnx_export import export_onnx
from supportnet.cli.cmd_maps import run_maps
from supportnet.cli.cmd_predict import run_predict
from supportnet.cli.cmd_synth import run_synth
from supportnet.cli.console import make_console
from supportnet.cli.output_dir import write_json
from supportnet.runtime.flow_matcher import SHIPPED_FLOW_MODEL
from supportnet.runtime.support_predictor import SHIPPED_MODEL
from train.fit import run_train, run_train_flow
from train.train_config import FlowTrainConfig, TrainConfig, load_train_config

app = typer.Typer(add_completion=False, no_args_is_help=True)

ROOT = Path("build/model")
SEQUENCES = {"01": 1, "02": 2, "03": 3, "09": 9}
"""Sequence name → world seed; ``09`` is held out (``configs/train.yaml`` lists the splits)."""


def _synthesise(frames: int, console: Console, maps: bool) -> None:
    """The synthetic sequences (and their offline maps), each skipped when it exists."""
    for world in ("vineyard", "urban"):
        for sequence, seed in SEQUENCES.items():
            if not (ROOT / world / "sequences" / sequence).is_dir():
                run_synth(world, frames, seed, ROOT / world, sequence, console=console, small=True)
            folder = ROOT / "maps" / f"{world}_{sequence}"
            if maps and not folder.is_dir():
                run_maps(ROOT / world, sequence, folder, load_maps_config(), resume=True, console=console)


def _trained(config: TrainConfig | FlowTrainConfig, run: Callable[..., dict], console: Console) -> dict:
    """The training summary: read back when the run is complete, else trained now."""
    summary_path = Path(config.out) / "summary.json"
    if summary_path.is_file():
        return json.loads(summary_path.read_text())
    return run(config, overwrite=True, console=console)


def _hardware(config: TrainConfig | FlowTrainConfig) -> str:
    """What trained it: the GPU where Lightning's accelerator took one, else the CPU's cores."""
    import torch

    cores = f"{os.cpu_count()} CPU cores"
    if config.trainer.accelerator in ("auto", "gpu", "cuda") and torch.cuda.is_available():
        return f"{torch.cuda.device_count()}x {torch.cuda.get_device_name(0)}, {cores}"
    return f"CPU only, {cores}, {torch.get_num_threads()} torch threads"


def _card(
    out: Path,
    report: dict,
    config: TrainConfig | FlowTrainConfig,
    frames: int,
    summary: dict,
    best: str,
    start: float,
) -> dict:
    """The model card's common part: the file, its checks, what it was trained on and how long."""
    return {
        "model": out.name,
        "bytes": report["bytes"],
        "onnx_parity_max_abs_diff": report["max_abs_diff"],
        "contract": json.loads(report["contract"]),
        "trained_on": [f"{Path(x.data).name}_{x.sequence}" for x in config.data.sources if x.split != "val"],
        "frames_per_sequence": frames,
        "training": {k: summary[k] for k in ("train_frames", "val_frames", "epochs", "minutes", best)},
        "machine": f"{platform.machine()} {platform.system()}, python {platform.python_version()}",
        "hardware": _hardware(config),
        "recipe_minutes": (time.perf_counter() - start) / 60,
    }


@app.command("support")
def make_model(
    frames: Annotated[int, typer.Option(help="Frames per synthetic sequence.")] = 80,
    config: Annotated[Path, typer.Option(help="Training config.")] = Path("configs/train.yaml"),
    out: Annotated[Path, typer.Option(help="ONNX file to write; its model card goes beside it.")] = (
        SHIPPED_MODEL
    ),
) -> None:
    """The support predictor."""
    console = make_console()
    start = time.perf_counter()
    _synthesise(frames, console, maps=True)
    train_config = load_train_config(config)
    summary = _trained(train_config, run_train, console)
    report = export_onnx(Path(summary["best_checkpoint"]), out, overwrite=True)
    held_out = {}
    for source in (s for s in train_config.data.sources if s.split == "val"):
        name = f"{Path(source.data).name}_{source.sequence}"
        scores = run_predict(
            out, source.data, source.sequence, ROOT / "predicted" / name, source.maps, True, console
        )
        held_out[name] = {k: scores[k] for k in ("per_frame", "sequence_map")}
    card = _card(out, report, train_config, frames, summary, "best_val_pearson", start)
    card["held_out_scores"] = held_out
    write_json(out.with_suffix(".json"), card)
    console.print(json.dumps(card["held_out_scores"], indent=1), markup=False, highlight=False)


@app.command("flow")
def make_flow_model(
    frames: Annotated[int, typer.Option(help="Frames per synthetic sequence.")] = 80,
    config: Annotated[Path, typer.Option(help="Training config.")] = Path("configs/train_flow.yaml"),
    out: Annotated[Path, typer.Option(help="ONNX file to write; its model card goes beside it.")] = (
        SHIPPED_FLOW_MODEL
    ),
) -> None:
    """The flow matcher."""
    console = make_console()
    start = time.perf_counter()
    _synthesise(frames, console, maps=False)
    train_config = load_train_config(config, [], FlowTrainConfig)
    summary = _trained(train_config, run_train_flow, console)
    report = export_onnx(Path(summary["best_checkpoint"]), out, overwrite=True)
    card = _card(out, report, train_config, frames, summary, "best_val_epe", start)
    card["held_out_last_epoch"] = {k: v for k, v in summary["final"].items() if k.startswith("val/")}
    write_json(out.with_suffix(".json"), card)
    console.print(json.dumps(card["held_out_last_epoch"], indent=1), markup=False, highlight=False)


if __name__ == "__main__":
    app()
