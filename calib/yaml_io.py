"""YAML configs validated by pydantic models: one way to read them, one way to report problems."""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from calib.errors import ConfigError

__all__ = ["DEFAULTS", "load_config", "read_yaml", "validate"]

DEFAULTS = Path(__file__).resolve().parent / "defaults"
"""The packaged default configs; ``configs/`` at the top of a checkout holds the same files for
users to copy and edit (a test keeps them equal)."""

Model = TypeVar("Model", bound=BaseModel)


def read_yaml(path: Path) -> dict:
    """The mapping in a YAML file (empty file: ``{}``).

    Raises:
        ConfigError: the file is missing, is not UTF-8 text, does not parse, or is not a mapping.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(path, "is a folder, not a YAML file" if path.is_dir() else "file not found")
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")  # a byte-order mark is fine
    except UnicodeDecodeError as exc:
        raise ConfigError(path, f"not UTF-8 text (byte {exc.start}: {raw[exc.start]:#04x})") from None
    if "\0" in text:
        raise ConfigError(path, "not UTF-8 text (a binary file: it holds NUL bytes)")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(path, f"not valid YAML ({str(exc).splitlines()[0]})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(path, "expected a mapping at the top level")
    return data


def validate(model: type[Model], data: dict, path: Path) -> Model:
    """``model`` validated from ``data``; every problem named with its key path (and the value
    given), in one line.

    Raises:
        ConfigError: naming ``path`` and each offending key.
    """
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(map(str, e['loc'])) or 'file'}: {e['msg']}{_given(e)}" for e in exc.errors()
        )
        raise ConfigError(path, problems) from None


def _given(error: dict) -> str:
    """`` (got VALUE)`` for a scalar value that failed (``.inf``, ``-1``), else nothing."""
    value = error.get("input")
    if error["type"] == "missing" or not isinstance(value, int | float | str) or len(repr(value)) > 40:
        return ""
    return f" (got {value!r})"


def load_config(model: type[Model], path: Path | None, default: str) -> Model:
    """``model`` validated from the YAML file ``path``, or from the packaged ``default`` (a name
    under :data:`DEFAULTS`, e.g. ``"calibrate.yaml"``) when ``path`` is ``None``."""
    path = Path(path) if path is not None else DEFAULTS / default
    return validate(model, read_yaml(path), path)
