"""The flow matcher's data: calibrated frames, random extrinsic errors, and the flow they cause.

CMRNext's recipe needs only calibrated data: perturb the reference extrinsic, project the scan
under the perturbed one, and every projected point's true flow is where the reference puts it
minus where it landed. Frames are held in memory at the matcher's working resolution; every
training sample draws a new error (a curriculum from large to small over the epochs) and a random
crop; validation uses whole frames with fixed draws.
"""

from __future__ import annotations

from dataclasses import dataclass

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from calib.data import open_dataset
from calib.errors import DataError
from calib.geometry import perturb
from calib.match.correspondences import working_view
from calib.projection import project_points, project_scan, render_image, transform_points
from supportnet.runtime.flow_matcher import VISIBILITY, lidar_image
from train.loaders import loader
from train.train_config import FlowDataConfig, SequenceSource

__all__ = ["FlowDataModule", "ScanFrames", "curriculum_bound", "flow_sample", "load_scans"]


@dataclass(frozen=True)
class ScanFrames:
    """Calibrated frames at the working resolution.

    Attributes:
        images: ``(N, H, W, 3)`` uint8 RGB. points: ``N`` scans ``(M, 4)`` float32.
        labels: ``N`` per-point classes ``(M,)`` (``-1`` where the data has none).
        K: ``(N, 3, 3)`` working intrinsics. T: ``(N, 4, 4)`` reference ``T_cam_lidar``.
    """

    images: np.ndarray
    points: list[np.ndarray]
    labels: list[np.ndarray]
    K: np.ndarray
    T: np.ndarray

    def __len__(self) -> int:
        return len(self.images)


def load_scans(source: SequenceSource, stride: int, focal_px: float) -> ScanFrames:
    """Every ``stride``-th frame of one sequence, which must carry a reference calibration."""
    images, points, labels, Ks, Ts = [], [], [], [], []
    with open_dataset(source.data, sequence=source.sequence, camera=source.camera) as seq:
        if seq.calibration.T_cam_lidar is None:
            raise DataError(source.data, "has no reference calibration to learn the flow from")
        for i in range(0, len(seq), stride):
            frame = seq[i]
            view = working_view(frame, focal_px)
            images.append(view.image)
            points.append(np.asarray(frame.points, np.float32))
            n = len(frame.points)
            labels.append(np.asarray(frame.labels) if frame.labels is not None else np.full(n, -1))
            Ks.append(view.K)
            Ts.append(frame.calibration.T_cam_lidar)
    return ScanFrames(np.stack(images), points, labels, np.stack(Ks), np.stack(Ts))


def _concat(parts: list[ScanFrames]) -> ScanFrames:
    if len({p.images.shape[1:3] for p in parts}) > 1:
        raise DataError("data.sources", "one split mixes image sizes; use one working_focal_px camera")
    return ScanFrames(
        np.concatenate([p.images for p in parts]),
        [s for p in parts for s in p.points],
        [s for p in parts for s in p.labels],
        np.concatenate([p.K for p in parts]),
        np.concatenate([p.T for p in parts]),
    )


def flow_sample(frames: ScanFrames, i: int, T_init: np.ndarray, near_m: float) -> dict[str, torch.Tensor]:
    """One whole-frame sample: the scan projected under ``T_init``, and its true flow.

    Returns:
        ``image (3, H, W)`` float in [0, 1]; ``lidar (5, H, W)``; ``flow (2, H, W)`` pixels,
        ``reference − projected``; ``valid (1, H, W)`` where a point landed and its true position
        is inside the image; ``label (1, H, W)`` its class (``-1``: none).
    """
    image, K = frames.images[i], frames.K[i]
    size = image.shape[:2]
    scan = project_scan(frames.points[i], T_init, K, size, VISIBILITY)
    lidar = torch.from_numpy(lidar_image(scan, frames.points[i], T_init, K, near_m))
    points = torch.from_numpy(frames.points[i][scan.index, :3].astype(np.float64))
    uv_true, _ = project_points(transform_points(torch.from_numpy(frames.T[i]), points), torch.from_numpy(K))
    uv, depth = torch.from_numpy(scan.uv), torch.from_numpy(scan.depth)
    H, W = size
    inside = ((uv_true >= -0.5) & (uv_true <= torch.tensor([W - 0.5, H - 0.5], dtype=uv_true.dtype))).all(1)
    labels = torch.from_numpy(frames.labels[i][scan.index]).double()
    # flow x, flow y, class and "true position inside", of the nearest point per pixel (one z-buffer)
    values = torch.cat([uv_true - uv, labels[:, None], inside.double()[:, None]], 1)
    drawn = render_image(uv, depth, size, values).permute(2, 0, 1).float()
    valid = drawn[3] * lidar[0].float()
    label = torch.where(lidar[0] > 0, drawn[2], torch.full_like(drawn[2], -1.0))
    return {
        "image": torch.from_numpy(image).permute(2, 0, 1).float() / 255.0,
        "lidar": lidar.float(),
        "flow": drawn[:2] * valid,
        "valid": valid[None],
        "label": label[None],
    }


def curriculum_bound(config: FlowDataConfig, epoch: int, epochs: int) -> tuple[float, float]:
    """The largest error (cm, °) drawn in ``epoch`` of ``epochs``: geometric from start to end."""
    start, end = np.array(config.perturbation.start), np.array(config.perturbation.end)
    t = epoch / max(epochs - 1, 1)
    return tuple(float(v) for v in start * (end / np.maximum(start, 1e-9)) ** min(t, 1.0))


class _Perturbed(Dataset):
    """``length`` random crops of random frames, each under a new random error up to ``bound``."""

    def __init__(self, frames: ScanFrames, config: FlowDataConfig) -> None:
        self.frames, self.config = frames, config
        self.bound = config.perturbation.start

    def __len__(self) -> int:
        return self.config.samples_per_epoch

    def __getitem__(self, _: int) -> dict[str, torch.Tensor]:
        i = int(torch.randint(len(self.frames), ()))
        cm, deg = (float(torch.rand(())) * b for b in self.bound)
        generator = torch.Generator().manual_seed(int(torch.randint(2**31, ())))
        sample = flow_sample(
            self.frames, i, perturb(self.frames.T[i], cm, deg, generator), self.config.near_m
        )
        (H, W), (h, w) = self.frames.images.shape[1:3], self.config.crop
        r, c = int(torch.randint(H - h + 1, ())), int(torch.randint(W - w + 1, ()))
        return {k: v[:, r : r + h, c : c + w] for k, v in sample.items()}


class FlowDataModule(L.LightningDataModule):
    """Perturbed training crops and fixed-error whole validation frames, split by sequence."""

    def __init__(self, config: FlowDataConfig) -> None:
        super().__init__()
        self.config = config
        self.train: ScanFrames | None = None
        self.val: list[dict[str, torch.Tensor]] | None = None
        self._crops: _Perturbed | None = None

    def setup(self, stage: str | None = None) -> None:
        if self.train is not None:
            return
        splits: dict[str, list[ScanFrames]] = {"train": [], "val": []}
        for source in self.config.sources:
            stride = self.config.frame_stride if source.split == "train" else self.config.val_frame_stride
            splits[source.split].append(load_scans(source, stride, self.config.working_focal_px))
        for name, parts in splits.items():
            if not parts:
                raise DataError("data.sources", f"no sequence has split: {name}")
        train, val = _concat(splits["train"]), _concat(splits["val"])
        H, W = train.images.shape[1:3]
        if self.config.crop[0] > H or self.config.crop[1] > W:
            raise DataError("data.crop", f"{self.config.crop} is larger than the images ({H}, {W})")
        self.train, self._crops = train, _Perturbed(train, self.config)
        cm, deg = self.config.perturbation.val
        self.val = [  # fixed draws: the same errors every epoch and every run
            flow_sample(
                val, i, perturb(val.T[i], cm, deg, torch.Generator().manual_seed(i)), self.config.near_m
            )
            for i in range(len(val))
        ]

    def set_epoch(self, epoch: int, epochs: int) -> None:
        """Moves the curriculum: this epoch's largest training error."""
        self._crops.bound = curriculum_bound(self.config, epoch, epochs)

    def train_dataloader(self) -> DataLoader:
        return loader(self._crops, self.config.batch_size, self.config.workers)

    def val_dataloader(self) -> DataLoader:
        return loader(self.val, 1, self.config.workers)
