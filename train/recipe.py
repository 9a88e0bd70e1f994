"""``make model`` and ``make flow-model``: the shipped networks, re-made from nothing with fixed
seeds (``python -m train.recipe support`` and ``... flow``).

The support predictor:

1. Synthetic sequences: those ``configs/train.yaml`` names (three of each world to train on, one
   of each held out, each sequence named by its seed), at the small 624x188 size (``supportnet
   synth --small``) the shipped models were trained on.
2. Offline support maps of each (Stage 3 under the reference calibration).
3. Training with ``configs/train.yaml`` (its sources are the folders written here).
4. Export to ONNX (checked) as ``supportnet/assets/support_unet.onnx``, and that quantised to 8
   bits on the training sequences' images (checked against it) as ``support_unet_int8.onnx``,
   the model Stage 3 runs by default.
5. Scores of both on the held-out sequences against their offline maps, written with the
   training summary as the model card ``support_unet.json`` beside them.

The flow matcher: full-resolution synthetic sequences, 16 seeds of each world (no maps needed),
packed into frame packs (``train.flow_data.write_frames``), trained with
``configs/train_flow.yaml`` (sized for one GPU; on a CPU it stops at its time limit), exported as
``supportnet/assets/flow_matcher.onnx`` with its card ``flow_matcher.json`` (held-out endpoint
errors by class). Where the packs exist, nothing is synthesised: a GPU machine needs the packs
alone.

Steps whose output exists are skipped, so an interrupted run continues where it stopped.
"""

from __future__ import annotations

import json
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from calib.support.support_maps import load_maps_config
from export.onnx_export import export_onnx, quantise_onnx, run_time_images
from supportnet.cli.cmd_maps import run_maps
from supportnet.cli.cmd_predict import run_predict
from supportnet.cli.cmd_synth import run_synth
from supportnet.cli.console import make_console
from supportnet.cli.output_dir import write_json
from supportnet.runtime.flow_matcher import SHIPPED_FLOW_MODEL
from supportnet.runtime.support_predictor import SHIPPED_FLOAT_MODEL, SHIPPED_MODEL
from train.fit import run_train, run_train_flow
from train.train_config import FlowTrainConfig, TrainConfig, load_train_config

app = typer.Typer(add_completion=False, no_args_is_help=True)


def _synthesise(sources: list, frames: int, console: Console, small: bool) -> None:
    """Every source of a training config, each skipped when it exists: the synthetic world named
    by its folder (``build/model/urban``) with the seed its sequence names, and its offline support
    maps where the source has a ``maps`` folder."""
    for source in sources:
        world, seed = Path(source.data).name, int(source.sequence)
        if not (Path(source.data) / "sequences" / source.sequence).is_dir():
            run_synth(world, frames, seed, Path(source.data), source.sequence, console=console, small=small)
        maps = getattr(source, "maps", None)
        if maps is not None and not Path(maps).is_dir():
            run_maps(
                Path(source.data),
                source.sequence,
                Path(maps),
                load_maps_config(),
                resume=True,
                console=console,
            )


def _trained(config: TrainConfig | FlowTrainConfig, run: Callable[..., dict], console: Console) -> dict:
    """The training summary: read back when the run is complete, else trained now."""
    summary_path = Path(config.out) / "summary.json"
    if summary_path.is_file():
        return json.loads(summary_path.read_text())
    return run(config, overwrite=True, console=console)


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
        "hardware": summary.get("hardware", "not recorded"),
        "recipe_minutes": (time.perf_counter() - start) / 60,
    }


@app.command("support")
def make_model(
    frames: Annotated[int, typer.Option(help="Frames per synthetic sequence.")] = 80,
    config: Annotated[Path, typer.Option(help="Training config.")] = Path("configs/train.yaml"),
    out: Annotated[Path, typer.Option(help="ONNX file to write; its model card goes beside it.")] = (
        SHIPPED_FLOAT_MODEL
    ),
    int8_out: Annotated[Path, typer.Option(help="The 8-bit model to write.")] = SHIPPED_MODEL,
    int8_frames: Annotated[int, typer.Option(help="Images per training sequence for its ranges.")] = 8,
) -> None:
    """The support predictor, as trained and quantised to 8 bits."""
    console = make_console()
    start = time.perf_counter()
    train_config = load_train_config(config)
    _synthesise(train_config.data.sources, frames, console, small=True)
    summary = _trained(train_config, run_train, console)
    report = export_onnx(Path(summary["best_checkpoint"]), out, overwrite=True)
    card = _card(out, report, train_config, frames, summary, "best_val_pearson", start)
    _quantised(card, out, int8_out, train_config, int8_frames, console)


@app.command("support-int8")
def make_int8_model(
    frames: Annotated[int, typer.Option(help="Frames per synthetic sequence.")] = 80,
    config: Annotated[Path, typer.Option(help="Training config.")] = Path("configs/train.yaml"),
    model: Annotated[Path, typer.Option(help="The float model; its card is updated.")] = SHIPPED_FLOAT_MODEL,
    int8_out: Annotated[Path, typer.Option(help="The 8-bit model to write.")] = SHIPPED_MODEL,
    int8_frames: Annotated[int, typer.Option(help="Images per training sequence for its ranges.")] = 8,
) -> None:
    """The 8-bit support predictor alone, from the float one (its training data re-made)."""
    console = make_console()
    train_config = load_train_config(config)
    _synthesise(train_config.data.sources, frames, console, small=True)
    card = json.loads(model.with_suffix(".json").read_text())
    _quantised(card, model, int8_out, train_config, int8_frames, console)


def _quantised(
    card: dict, out: Path, int8_out: Path, config: TrainConfig, frames: int, console: Console
) -> None:
    """Quantise ``out`` to ``int8_out`` on ``frames`` images of each training sequence, score both
    on the held-out sequences, and write the model card (``card`` with both) beside ``out``."""
    trained_on = [(Path(s.data), s.sequence) for s in config.data.sources if s.split == "train"]
    quantised = quantise_onnx(out, int8_out, run_time_images(out, trained_on, frames), overwrite=True)
    held_out: dict = {out.name: {}, int8_out.name: {}}
    for model in (out, int8_out):
        for source in (s for s in config.data.sources if s.split == "val"):
            name = f"{Path(source.data).name}_{source.sequence}"
            scores = run_predict(
                model,
                source.data,
                source.sequence,
                Path("build/model/predicted") / model.stem / name,
                source.maps,
                True,
                console,
            )
            held_out[model.name][name] = {k: scores[k] for k in ("per_frame", "sequence_map")}
    card["int8"] = {"model": int8_out.name} | {
        k: quantised[k] for k in ("bytes", "calibration_images", "max_abs_support_diff")
    }
    card["held_out_scores"] = held_out
    write_json(out.with_suffix(".json"), card)
    console.print(json.dumps(held_out, indent=1), markup=False, highlight=False)
    console.print(json.dumps(card["held_out_scores"], indent=1), markup=False, highlight=False)


def _flow_data(config: Path, frames: int, console: Console) -> FlowTrainConfig:
    """The flow config, its synthetic sequences written and packed (skipped where packs exist)."""
    from train.flow_data import FlowDataModule

    train_config = load_train_config(config, [], FlowTrainConfig)
    cache = train_config.data.cache
    if cache is None or not all((cache / f"{split}.npz").is_file() for split in ("train", "val")):
        _synthesise(train_config.data.sources, frames, console, small=False)
        FlowDataModule(train_config.data).setup()  # writes the packs where data.cache is set
    return train_config


@app.command("flow-data")
def make_flow_data(
    frames: Annotated[int, typer.Option(help="Frames per synthetic sequence.")] = 24,
    config: Annotated[Path, typer.Option(help="Training config.")] = Path("configs/train_flow.yaml"),
) -> None:
    """The flow matcher's training data alone, packed into the config's data.cache: what a GPU
    machine needs to run ``supportnet train-flow`` (carry the folder there)."""
    console = make_console()
    cache = _flow_data(config, frames, console).data.cache
    console.print(f"frame packs in {cache}", markup=False, highlight=False)


@app.command("flow")
def make_flow_model(
    frames: Annotated[int, typer.Option(help="Frames per synthetic sequence.")] = 24,
    config: Annotated[Path, typer.Option(help="Training config.")] = Path("configs/train_flow.yaml"),
    out: Annotated[Path, typer.Option(help="ONNX file to write; its model card goes beside it.")] = (
        SHIPPED_FLOW_MODEL
    ),
) -> None:
    """The flow matcher."""
    console = make_console()
    start = time.perf_counter()
    train_config = _flow_data(config, frames, console)
    summary = _trained(train_config, run_train_flow, console)
    report = export_onnx(Path(summary["best_checkpoint"]), out, overwrite=True)
    card = _card(out, report, train_config, frames, summary, "best_val_epe", start)
    card["held_out_last_epoch"] = {k: v for k, v in summary["final"].items() if k.startswith("val/")}
    write_json(out.with_suffix(".json"), card)
    console.print(json.dumps(card["held_out_last_epoch"], indent=1), markup=False, highlight=False)


if __name__ == "__main__":
    app()
