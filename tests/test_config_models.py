"""Issue 19, defect 7 (``sigma: .inf`` in a config): every pydantic config model refuses NaN and
infinity, and every number in it has a lower bound unless it is signed by nature (listed here)."""

from __future__ import annotations

import importlib
import inspect
import types
import typing
from pathlib import Path

import annotated_types
import pytest
from pydantic import BaseModel

ROOT = Path(__file__).resolve().parents[1]
NOT_CONFIGS = {"calib.data.custom"}
"""A dataset's calibration.yaml (a data file, validated by its reader), not a config."""

SIGNED = {
    ("Stage1Config", "translation_prior_m"): "a translation: any sign",
    ("ExtrinsicConfig", "camera_position_m"): "a position: any sign",
    ("CameraConfig", "cx"): "the principal point may lie outside the image",
    ("CameraConfig", "cy"): "the principal point may lie outside the image",
    ("WindConfig", "direction_deg"): "an angle: any value",
    ("LightConfig", "sun_azimuth_deg"): "an angle: any value",
    ("DriveConfig", "lane_offset_m"): "left or right of the centreline",
    ("TrainerConfig", "devices"): "Lightning's: -1 means every device",
}


def config_models() -> list[type[BaseModel]]:
    """Every pydantic model defined in ``calib``, ``supportnet``, ``train`` and ``export``."""
    found = []
    for package in ("calib", "supportnet", "train", "export"):
        for path in sorted((ROOT / package).rglob("*.py")):
            if "BaseModel" not in path.read_text():
                continue
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
            if name in NOT_CONFIGS:
                continue
            module = importlib.import_module(name)
            found += [
                cls
                for cls in vars(module).values()
                if inspect.isclass(cls) and issubclass(cls, BaseModel) and cls.__module__ == name
            ]
    return found


MODELS = config_models()


def unbounded_numbers(annotation: object, metadata: list, path: str):
    """The paths of ``int``/``float`` leaves of a field (inside optionals and tuples) that have no
    lower bound (``ge``/``gt``)."""
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        base, *extra = typing.get_args(annotation)
        yield from unbounded_numbers(base, [*metadata, *extra], path)
    elif origin in (typing.Union, types.UnionType):
        for arg in typing.get_args(annotation):
            yield from unbounded_numbers(arg, metadata, path)
    elif origin in (tuple, list):
        for i, arg in enumerate(typing.get_args(annotation)):
            if arg is not Ellipsis:
                yield from unbounded_numbers(arg, [], f"{path}[{i}]")
    elif annotation in (int, float) and not any(
        isinstance(m, annotated_types.Ge | annotated_types.Gt) for m in metadata
    ):
        yield path


def test_the_walk_finds_the_config_models():
    names = {cls.__name__ for cls in MODELS}
    assert {
        "CalibrateConfig",
        "MapsConfig",
        "Stage1Config",
        "SynthConfig",
        "TrainConfig",
        "FlowConfig",
    } <= names


@pytest.mark.parametrize("model", MODELS, ids=lambda cls: f"{cls.__module__}.{cls.__name__}")
def test_config_models_refuse_nan_and_infinity(model):
    assert model.model_config.get("allow_inf_nan") is False
    assert model.model_config.get("extra") == "forbid"


@pytest.mark.parametrize("model", MODELS, ids=lambda cls: f"{cls.__module__}.{cls.__name__}")
def test_every_number_has_a_lower_bound_unless_signed_by_nature(model):
    missing = [
        path
        for field, info in model.model_fields.items()
        if (model.__name__, field) not in SIGNED
        for path in unbounded_numbers(info.annotation, info.metadata, field)
    ]
    assert not missing, f"{model.__name__}: no lower bound on {missing}"
