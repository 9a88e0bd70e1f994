"""The flow matcher's data: calibrated frames, random extrinsic errors, and the flow they cause.

CMRNext's recipe needs only calibrated data: perturb the reference extrinsic, project the scan
under the perturbed one, and every projected point's true flow is where the reference puts it
minus where it landed. Frames are held in memory at the matcher's working resolution; every
training sample draws a new error (a curriculum from large to small over the epochs) and a random
crop; validation uses whole frames with fixed draws.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from calib.data import open_dataset
from calib.errors import DataError
from calib.features import RingProfile, ring_spacing_profile
from calib.geometry import perturb
from calib.match.correspondences import working_view
from calib.projection import project_points, project_scan, render_image, transform_points
from supportnet.runtime.flow_matcher import VISIBILITY, lidar_image
from train.loaders import loader
from train.train_config import FlowDataConfig, SequenceSource

__all__ = [
    "FlowDataModule",
    "ScanFrames",
    "curriculum_bound",
    "flow_sample",
    "load_scans",
    "read_frames",
    "write_frames",
]

PACK_STEP_M = 0.004
"""Point coordinates in a frame pack are multiples of 4 mm (int16: within 131 m of the LiDAR);
2 mm at most moves a point 5 m away by 0.15 px at the working focal length."""
FOV_MARGIN = 0.35
"""Points are kept where the reference projects them within this many focal lengths of the image
(about 19°): a 10° / 50 cm error moves no point from farther out into the image, save nearer than
1.5 m."""


@dataclass(frozen=True)
class ScanFrames:
    """Calibrated frames at the working resolution (sizes may differ between frames).

    Attributes:
        images: ``N`` uint8 RGB ``(H, W, 3)``. points: ``N`` scans ``(M, 4)`` float32, the points
            the camera can see under an extrinsic error (:data:`FOV_MARGIN`).
        labels: ``N`` per-point classes ``(M,)`` (``-1`` where the data has none).
        rings: ``N`` :class:`~calib.features.RingProfile` of each whole scan.
        K: ``(N, 3, 3)`` working intrinsics. T: ``(N, 4, 4)`` reference ``T_cam_lidar``.
    """

    images: list[np.ndarray]
    points: list[np.ndarray]
    labels: list[np.ndarray]
    rings: list[RingProfile]
    K: np.ndarray
    T: np.ndarray

    def __len__(self) -> int:
        return len(self.images)


def _in_view(points: np.ndarray, T_cam_lidar: np.ndarray, K: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``(M,)`` bool: in front of the camera and projected within :data:`FOV_MARGIN` of the image."""
    points_cam = transform_points(
        torch.from_numpy(T_cam_lidar), torch.from_numpy(points[:, :3].astype(np.float64))
    )
    uv, depth = (x.numpy() for x in project_points(points_cam, torch.from_numpy(K)))
    margin = FOV_MARGIN * K[0, 0]
    H, W = size
    return (depth > 0.1) & (uv >= -margin).all(1) & (uv[:, 0] <= W + margin) & (uv[:, 1] <= H + margin)


def load_scans(source: SequenceSource, stride: int, focal_px: float) -> ScanFrames:
    """Every ``stride``-th frame of one sequence, which must carry a reference calibration."""
    images, points, labels, rings, Ks, Ts = [], [], [], [], [], []
    with open_dataset(source.data, sequence=source.sequence, camera=source.camera) as seq:
        if seq.calibration.T_cam_lidar is None:
            raise DataError(source.data, "has no reference calibration to learn the flow from")
        for i in range(0, len(seq), stride):
            frame = seq[i]
            view = working_view(frame, focal_px)
            scan = np.asarray(frame.points, np.float32)
            label = np.asarray(frame.labels) if frame.labels is not None else np.full(len(scan), -1)
            keep = _in_view(scan, frame.calibration.T_cam_lidar, view.K, view.image.shape[:2])
            images.append(view.image)
            points.append(scan[keep])
            labels.append(label[keep].astype(np.int16))
            rings.append(ring_spacing_profile(scan))
            Ks.append(view.K)
            Ts.append(frame.calibration.T_cam_lidar)
    return ScanFrames(images, points, labels, rings, np.stack(Ks), np.stack(Ts))


def _concat(parts: list[ScanFrames]) -> ScanFrames:
    return ScanFrames(
        [x for p in parts for x in p.images],
        [x for p in parts for x in p.points],
        [x for p in parts for x in p.labels],
        [x for p in parts for x in p.rings],
        np.concatenate([p.K for p in parts]),
        np.concatenate([p.T for p in parts]),
    )


def _joined(arrays: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Arrays of different lengths as one array and the offsets between them."""
    return np.concatenate(arrays), np.cumsum([0] + [len(a) for a in arrays])


def _parts(joined: np.ndarray, offsets: np.ndarray) -> list[np.ndarray]:
    return [joined[a:b] for a, b in zip(offsets[:-1], offsets[1:], strict=True)]


def write_frames(frames: ScanFrames, path: Path, made_from: str = "", quality: int = 95) -> None:
    """``frames`` as one compact ``.npz``: JPEG images, the points a camera can see on a 4 mm grid
    (:data:`PACK_STEP_M`) with float16 intensities, ring profiles, and ``made_from`` (what they
    were read from, for :func:`read_frames` to compare). A synthetic 64-beam frame takes about
    0.2 MB instead of 3."""
    jpegs = [
        np.frombuffer(cv2.imencode(".jpg", im[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])[1], np.uint8)
        for im in frames.images
    ]
    arrays = {
        "K": frames.K,
        "T": frames.T,
        "ring_median": np.array([r.median_deg for r in frames.rings]),
        "made_from": np.array(made_from),
    }
    limit = np.iinfo(np.int16).max * PACK_STEP_M
    kept = [(np.abs(p[:, :3]) < limit).all(1) for p in frames.points]
    points = [p[k] for p, k in zip(frames.points, kept, strict=True)]
    for name, parts in (
        ("jpeg", jpegs),
        ("xyz", [np.round(p[:, :3] / PACK_STEP_M).astype(np.int16) for p in points]),
        ("intensity", [p[:, 3].astype(np.float16) for p in points]),
        ("labels", [label[k] for label, k in zip(frames.labels, kept, strict=True)]),
        ("ring_elevation", [r.elevation_deg for r in frames.rings]),
        ("ring_spacing", [r.spacing_deg for r in frames.rings]),
    ):
        arrays[name], arrays[name + "_offsets"] = _joined(parts)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path.with_suffix(".partial"), "wb") as f:
        np.savez_compressed(f, **arrays)
    path.with_suffix(".partial").replace(path)


def read_frames(path: Path, made_from: str | None = None) -> ScanFrames:
    """The frames :func:`write_frames` stored in ``path``.

    Raises:
        DataError: not a frame pack, or (``made_from`` given) one made from something else: a pack
            left by another config is refused rather than trained on.
    """
    try:
        with np.load(path) as z:
            parts = {
                k[: -len("_offsets")]: _parts(z[k[: -len("_offsets")]], z[k])
                for k in z.files
                if k.endswith("_offsets")
            }
            K, T, medians, packed_from = z["K"], z["T"], z["ring_median"], str(z["made_from"])
    except (OSError, ValueError, KeyError) as error:
        raise DataError(path, f"is not a frame pack written by write_frames ({error})") from None
    if made_from is not None and packed_from != made_from:
        raise DataError(
            path,
            f"was packed from {packed_from or 'something unrecorded'}, not {made_from}: delete it (it is "
            "re-made from the sources) or point data.cache elsewhere",
        )
    images = [cv2.imdecode(j, cv2.IMREAD_COLOR)[..., ::-1].copy() for j in parts["jpeg"]]
    rings = [
        RingProfile(e, s, float(m))
        for e, s, m in zip(parts["ring_elevation"], parts["ring_spacing"], medians, strict=True)
    ]
    points = [
        np.column_stack([xyz * np.float32(PACK_STEP_M), i.astype(np.float32)])
        for xyz, i in zip(parts["xyz"], parts["intensity"], strict=True)
    ]
    return ScanFrames(images, points, parts["labels"], rings, K, T)


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
    lidar = torch.from_numpy(lidar_image(scan, frames.points[i], T_init, K, near_m, frames.rings[i]))
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


def curriculum_bound(config: FlowDataConfig, progress: float) -> tuple[float, float]:
    """The largest error (cm, °) drawn at ``progress`` ∈ [0, 1] of the run: geometric from
    ``perturbation.start`` to ``perturbation.end``."""
    start, end = np.array(config.perturbation.start), np.array(config.perturbation.end)
    t = min(max(progress, 0.0), 1.0)
    return tuple(float(v) for v in start * (end / np.maximum(start, 1e-9)) ** t)


class _Perturbed(Dataset):
    """``length`` random crops of random frames, each under a new random error up to ``bound``
    (a shared tensor, so loader workers that outlive an epoch see the curriculum move)."""

    def __init__(self, frames: ScanFrames, config: FlowDataConfig) -> None:
        self.frames, self.config = frames, config
        self.bound = torch.tensor(config.perturbation.start, dtype=torch.float64).share_memory_()

    def __len__(self) -> int:
        return self.config.samples_per_epoch

    def __getitem__(self, _: int) -> dict[str, torch.Tensor]:
        i = int(torch.randint(len(self.frames), ()))
        cm, deg = (float(torch.rand(())) * float(b) for b in self.bound)
        generator = torch.Generator().manual_seed(int(torch.randint(2**31, ())))
        sample = flow_sample(
            self.frames, i, perturb(self.frames.T[i], cm, deg, generator), self.config.near_m
        )
        (H, W), (h, w) = self.frames.images[i].shape[:2], self.config.crop
        r, c = int(torch.randint(H - h + 1, ())), int(torch.randint(W - w + 1, ()))
        return {k: v[:, r : r + h, c : c + w] for k, v in sample.items()}


class FlowDataModule(L.LightningDataModule):
    """Perturbed training crops and fixed-error whole validation frames, split by sequence.

    With ``data.cache`` set, the frames are read from ``train.npz`` and ``val.npz`` there
    (:func:`write_frames`) where they exist, and written there after loading them otherwise: a
    GPU machine then needs the packs alone, not the datasets.
    """

    def __init__(self, config: FlowDataConfig) -> None:
        super().__init__()
        self.config = config
        self.train: ScanFrames | None = None
        self.val: list[dict[str, torch.Tensor]] | None = None
        self._crops: _Perturbed | None = None

    def _frames(self, split: str) -> ScanFrames:
        """One split's frames: from its pack where there is one, else from the sources (and
        packed where ``data.cache`` is set)."""
        stride = self.config.frame_stride if split == "train" else self.config.val_frame_stride
        sources = [s for s in self.config.sources if s.split == split]
        made_from = json.dumps(
            {
                "sources": [s.model_dump(mode="json", exclude={"split"}) for s in sources],
                "frame_stride": stride,
                "working_focal_px": self.config.working_focal_px,
            },
            sort_keys=True,
        )
        pack = self.config.cache / f"{split}.npz" if self.config.cache is not None else None
        if pack is not None and pack.is_file():
            return read_frames(pack, made_from)
        parts = [load_scans(s, stride, self.config.working_focal_px) for s in sources]
        if not parts:
            raise DataError("data.sources", f"no sequence has split: {split}")
        frames = _concat(parts)
        if pack is not None:
            write_frames(frames, pack, made_from)
        return frames

    def setup(self, stage: str | None = None) -> None:
        if self.train is not None:
            return
        train, val = self._frames("train"), self._frames("val")
        smallest = tuple(min(im.shape[k] for im in train.images) for k in (0, 1))
        if self.config.crop[0] > smallest[0] or self.config.crop[1] > smallest[1]:
            raise DataError(
                "data.crop", f"{self.config.crop} is larger than the smallest image size {smallest}"
            )
        self.train, self._crops = train, _Perturbed(train, self.config)
        cm, deg = self.config.perturbation.val
        self.val = [  # fixed draws: the same errors every epoch and every run
            flow_sample(
                val, i, perturb(val.T[i], cm, deg, torch.Generator().manual_seed(i)), self.config.near_m
            )
            for i in range(len(val))
        ]

    def set_progress(self, progress: float) -> None:
        """Moves the curriculum: the largest training error from here on."""
        self._crops.bound.copy_(torch.tensor(curriculum_bound(self.config, progress)))

    def train_dataloader(self) -> DataLoader:
        return loader(self._crops, self.config.batch_size, self.config.workers)

    def val_dataloader(self) -> DataLoader:
        return loader(self.val, 1, 0)  # drawn once in setup: nothing for workers to do
