"""``configs/train.yaml`` (the support predictor) and ``configs/train_flow.yaml`` (the flow
matcher): training configs, validated (a typo fails loudly)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, NonNegativeFloat, PositiveInt, field_validator

from calib.errors import ConfigError
from calib.seeds import SEED_LIMIT
from calib.yaml_io import read_yaml, validate
from supportnet.nets.flow_net import FlowConfig
from supportnet.nets.support_unet import ModelConfig

__all__ = [
    "ACCELERATORS",
    "PRECISIONS",
    "FlowTrainConfig",
    "TrainConfig",
    "accelerator_value",
    "devices_value",
    "load_train_config",
    "precision_value",
    "trainer_problem_here",
]

ACCELERATORS = ("auto", "cpu", "gpu")
"""``trainer.accelerator`` (``--accelerator``): auto takes a GPU where there is one."""

PRECISIONS = {"32-true": "32-true", "16-mixed": "16-mixed", "bf16-mixed": "bf16-mixed"}
PRECISIONS.update({"32": "32-true", "16": "16-mixed", "bf16": "bf16-mixed"})
"""``trainer.precision`` (``--precision``) the training modules support → Lightning's name:
full precision, or fp16 / bf16 mixed precision (Lightning's short aliases taken too; on a CPU
Lightning runs 16-mixed as bf16-mixed). 64-true, 16-true, bf16-true and transformer-engine are
refused: the networks and their losses are not written for those."""


def accelerator_value(value: object) -> str:
    """``value`` if it is one of :data:`ACCELERATORS`, else ``ValueError`` saying which are."""
    if not isinstance(value, str) or value not in ACCELERATORS:
        raise ValueError(f"must be one of {', '.join(ACCELERATORS)}")
    return value


def devices_value(value: object) -> int | str:
    """``trainer.devices`` (``--devices``) as Lightning takes it: a count (``4``; ``-1``: all),
    ``auto``, or a comma-separated list of GPU indices (``0,1``). ``ValueError`` otherwise."""
    problem = "must be a count (1, 2, ...), -1 (all), auto, or GPU indices like 0,1"
    if isinstance(value, bool) or not isinstance(value, int | str):
        raise ValueError(problem)
    text = str(value).strip()
    if text == "auto":
        return text
    if re.fullmatch(r"-?\d+", text):
        count = int(text)
        if count == -1 or count >= 1:
            return count
        raise ValueError(problem)
    if re.fullmatch(r"\d+(\s*,\s*\d+)*\s*,?", text):
        indices = [int(v) for v in text.split(",") if v.strip()]
        if len(set(indices)) == len(indices):
            return ",".join(map(str, indices)) + ("," if len(indices) == 1 else "")
    raise ValueError(problem)


def precision_value(value: object) -> str:
    """Lightning's name of a precision in :data:`PRECISIONS`, else ``ValueError`` listing them."""
    text = str(value).strip() if isinstance(value, int | str) and not isinstance(value, bool) else None
    if text not in PRECISIONS:
        accepted = ", ".join(PRECISIONS)
        raise ValueError(f"must be one of {accepted}")
    return PRECISIONS[text]


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

    accelerator: str = Field("auto", description="auto, cpu or gpu")
    devices: int | str = Field(1, description="a count, -1 (all), auto, or GPU indices like 0,1")
    strategy: str = "auto"
    precision: str = Field("32-true", description="32-true, 16-mixed or bf16-mixed")
    max_epochs: int = Field(24, ge=1)
    max_time_min: float = Field(18.0, gt=0, description="stop training after this many minutes")
    patience: int = Field(8, ge=1, description="early stopping on the validation metric")
    logger: Literal["csv", "tensorboard"] = "csv"
    log_every_n_steps: int = Field(10, ge=1)
    threads: int = Field(0, ge=0, description="torch CPU threads (0: torch's default)")
    fast_dev_run: bool = False

    _accelerator = field_validator("accelerator", mode="before")(accelerator_value)
    _devices = field_validator("devices", mode="before")(devices_value)
    _precision = field_validator("precision", mode="before")(precision_value)


def trainer_problem_here(trainer: TrainerConfig) -> tuple[str, str] | None:
    """``(field, problem)`` where this machine cannot run ``trainer`` (a GPU asked for where
    there is none, GPU indices it does not have, bf16 on a GPU without it), else ``None``:
    checked before any training starts, not found by Lightning after the data is loaded."""
    import torch

    cuda = torch.cuda.is_available()
    count = torch.cuda.device_count() if cuda else 0
    if trainer.accelerator == "gpu" and not cuda:
        return (
            "accelerator",
            "gpu: this machine has no CUDA GPU (torch.cuda.is_available() is False); use auto or cpu",
        )
    on_gpu = trainer.accelerator == "gpu" or (trainer.accelerator == "auto" and cuda)
    devices = trainer.devices
    if isinstance(devices, str) and devices != "auto":
        if not on_gpu:
            return (
                "devices",
                f"{devices}: GPU indices need a GPU and this run is on the CPU; give a count (e.g. 1)",
            )
        missing = [i for i in (int(v) for v in devices.split(",") if v) if i >= count]
        if missing:
            return "devices", f"{devices}: this machine has {count} GPU(s), indices 0 to {count - 1}"
    if isinstance(devices, int) and on_gpu and devices > count:
        return "devices", f"{devices}: this machine has {count} GPU(s)"
    if trainer.precision == "bf16-mixed" and on_gpu and not torch.cuda.is_bf16_supported():
        return "precision", "bf16-mixed: this GPU has no bfloat16; use 16-mixed or 32-true"
    return None


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
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            problem = " ".join(str(getattr(exc, "problem", None) or exc).split())
            raise ConfigError("override", f"{item!r}: the value is not YAML ({problem})") from None
        _set(data, key.strip(), value)
    return validate(schema, data, path)
