"""YAML configs validated by pydantic models: one way to read them, one way to report problems."""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from calib.errors import DataError

__all__ = ["read_yaml", "validate"]

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
