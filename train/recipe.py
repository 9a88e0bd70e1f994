"""``make model``: the shipped support predictor, re-made from nothing with fixed seeds.

1. Synthetic sequences: three of each world to train on, one of each held out (seed 9).
2. Offline support maps of each (Stage 3 under the reference calibration).
3. Training with ``configs/train.yaml`` (its sources are the folders written here).
4. Export to ONNX (checked) as ``supportnet/assets/support_unet.onnx``.
5. Scores of the exported model on the held-out sequences against their offline maps, written
   with the training summary as the model card ``support_unet.json`` beside it.

Steps whose output exists are skipped, so an interrupted run continues where it stopped.
"""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from export.onnx import export_onnx
from supportnet.maps import load_maps_config, run_maps
from supportnet.outputs import write_json
from supportnet.predict import run_predict
from supportnet.predictor import SHIPPED_MODEL
from supportnet.synth import run_synth
from train.config import load_train_config
from train.run import run_train

ROOT = Path("build/model")
SEQUENCES = {"01": 1, "02": 2, "03": 3, "09": 9}
"""Sequence name → world seed; ``09`` is held out (``configs/train.yaml`` lists the splits)."""


def make_model(
    frames: Annotated[int, typer.Option(help="Frames per synthetic sequence.")] = 80,
    config: Annotated[Path, typer.Option(help="Training config.")] = Path("configs/train.yaml"),
    out: Annotated[Path, typer.Option(help="ONNX file to write; its model card goes beside it.")] = (
        SHIPPED_MODEL
    ),
) -> None:
    console = Console(stderr=True)
    start = time.perf_counter()
    for world in ("vineyard", "urban"):
        for sequence, seed in SEQUENCES.items():
            if not (ROOT / world / "sequences" / sequence).is_dir():
                run_synth(world, frames, seed, ROOT / world, sequence, console=console)
            maps = ROOT / "maps" / f"{world}_{sequence}"
            if not maps.is_dir():
                run_maps(ROOT / world, sequence, maps, load_maps_config(), resume=True, console=console)
    train_config = load_train_config(config)
    summary_path = Path(train_config.out) / "summary.json"
    if summary_path.is_file():
        summary = json.loads(summary_path.read_text())
    else:
        summary = run_train(train_config, overwrite=True, console=console)
    report = export_onnx(Path(summary["best_checkpoint"]), out, overwrite=True)
    held_out = {}
    for source in (s for s in train_config.data.sources if s.split == "val"):
        name = f"{Path(source.data).name}_{source.sequence}"
        scores = run_predict(
            out, source.data, source.sequence, ROOT / "predicted" / name, source.maps, True, console
        )
        held_out[name] = {k: scores[k] for k in ("per_frame", "sequence_map")}
    card = {
        "model": out.name,
        "bytes": report["bytes"],
        "onnx_parity_max_abs_diff": report["max_abs_diff"],
        "contract": json.loads(report["contract"]),
        "trained_on": [
            f"{Path(s.data).name}_{s.sequence}" for s in train_config.data.sources if s.split == "train"
        ],
        "frames_per_sequence": frames,
        "training": {
            k: summary[k] for k in ("train_frames", "val_frames", "epochs", "minutes", "best_val_pearson")
        },
        "held_out_scores": held_out,
        "machine": f"{platform.machine()} {platform.system()}, python {platform.python_version()}",
        "recipe_minutes": (time.perf_counter() - start) / 60,
    }
    write_json(out.with_suffix(".json"), card)
    console.print(json.dumps(card["held_out_scores"], indent=1), markup=False, highlight=False)


if __name__ == "__main__":
    typer.run(make_model)
