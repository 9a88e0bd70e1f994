"""``SupportModule``: the Lightning training system around :class:`SupportUNet`.

Loss: binary cross-entropy of the logits against the offline map, weighted by the coverage (no
LiDAR there means no target there). Validation: weighted MAE, Pearson r and Spearman ρ on whole
held-out frames (:func:`supportnet.nets.map_targets.agreement_scores`).
"""

from __future__ import annotations

import math

import kornia.augmentation as KA
import lightning as L
import numpy as np
import torch
import torch.nn.functional as F
from lightning.pytorch.callbacks import Timer

from supportnet.nets.map_targets import agreement_scores
from supportnet.nets.support_unet import ModelConfig, SupportUNet
from train.gather import gathered
from train.train_config import AugmentConfig, OptimConfig

__all__ = ["SupportModule", "one_cycle", "one_cycle_factor", "photometric", "run_progress", "weighted_bce"]

VAL_PIXELS_PER_FRAME = 20_000
"""Validation keeps at most this many weighted pixels per frame (a fixed subsample) for ρ."""


def weighted_bce(logits: torch.Tensor, target: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """``Σ w · BCE(σ(logits), target) / Σ w`` over all pixels; 0 when no pixel has weight."""
    loss = F.binary_cross_entropy_with_logits(logits, target, reduction="none")
    return (weight * loss).sum() / weight.sum().clamp_min(1e-6)


class SupportModule(L.LightningModule):
    """Trains a :class:`SupportUNet` on offline support maps.

    Args:
        model: network config. optim: learning rate and weight decay. augment: probabilities.
        target: which offline map is learned (stored in the exported contract).
        working_focal_px: the focal length the data's images were resampled to (stored there too).
    """

    def __init__(
        self,
        model: dict,
        optim: dict,
        augment: dict,
        target: str = "agreement",
        working_focal_px: float | None = None,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.net = SupportUNet(ModelConfig(**model))
        self.optim_config = OptimConfig(**optim)
        self.contract = self.net.contract(target, working_focal_px)
        aug = AugmentConfig(**augment)
        # geometric: image, target and weight stacked, so they move together
        self.geometric = KA.AugmentationSequential(
            KA.RandomHorizontalFlip(p=aug.flip),
            KA.RandomAffine(degrees=3.0, translate=(0.05, 0.05), scale=(0.9, 1.1), p=aug.affine),
        )
        self.photometric = photometric(aug.colour, aug.blur)  # the image only
        self.register_buffer("mean", torch.tensor(self.contract.mean).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(self.contract.std).view(1, 3, 1, 1), persistent=False)
        self._val: list[np.ndarray] = []

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """``(B, 3, H, W)`` RGB in [0, 1] → ``(B, 1, H, W)`` logits (normalised per the contract)."""
        return self.net((image - self.mean) / self.std)

    def on_after_batch_transfer(self, batch: dict, dataloader_idx: int) -> dict:
        if not self.training:
            return batch
        stacked = self.geometric(torch.cat([batch["image"], batch["target"], batch["weight"]], dim=1))
        image, target, weight = stacked[:, :3], stacked[:, 3:4], stacked[:, 4:5]
        return {"image": self.photometric(image.clamp(0, 1)), "target": target.clamp(0, 1), "weight": weight}

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        loss = weighted_bce(self(batch["image"]), batch["target"], batch["weight"])
        self.log("train/loss", loss, prog_bar=True, on_step=True, on_epoch=True, sync_dist=True)
        return loss

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        logits = self(batch["image"])
        loss = weighted_bce(logits, batch["target"], batch["weight"])
        self.log("val/loss", loss, on_epoch=True, sync_dist=True)
        pred, target, weight = (  # float32 for numpy: under bf16-mixed the logits are bfloat16
            t.flatten().float().cpu().numpy() for t in (logits.sigmoid(), batch["target"], batch["weight"])
        )
        keep = np.flatnonzero(weight > 0)
        keep = np.random.default_rng(batch_idx).permutation(keep)[:VAL_PIXELS_PER_FRAME]
        self._val.append(np.stack([pred[keep], target[keep], weight[keep]]))

    def on_validation_epoch_end(self) -> None:
        if not self._val:
            return
        pred, target, weight = gathered(np.concatenate(self._val, axis=1))
        self._val.clear()
        scores = agreement_scores(pred, target, weight)
        for name in ("mae", "pearson", "spearman"):
            self.log(f"val/{name}", float(np.nan_to_num(scores[name])), prog_bar=name == "pearson")

    def configure_optimizers(self) -> dict:
        return one_cycle(self, self.optim_config)


def photometric(
    colour: float, blur: float, gamma: float = 0.0, noise: float = 0.0
) -> KA.AugmentationSequential:
    """Colour jitter and blur with these probabilities, for the RGB image only; a gamma in [1/2, 2]
    and Gaussian noise where their probabilities are not 0 (left out, not drawn, where they are:
    a config without them draws what it always drew)."""
    extra = [KA.RandomGamma((0.5, 2.0), p=gamma)] if gamma else []
    extra += [KA.RandomGaussianNoise(std=0.03, p=noise)] if noise else []
    return KA.AugmentationSequential(
        KA.ColorJitter(0.3, 0.3, 0.3, 0.03, p=colour),
        KA.RandomGaussianBlur((5, 5), (0.1, 1.5), p=blur),
        *extra,
    )


def run_progress(trainer: L.Trainer) -> float:
    """How far a run is through its budget, 0 → 1: the optimiser steps done over those planned
    (``max_epochs``), or the training time spent over ``max_time``, whichever is further on. A
    run that ``max_time`` stops early still ends its schedule and curriculum."""
    steps = trainer.global_step / max(trainer.estimated_stepping_batches, 1)
    timers = [c for c in trainer.callbacks if isinstance(c, Timer)]
    if not timers or timers[0].time_remaining("train") is None:
        return min(steps, 1.0)
    elapsed, remaining = timers[0].time_elapsed("train"), timers[0].time_remaining("train")
    return min(max(steps, elapsed / max(elapsed + remaining, 1e-9)), 1.0)


def one_cycle_factor(
    progress: float, warmup: float = 0.3, div: float = 25.0, final_div: float = 1e4
) -> float:
    """The learning rate over its peak at ``progress`` ∈ [0, 1]: torch's ``OneCycleLR`` (cosine
    up from peak/``div`` over ``warmup`` of the run, then down to peak/(``div``·``final_div``))."""
    if progress < warmup:
        low, high, t = 1.0 / div, 1.0, progress / warmup
    else:
        low, high, t = 1.0, 1.0 / (div * final_div), (progress - warmup) / (1.0 - warmup)
    return high + (low - high) * (1.0 + math.cos(math.pi * min(t, 1.0))) / 2.0


def one_cycle(module: L.LightningModule, config: OptimConfig) -> dict:
    """AdamW under a one-cycle schedule over the whole run (:func:`run_progress`), stepped per batch."""
    optimizer = torch.optim.AdamW(module.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    scheduler = torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda _: one_cycle_factor(run_progress(module.trainer))
    )
    return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}
