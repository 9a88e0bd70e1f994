"""The support predictor's data: RGB frames and their Stage 3 per-frame maps, split by sequence.

Maps are refused unless made from the same dataset (``summary.json``'s fingerprint); the
sequences and their fingerprints are saved in every checkpoint (:meth:`SupportDataModule.state_dict`).

Frames of a longer focal length than ``working_focal_px`` are resampled down to it with their maps
(:func:`~calib.match.correspondences.working_view`), as the predictor resamples what it is given.
Everything is loaded into memory once (a few hundred frames of 624x188 fit easily); training
draws random crops, validation uses whole frames. Augmentation runs on the batch in
:class:`train.support_module.SupportModule` (kornia), so it runs on the accelerator too.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from calib.data import open_dataset
from calib.errors import DataError
from calib.match.correspondences import working_view
from calib.support.map_files import check_maps_fingerprint, dataset_identity, load_frame_maps
from supportnet.nets.map_targets import offline_target
from train.loaders import loader
from train.train_config import DataConfig, Source

__all__ = ["FrameTargets", "SupportDataModule", "load_source"]


@dataclass(frozen=True)
class FrameTargets:
    """Frames of one or more sequences and what the network learns from them.

    Attributes:
        images: ``(N, H, W, 3)`` uint8 RGB.
        target: ``(N, H, W)`` float32 in [0, 1].
        weight: ``(N, H, W)`` float32 loss weight (0: no LiDAR evidence there).
        sources: per sequence: its data, sequence, camera, maps folder and dataset fingerprint
            (what checkpoints record, see :meth:`SupportDataModule.state_dict`).
    """

    images: np.ndarray
    target: np.ndarray
    weight: np.ndarray
    sources: tuple[dict, ...] = ()

    def __len__(self) -> int:
        return len(self.images)


def load_source(source: Source, config: DataConfig) -> FrameTargets:
    """Every ``frame_stride``-th (validation: ``val_frame_stride``-th) frame of one sequence with
    its targets.

    Raises:
        DataError: maps made from another dataset (their fingerprint differs) or without a
            fingerprint, missing frames, unreadable map files, maps and images of other sizes.
    """
    maps = Path(source.maps)
    images, targets, weights = [], [], []
    with open_dataset(source.data, sequence=source.sequence, camera=source.camera) as seq:
        check_maps_fingerprint(maps, seq)
        identity = {
            "data": str(source.data),
            "sequence": source.sequence,
            "maps": str(maps),
            "split": source.split,
            **dataset_identity(seq),
        }
        stride = config.frame_stride if source.split == "train" else config.val_frame_stride
        for i in range(0, len(seq), stride):
            stored = load_frame_maps(maps, i)
            frame = seq[i]
            if stored["raw"].shape != frame.image_size:
                path = maps / "frames" / f"{i:06d}.npz"
                raise DataError(path, f"map is {stored['raw'].shape}, the image {frame.image_size}")
            target, weight = offline_target(
                stored["raw"], stored["coverage"], config.target, config.min_coverage, config.weight_cap
            )
            view = working_view(frame, config.working_focal_px)
            size = view.image.shape[1::-1]
            if size != frame.image.shape[1::-1]:  # the maps with the image: pixel means, the target weighted
                weighted, weight = (
                    cv2.resize(x, size, interpolation=cv2.INTER_AREA) for x in (target * weight, weight)
                )
                target = np.where(weight > 0, weighted / np.maximum(weight, 1e-12), 0).astype(np.float32)
            images.append(view.image)
            targets.append(target)
            weights.append(weight)
    if not images:
        raise DataError(source.data, "holds no frames")
    return FrameTargets(np.stack(images), np.stack(targets), np.stack(weights), (identity,))


def _concat(parts: list[FrameTargets]) -> FrameTargets:
    shapes = {p.images.shape[1:3] for p in parts}
    if len(shapes) > 1:
        raise DataError("data.sources", f"one split mixes image sizes {sorted(shapes)}")
    return FrameTargets(
        *(np.concatenate([getattr(p, k) for p in parts]) for k in ("images", "target", "weight")),
        sources=tuple(s for p in parts for s in p.sources),
    )


def _tensors(frames: FrameTargets, i: int, rows: slice, cols: slice) -> dict[str, torch.Tensor]:
    image = torch.from_numpy(frames.images[i, rows, cols]).permute(2, 0, 1).float() / 255.0
    return {
        "image": image,
        "target": torch.from_numpy(frames.target[i, rows, cols]).unsqueeze(0),
        "weight": torch.from_numpy(frames.weight[i, rows, cols]).unsqueeze(0),
    }


class _RandomCrops(Dataset):
    """``length`` random crops of random frames (torch's RNG, so seeding makes it repeatable)."""

    def __init__(self, frames: FrameTargets, crop: tuple[int, int], length: int) -> None:
        self.frames, self.crop, self.length = frames, crop, length

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, _: int) -> dict[str, torch.Tensor]:
        (H, W), (h, w) = self.frames.images.shape[1:3], self.crop
        i = int(torch.randint(len(self.frames), ()))
        r, c = int(torch.randint(H - h + 1, ())), int(torch.randint(W - w + 1, ()))
        return _tensors(self.frames, i, slice(r, r + h), slice(c, c + w))


class _WholeFrames(Dataset):
    def __init__(self, frames: FrameTargets) -> None:
        self.frames = frames

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return _tensors(self.frames, i, slice(None), slice(None))


class SupportDataModule(L.LightningDataModule):
    """Training crops and whole validation frames from the config's sources, split by sequence."""

    def __init__(self, config: DataConfig) -> None:
        super().__init__()
        self.config = config
        self.train: FrameTargets | None = None
        self.val: FrameTargets | None = None

    def setup(self, stage: str | None = None) -> None:
        if self.train is not None:
            return
        splits = {"train": [], "val": []}
        for source in self.config.sources:
            splits[source.split].append(load_source(source, self.config))
        for name, parts in splits.items():
            if not parts:
                raise DataError("data.sources", f"no sequence has split: {name}")
        self.train, self.val = _concat(splits["train"]), _concat(splits["val"])
        H, W = self.train.images.shape[1:3]
        if self.config.crop[0] > H or self.config.crop[1] > W:
            raise DataError("data.crop", f"{self.config.crop} is larger than the images ({H}, {W})")

    @property
    def sources(self) -> list[dict]:
        """Each training and validation sequence with its dataset fingerprint (after setup)."""
        return [s for part in (self.train, self.val) if part is not None for s in part.sources]

    def state_dict(self) -> dict:
        """Saved by Lightning in every checkpoint (under ``SupportDataModule``): the sequences and
        their dataset fingerprints, so a checkpoint says what data it learned from."""
        return {"sources": self.sources}

    def train_dataloader(self) -> DataLoader:
        data = _RandomCrops(self.train, self.config.crop, self.config.samples_per_epoch)
        return loader(data, self.config.batch_size, self.config.workers)

    def val_dataloader(self) -> DataLoader:
        return loader(_WholeFrames(self.val), 1, self.config.workers)
