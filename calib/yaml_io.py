"""YAML configs validated by pydantic models: one way to read them, one way to report problems."""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from calib.errors import DataError

__all__ = ["DEFAULTS", "load_config", "read_yaml", "validate"]

DEFAULTS = Path(__file__).resolve().parent / "defaults"
"""The packaged default configs; ``configs/`` at the top of a checkout holds the same files for
users to copy and edit (a test keeps them equal)."""

Model = TypeVar("Model", bound=BaseModel)


def read_yaml(path: Path) -> dict:
    """The mapping in a YAML file (empty file: ``{}``).

    Raises:
        DataError: the file is missing, does not parse, or is not a mapping.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "file not found")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise DataError(path, f"not valid YAML ({str(exc).splitlines()[0]})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise DataError(path, "expected a mapping at the top level")
    return data


def validate(model: type[Model], data: dict, path: Path) -> Model:
    """``model`` validated from ``data``; every problem named with its key path, in one line.

    Raises:
        DataError: naming ``path`` and each offending key.
    """
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc'])) or 'file'}: {e['msg']}" for e in exc.errors())
        raise DataError(path, problems) from None


def load_config(model: type[Model], path: Path | None, default: str) -> Model:
    """``model`` validated from the YAML file ``path``, or from the packaged ``default`` (a name
    under :data:`DEFAULTS`, e.g. ``"calibrate.yaml"``) when ``path`` is ``None``."""
    path = Path(path) if path is not None else DEFAULTS / default
    return validate(model, read_yaml(path), path)
