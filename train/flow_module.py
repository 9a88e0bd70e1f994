"""``FlowModule``: the Lightning training system around :class:`FlowNet`.

Loss (RAFT Eq. 7): ``Σ_i γ^(N−i) ‖f_gt − f_i‖₁`` over the refinement steps, on LiDAR pixels only
(elsewhere there is no point, so no flow to learn). Validation: endpoint error of the last step on
whole held-out frames under fixed extrinsic errors, overall and split by class (rigid structure,
foliage), beside the error of predicting no flow at all.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import lightning as L
import numpy as np
import torch

from calib.data.classes import RIGID_CLASSES
from calib.errors import DataError
from supportnet.nets.flow_net import LIDAR_CHANNELS, FlowConfig, FlowNet
from train.gather import gathered
from train.support_module import one_cycle, photometric, run_progress
from train.train_config import FlowAugmentConfig, OptimConfig

__all__ = ["FOLIAGE_CLASSES", "FlowModule", "sequence_loss"]

MIRROR_SIGNS = {
    "flow": (-1.0, 1.0),
    "lidar": tuple(-1.0 if name == "edge_sin" else 1.0 for name in LIDAR_CHANNELS),
}
"""Channels that change sign in a mirrored image: flow x, and sin 2θ of an edge at angle θ."""
INTENSITY = LIDAR_CHANNELS.index("relative_intensity")
FOLIAGE_CLASSES = {70}
"""Vegetation (the synthetic worlds' swaying leaves), the class CMRNext-style matching finds hard."""


def sequence_loss(
    flows: list[torch.Tensor], target: torch.Tensor, valid: torch.Tensor, gamma: float
) -> torch.Tensor:
    """RAFT Eq. 7 on the valid pixels: ``Σ_i γ^(N−i) mean_valid ‖f_gt − f_i‖₁``."""
    n = len(flows)
    count = valid.sum().clamp_min(1.0)
    return sum(
        gamma ** (n - 1 - i) * ((f - target).abs().sum(1, keepdim=True) * valid).sum() / count
        for i, f in enumerate(flows)
    )


class FlowModule(L.LightningModule):
    """Trains a :class:`FlowNet` on perturbed projections (:mod:`train.flow_data`).

    Args:
        model: network config. optim: learning rate and weight decay. augment: probabilities.
        gamma: RAFT's step weight. near_m, working_focal_px: the data's LiDAR encoding and
            resolution, stored in the exported contract.
    """

    def __init__(
        self, model: dict, optim: dict, augment: dict, gamma: float, near_m: float, working_focal_px: float
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.net = FlowNet(FlowConfig(**model))
        self.optim_config = OptimConfig(**optim)
        self.augment = FlowAugmentConfig(**augment)
        self.photometric = photometric(
            self.augment.colour, self.augment.blur, self.augment.gamma, self.augment.noise
        )
        self.contract = self.net.contract(near_m, working_focal_px)
        self.register_buffer("mean", torch.tensor(self.contract.mean).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(self.contract.std).view(1, 3, 1, 1), persistent=False)
        self._val: list[np.ndarray] = []

    def load_weights(self, path: Path) -> None:
        """The network's weights from a checkpoint of the same architecture, or from an exported
        flow matcher (``.onnx``, e.g. the shipped one: its initialisers carry the parameter names),
        for fine-tuning.

        Raises:
            DataError: not readable, another network's weights, or an ONNX model drawn with
                another LiDAR encoding or working resolution than this run's data."""
        path = Path(path)
        try:
            if path.suffix == ".onnx":
                self.net.load_state_dict(self._onnx_weights(path))
            else:
                state = torch.load(path, map_location="cpu", weights_only=False)["state_dict"]
                # the network's alone: the augmentation (kornia's buffers) may differ from the run's
                self.net.load_state_dict(
                    {k.removeprefix("net."): v for k, v in state.items() if k.startswith("net.")}
                )
        except (OSError, KeyError, RuntimeError, ValueError, pickle.UnpicklingError) as error:
            first = str(error).splitlines()[0] if str(error) else type(error).__name__
            raise DataError(path, f"holds no weights of this flow network ({first})") from None

    def _onnx_weights(self, path: Path) -> dict[str, torch.Tensor]:
        import onnx
        from onnx import numpy_helper

        from supportnet.nets.contract import METADATA_KEY, Contract

        try:
            model = onnx.load(str(path))
        except OSError:
            raise
        except Exception as error:  # protobuf's own error types for a file that is not ONNX
            raise ValueError(f"not an ONNX model ({type(error).__name__})") from None
        meta = {p.key: p.value for p in model.metadata_props}
        if METADATA_KEY not in meta:
            raise ValueError("no supportnet contract in its metadata")
        theirs = Contract.from_json(meta[METADATA_KEY]).extra
        ours = Contract.from_json(self.contract.to_json()).extra  # as JSON holds it
        if theirs != ours:
            raise ValueError(f"drawn with {theirs}, this run's data with {ours}")
        return {i.name: torch.from_numpy(numpy_helper.to_array(i).copy()) for i in model.graph.initializer}

    def forward(self, image: torch.Tensor, lidar: torch.Tensor, all_iterations: bool = False):
        """``image (B, 3, H, W)`` RGB in [0, 1] (normalised per the contract), ``lidar (B, 5, H, W)``."""
        return self.net((image - self.mean) / self.std, lidar, all_iterations)

    def on_train_epoch_start(self) -> None:
        self.trainer.datamodule.set_progress(run_progress(self.trainer))

    def on_after_batch_transfer(self, batch: dict, dataloader_idx: int) -> dict:
        if not self.training:
            return batch
        batch = dict(batch)
        mirror = torch.rand(len(batch["image"]), device=self.device) < self.augment.flip
        for key in ("image", "lidar", "flow", "valid", "label"):  # a mirrored world
            flipped = batch[key].flip(-1)
            if key in MIRROR_SIGNS:
                flipped = flipped * torch.tensor(MIRROR_SIGNS[key], device=self.device).view(1, -1, 1, 1)
            batch[key] = torch.where(mirror.view(-1, 1, 1, 1), flipped, batch[key])
        batch["image"] = self.photometric(batch["image"]).clamp(0, 1)
        return self._sensor_variety(batch)

    def _sensor_variety(self, batch: dict) -> dict:
        """Other cameras and LiDARs than the synthetic ones: grey images, intensity response
        curves (a power in [1/2, 2]), scans without intensity, and scans that miss returns (a
        share in [0, 0.4] of the LiDAR image's points lost, and left out of the loss), each per
        sample."""
        n, a = len(batch["image"]), self.augment
        draw = lambda p: (torch.rand(n, device=self.device) < p).view(-1, 1, 1, 1)  # noqa: E731
        grey = batch["image"].mean(1, keepdim=True).expand_as(batch["image"])
        batch["image"] = torch.where(draw(a.grey), grey, batch["image"])
        lidar = batch["lidar"].clone()
        power = torch.exp2(torch.empty(n, 1, 1, device=self.device).uniform_(-1, 1))
        intensity = lidar[:, INTENSITY]
        intensity = torch.where(draw(a.intensity_gamma)[:, 0], intensity.clamp_min(0) ** power, intensity)
        lidar[:, INTENSITY] = torch.where(draw(a.intensity_off)[:, 0], torch.zeros_like(intensity), intensity)
        if a.lidar_dropout:
            lost = torch.empty(n, 1, 1, 1, device=self.device).uniform_(0, 0.4) * draw(a.lidar_dropout)
            keep = (torch.rand_like(lidar[:, :1]) >= lost).to(lidar.dtype)
            lidar = lidar * keep
            batch["valid"] = batch["valid"] * keep
        batch["lidar"] = lidar
        return batch

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        flows = self(batch["image"], batch["lidar"], all_iterations=True)
        loss = sequence_loss(flows, batch["flow"], batch["valid"], self.hparams.gamma)
        self.log("train/loss", loss, prog_bar=True, on_step=True, on_epoch=True, sync_dist=True)
        return loss

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        flow = self(batch["image"], batch["lidar"])
        valid = batch["valid"][:, 0] > 0
        epe = (flow - batch["flow"]).norm(dim=1)[valid]
        zero = batch["flow"].norm(dim=1)[valid]
        self._val.append(torch.stack([epe, zero, batch["label"][:, 0][valid]]).cpu().numpy())

    def on_validation_epoch_end(self) -> None:
        if not self._val:
            return
        epe, zero, label = gathered(np.concatenate(self._val, axis=1))
        self._val.clear()
        rigid, foliage = np.isin(label, list(RIGID_CLASSES)), np.isin(label, list(FOLIAGE_CLASSES))
        self.log("val/epe", float(epe.mean()), prog_bar=True)
        self.log("val/epe_median", float(np.median(epe)))
        self.log("val/epe_zero", float(np.median(zero)))
        for name, mask in (("rigid", rigid), ("foliage", foliage)):
            if mask.any():
                self.log(f"val/epe_{name}", float(np.median(epe[mask])))

    def configure_optimizers(self) -> dict:
        return one_cycle(self, self.optim_config)
