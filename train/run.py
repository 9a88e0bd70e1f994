"""``supportnet train``: fit the support predictor with Lightning and keep what a user checks.

Writes into ``<out>`` (built as ``<out>.partial``, renamed when done): ``checkpoints/best.ckpt``
(highest validation Pearson r) and ``last.ckpt``, Lightning's logs, ``learning_curves.png``,
``summary.json`` (best scores, epochs, minutes) and the resolved ``config.yaml``.
"""

from __future__ import annotations

import logging
import os
import shutil
import time
import warnings
from pathlib import Path

import lightning as L
import torch
from lightning.pytorch.callbacks import EarlyStopping, ModelCheckpoint
from lightning.pytorch.loggers import CSVLogger, TensorBoardLogger
from rich.console import Console

from calib.errors import DataError
from supportnet.outputs import resolved_config, write_json
from supportnet.viz import learning_curves
from train.config import TrainConfig
from train.data import SupportDataModule
from train.module import SupportModule

__all__ = ["run_train"]

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
    """Train; returns ``summary.json``'s content (with ``best_checkpoint`` under ``config.out``)."""
    console = console or Console(stderr=True)
    out = Path(config.out)
    if out.exists() and not overwrite:
        raise DataError(out, "already exists; pass --overwrite to replace it")
    partial = out.with_name(out.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir(parents=True)
    (partial / "config.yaml").write_text(resolved_config(config))
    L.seed_everything(config.seed, workers=True, verbose=False)
    if config.trainer.threads:
        torch.set_num_threads(config.trainer.threads)
    data = SupportDataModule(config.data)
    data.setup()
    console.print(
        f"training on {len(data.train)} frames, validating on {len(data.val)} held-out frames",
        markup=False,
        highlight=False,
    )
    module = SupportModule(
        config.model.model_dump(), config.optim.model_dump(), config.augment.model_dump(), config.data.target
    )
    t = config.trainer
    logger = (CSVLogger if t.logger == "csv" else TensorBoardLogger)(partial, name="logs", version="")
    best = ModelCheckpoint(
        partial / "checkpoints", filename="best", monitor="val/pearson", mode="max", save_last=True
    )
    trainer = L.Trainer(
        accelerator=t.accelerator,
        devices=t.devices,
        strategy=t.strategy,
        precision=t.precision,
        max_epochs=t.max_epochs,
        max_time={"minutes": t.max_time_min},
        logger=logger,
        callbacks=[best, EarlyStopping("val/pearson", mode="max", patience=t.patience)],
        log_every_n_steps=t.log_every_n_steps,
        fast_dev_run=t.fast_dev_run,
        deterministic=True,
        enable_model_summary=False,
    )
    start = time.perf_counter()
    with warnings.catch_warnings():
        for pattern in QUIET:
            warnings.filterwarnings("ignore", message=pattern)
        trainer.fit(module, datamodule=data)
    minutes = (time.perf_counter() - start) / 60
    if trainer.global_rank != 0:
        return {}
    summary = {
        "train_frames": len(data.train),
        "val_frames": len(data.val),
        "epochs": trainer.current_epoch,
        "minutes": minutes,
        "best_val_pearson": float(best.best_model_score) if best.best_model_score is not None else None,
        "final": {k: float(v) for k, v in trainer.callback_metrics.items()},
        "best_checkpoint": str(out / "checkpoints" / "best.ckpt") if best.best_model_path else None,
        "last_checkpoint": str(out / "checkpoints" / "last.ckpt"),
    }
    if t.fast_dev_run:  # no checkpoints in a fast dev run: keep the weights to export them
        trainer.save_checkpoint(partial / "checkpoints" / "last.ckpt")
    metrics = partial / "logs" / "metrics.csv"
    if metrics.is_file():
        learning_curves(metrics, partial / "learning_curves.png")
    write_json(partial / "summary.json", summary)
    if out.exists():
        shutil.rmtree(out)
    os.replace(partial, out)
    console.print(
        f"trained {summary['epochs']} epochs in {minutes:.1f} min; best validation Pearson r "
        f"{summary['best_val_pearson'] or float('nan'):.3f}; checkpoints in {out / 'checkpoints'}",
        markup=False,
        highlight=False,
    )
    return summary
