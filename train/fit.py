"""``supportnet train`` and ``train-flow``: fit with Lightning and keep what a user checks.

Writes into ``<out>`` (built as ``<out>.partial``, renamed when done): ``checkpoints/best.ckpt``
(best validation metric: the support predictor's Pearson r, the flow matcher's endpoint error) and
``last.ckpt``, Lightning's logs, ``learning_curves.png``, ``summary.json`` (best scores, epochs,
minutes) and the resolved ``config.yaml``.
"""

from __future__ import annotations

import logging
import os
import time
import warnings
from pathlib import Path

import lightning as L
import torch
from lightning.pytorch.callbacks import EarlyStopping, ModelCheckpoint
from lightning.pytorch.loggers import CSVLogger, TensorBoardLogger
from rich.console import Console

from supportnet.cli.console import make_console
from supportnet.cli.output_dir import (
    claim_output,
    claim_partial,
    removed_on_failure,
    replace_atomically,
    resolved_config,
    write_json,
    write_marker,
)
from supportnet.report.pictures import learning_curves
from train.support_data import SupportDataModule
from train.support_module import SupportModule
from train.train_config import FlowTrainConfig, TrainConfig, TrainerConfig

__all__ = ["hardware", "run_train", "run_train_flow"]

QUIET = (
    r".*overridden `on_after_batch_transfer`.*",  # intended: augmentation runs on the batch
    r".*treespec, LeafSpec.*",  # a deprecation inside Lightning
    r".*smaller than the logging interval.*",  # tiny runs (tests, fast_dev_run)
)


class _NoAdverts(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return "litlogger" not in record.getMessage()


logging.getLogger("lightning.pytorch.utilities.rank_zero").addFilter(_NoAdverts())


def run_train(config: TrainConfig, overwrite: bool = False, console: Console | None = None) -> dict:
    """Train the support predictor; returns ``summary.json``'s content (with ``best_checkpoint``)."""
    claim_output(Path(config.out), overwrite, _inputs(config))
    module = SupportModule(
        config.model.model_dump(),
        config.optim.model_dump(),
        config.augment.model_dump(),
        config.data.target,
        config.data.working_focal_px,
    )
    with removed_on_failure(_partial(config)):
        return _fit(config, SupportDataModule(config.data), module, "val/pearson", "max", overwrite, console)


def run_train_flow(config: FlowTrainConfig, overwrite: bool = False, console: Console | None = None) -> dict:
    """Train the flow matcher; returns ``summary.json``'s content (with ``best_checkpoint``)."""
    claim_output(Path(config.out), overwrite, _inputs(config))
    from train.flow_data import FlowDataModule
    from train.flow_module import FlowModule

    module = FlowModule(
        config.model.model_dump(),
        config.optim.model_dump(),
        config.augment.model_dump(),
        config.gamma,
        config.data.near_m,
        config.data.working_focal_px,
    )
    if config.init is not None:
        module.load_weights(config.init)
    with removed_on_failure(_partial(config)):
        return _fit(config, FlowDataModule(config.data), module, "val/epe", "min", overwrite, console)


def _inputs(config: TrainConfig | FlowTrainConfig) -> list[Path]:
    """What training reads (the datasets and maps): ``--out`` must not be, hold or replace them."""
    return [p for s in config.data.sources for p in (s.data, getattr(s, "maps", None)) if p is not None]


def _partial(config: TrainConfig | FlowTrainConfig) -> Path:
    out = Path(config.out)
    return out.with_name(out.name + ".partial")


def _fit(
    config: TrainConfig | FlowTrainConfig,
    data: L.LightningDataModule,
    module: L.LightningModule,
    monitor: str,
    mode: str,
    overwrite: bool,
    console: Console | None,
) -> dict:
    """The training run both share: output folder, seeding, checkpoints on ``monitor``, early
    stopping, logs, curves and the summary."""
    console = console or make_console()
    out, partial = Path(config.out), _partial(config)
    claim_output(out, overwrite, _inputs(config))
    if os.environ.get("LOCAL_RANK", "0") == "0":  # DDP's child processes share rank 0's folder
        claim_partial(partial, resume=False)  # a killed run's is removed, another's refused
        partial.mkdir(parents=True)
        write_marker(partial, "train")
    (partial / "config.yaml").write_text(resolved_config(config))
    L.seed_everything(config.seed, workers=True, verbose=False)
    if config.trainer.threads:
        torch.set_num_threads(config.trainer.threads)
    torch.set_float32_matmul_precision("high")  # TF32 on a GPU that has it; no effect on a CPU
    data.setup()
    console.print(
        f"training on {len(data.train)} frames, validating on {len(data.val)} held-out frames",
        markup=False,
        highlight=False,
    )
    best = ModelCheckpoint(
        partial / "checkpoints", filename="best", monitor=monitor, mode=mode, save_last=True
    )
    trainer = _trainer(
        config.trainer, partial, [best, EarlyStopping(monitor, mode=mode, patience=config.trainer.patience)]
    )
    start = time.perf_counter()
    with warnings.catch_warnings():
        for pattern in QUIET:
            warnings.filterwarnings("ignore", message=pattern)
        trainer.fit(module, datamodule=data)
    minutes = (time.perf_counter() - start) / 60
    if trainer.global_rank != 0:
        return {}
    key = "best_" + monitor.replace("/", "_")
    summary = {
        "train_frames": len(data.train),
        "val_frames": len(data.val),
        "epochs": trainer.current_epoch,
        "minutes": minutes,
        "hardware": hardware(trainer),
        key: float(best.best_model_score) if best.best_model_score is not None else None,
        "final": {k: float(v) for k, v in trainer.callback_metrics.items()},
        "best_checkpoint": str(out / "checkpoints" / "best.ckpt") if best.best_model_path else None,
        "last_checkpoint": str(out / "checkpoints" / "last.ckpt"),
    }
    if config.trainer.fast_dev_run:  # no checkpoints in a fast dev run: keep the weights to export them
        trainer.save_checkpoint(partial / "checkpoints" / "last.ckpt")
    metrics = partial / "logs" / "metrics.csv"
    if metrics.is_file():
        learning_curves(metrics, partial / "learning_curves.png")
    write_json(partial / "summary.json", summary)
    claim_output(out, overwrite, _inputs(config))
    replace_atomically([(partial, out)])
    score = summary[key] if summary[key] is not None else float("nan")
    console.print(
        f"trained {summary['epochs']} epochs in {minutes:.1f} min; best {monitor} {score:.3f}; "
        f"checkpoints in {out / 'checkpoints'}",
        markup=False,
        highlight=False,
    )
    return summary


def hardware(trainer: L.Trainer) -> str:
    """What trained it: the GPUs Lightning used, else the CPU's cores."""
    cores = f"{os.cpu_count()} CPU cores"
    if trainer.strategy.root_device.type == "cuda":
        return f"{trainer.num_devices}x {torch.cuda.get_device_name(trainer.strategy.root_device)}, {cores}"
    return f"CPU only, {cores}, {torch.get_num_threads()} torch threads"


def _trainer(t: TrainerConfig, root: Path, callbacks: list) -> L.Trainer:
    logger = (CSVLogger if t.logger == "csv" else TensorBoardLogger)(root, name="logs", version="")
    return L.Trainer(
        accelerator=t.accelerator,
        devices=t.devices,
        strategy=t.strategy,
        precision=t.precision,
        max_epochs=t.max_epochs,
        max_time={"minutes": t.max_time_min},
        logger=logger,
        callbacks=callbacks,
        log_every_n_steps=t.log_every_n_steps,
        fast_dev_run=t.fast_dev_run,
        # deterministic kernels wherever they exist; CUDA's bilinear backward has none, so a GPU run
        # warns there instead of refusing to train
        deterministic="warn",
        enable_model_summary=False,
    )
