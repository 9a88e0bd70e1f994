"""``configs/train.yaml`` (the support predictor) and ``configs/train_flow.yaml`` (the flow
matcher): training configs, validated (a typo fails loudly)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, NonNegativeFloat, PositiveInt

from calib.errors import ConfigError
from calib.seeds import SEED_LIMIT
from calib.yaml_io import read_yaml, validate
from supportnet.nets.flow_net import FlowConfig
from supportnet.nets.support_unet import ModelConfig

__all__ = ["FlowTrainConfig", "TrainConfig", "load_train_config"]


class _Group(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class SequenceSource(_Group):
    """One calibrated sequence (its reference extrinsic is the ground truth)."""

    data: Path
    sequence: str | None = None
    camera: str | None = Field(None, description="camera where the data has several (KITTI index, bag topic)")
    split: Literal["train", "val"]


class Source(SequenceSource):
    """One sequence and its ``supportnet maps`` folder."""

    maps: Path


class DataConfig(_Group):
    sources: list[Source] = Field(min_length=2, description="split by sequence: at least one of each")
    target: Literal["agreement", "support"] = Field(
        "support",
        description="Eq. 2 normalised by its peak (Stage 4's map; held-out r 0.69 against 0.59 for "
        "agreement on the vineyard), or the per-frame agreement Σ aG / Σ G",
    )
    working_focal_px: float = Field(
        360.8,
        gt=0,
        description="frames of a longer focal length are resampled down to it, their maps with them, and "
        "the export carries it, so the predictor sees every camera's images at this scale (the small "
        "synthetic worlds' focal length; README: on the vineyard at 960x540, f = 527, the shipped model's "
        "per-frame r 0.67 at this scale against 0.58 at the image's own)",
    )
    min_coverage: float = Field(0.5, gt=0, description="no target where the coverage is below this")
    weight_cap: float = Field(4.0, gt=0, description="the loss weight is the coverage, capped here")
    frame_stride: int = Field(1, ge=1, description="train on every k-th frame (neighbours are alike)")
    val_frame_stride: int = Field(4, ge=1, description="validate on every k-th held-out frame")
    crop: tuple[PositiveInt, PositiveInt] = Field((128, 320), description="training crop (H, W)")
    batch_size: int = Field(8, ge=1)
    samples_per_epoch: int = Field(960, ge=1, description="random crops per training epoch")
    workers: int = Field(0, ge=0)


class AugmentConfig(_Group):
    flip: float = Field(0.5, ge=0, le=1, description="horizontal flip probability (geometric)")
    affine: float = Field(0.5, ge=0, le=1, description="small rotation/scale/shift probability (geometric)")
    colour: float = Field(0.8, ge=0, le=1, description="colour jitter probability (photometric)")
    blur: float = Field(0.2, ge=0, le=1, description="Gaussian blur probability (photometric)")


class OptimConfig(_Group):
    lr: float = Field(3e-3, gt=0)
    weight_decay: float = Field(1e-4, ge=0)


class TrainerConfig(_Group):
    """Passed to ``lightning.Trainer``: ``accelerator: gpu, devices: 4, strategy: ddp`` trains on
    four GPUs with the same file; ``auto`` takes a GPU where there is one, else the CPU."""

    accelerator: str = "auto"
    devices: int | str = 1
    strategy: str = "auto"
    precision: str = "32-true"
    max_epochs: int = Field(24, ge=1)
    max_time_min: float = Field(18.0, gt=0, description="stop training after this many minutes")
    patience: int = Field(8, ge=1, description="early stopping on the validation metric")
    logger: Literal["csv", "tensorboard"] = "csv"
    log_every_n_steps: int = Field(10, ge=1)
    threads: int = Field(0, ge=0, description="torch CPU threads (0: torch's default)")
    fast_dev_run: bool = False


class TrainConfig(_Group):
    seed: int = Field(0, ge=0, lt=SEED_LIMIT, description="an integer in [0, 2^32)")
    out: Path = Field(Path("runs/support"), description="checkpoints, logs and curves go here")
    data: DataConfig
    model: ModelConfig = ModelConfig()
    augment: AugmentConfig = AugmentConfig()
    optim: OptimConfig = OptimConfig()
    trainer: TrainerConfig = TrainerConfig()


class PerturbationConfig(_Group):
    """Sizes (translation cm, rotation °) of the random extrinsic errors the flow is learned from:
    a curriculum from ``start`` (first epoch) to ``end`` (last), each draw uniform up to the
    epoch's bound; validation uses fixed draws of exactly ``val`` (Stage 4's default start)."""

    start: tuple[NonNegativeFloat, NonNegativeFloat] = (20.0, 3.0)
    end: tuple[NonNegativeFloat, NonNegativeFloat] = (5.0, 1.0)
    val: tuple[NonNegativeFloat, NonNegativeFloat] = (10.0, 2.0)


class FlowDataConfig(_Group):
    sources: list[SequenceSource] = Field(min_length=2, description="split by sequence")
    frame_stride: int = Field(2, ge=1, description="train on every k-th frame")
    val_frame_stride: int = Field(8, ge=1, description="validate on every k-th held-out frame")
    crop: tuple[PositiveInt, PositiveInt] = Field((128, 320), description="training crop (H, W)")
    batch_size: int = Field(4, ge=1)
    samples_per_epoch: int = Field(640, ge=1)
    workers: int = Field(0, ge=-1, description="loader processes (-1: one per CPU core but one)")
    cache: Path | None = Field(
        None, description="folder of frame packs (train.npz, val.npz): read where they exist, else written"
    )
    near_m: float = Field(2.0, gt=0, description="the LiDAR image holds near_m / depth")
    working_focal_px: float = Field(360.0, gt=0, description="images are resampled to this focal length")
    perturbation: PerturbationConfig = PerturbationConfig()


class FlowAugmentConfig(_Group):
    flip: float = Field(0.5, ge=0, le=1, description="mirror image, LiDAR image and flow together")
    colour: float = Field(0.8, ge=0, le=1, description="colour jitter probability (image only)")
    blur: float = Field(0.2, ge=0, le=1, description="Gaussian blur probability (image only)")
    grey: float = Field(0.0, ge=0, le=1, description="grey-level image probability (KITTI's camera 0)")
    intensity_gamma: float = Field(
        0.0, ge=0, le=1, description="probability of raising the LiDAR intensity to a power in [1/2, 2]"
    )
    intensity_off: float = Field(0.0, ge=0, le=1, description="probability of a LiDAR without intensity")
    gamma: float = Field(
        0.0, ge=0, le=1, description="probability of an image gamma in [1/2, 2] (exposure, camera response)"
    )
    noise: float = Field(0.0, ge=0, le=1, description="probability of Gaussian pixel noise (σ 0.03)")
    lidar_dropout: float = Field(
        0.0,
        ge=0,
        le=1,
        description="probability of losing up to 40 % of the LiDAR image's points (missed returns)",
    )


class FlowTrainConfig(_Group):
    seed: int = Field(0, ge=0, lt=SEED_LIMIT, description="an integer in [0, 2^32)")
    out: Path = Field(Path("runs/flow"), description="checkpoints, logs and curves go here")
    data: FlowDataConfig
    init: Path | None = Field(
        None,
        description="start from these weights (fine-tuning): a checkpoint of the same network, or an "
        "exported flow matcher such as the shipped supportnet/assets/flow_matcher.onnx",
    )
    model: FlowConfig = FlowConfig()
    augment: FlowAugmentConfig = FlowAugmentConfig()
    optim: OptimConfig = OptimConfig(lr=1e-3)
    gamma: float = Field(0.8, gt=0, le=1, description="RAFT's weight decay over the refinement steps")
    trainer: TrainerConfig = TrainerConfig()


def _set(tree: dict, dotted: str, value: object) -> None:
    *parents, leaf = dotted.split(".")
    for key in parents:
        child = tree.setdefault(key, {})
        if not isinstance(child, dict):
            raise ConfigError("override", f"{dotted}: {key} is not a group")
        tree = child
    tree[leaf] = value


DEFAULTS = Path(__file__).resolve().parent / "defaults"
"""The packaged ``train.yaml`` and ``train_flow.yaml`` (``configs/`` holds the same for users)."""


def load_train_config(
    path: Path | None, overrides: list[str] = (), schema: type[_Group] = TrainConfig
) -> TrainConfig | FlowTrainConfig:
    """The config in ``path`` with ``key.sub=value`` overrides (values parsed as YAML), validated
    as ``schema`` (:class:`TrainConfig` or :class:`FlowTrainConfig`)."""
    if path is None:
        path = DEFAULTS / ("train_flow.yaml" if schema is FlowTrainConfig else "train.yaml")
    data = read_yaml(path)
    for item in overrides:
        key, sep, text = item.partition("=")
        if not sep or not key:
            raise ConfigError("override", f"{item!r} is not key.sub=value")
        _set(data, key.strip(), yaml.safe_load(text))
    return validate(schema, data, path)
