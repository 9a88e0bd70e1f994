"""Output folders written atomically: built under a temporary name, renamed when complete."""

from __future__ import annotations

import json
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import yaml
from pydantic import BaseModel
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from calib.errors import DataError

__all__ = ["atomic_output", "progress_bar", "resolved_config", "write_json"]


@contextmanager
def atomic_output(out: Path, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary folder beside ``out``; on success it replaces ``out`` in one rename.

    An existing ``out`` is refused unless ``overwrite``; on any error the temporary folder is
    removed, so nothing half-written is left behind.
    """
    out = Path(out)
    if out.exists() and not overwrite:
        raise DataError(out, "already exists; pass --overwrite to replace it")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if out.exists():
        shutil.rmtree(out) if out.is_dir() else out.unlink()
    tmp.rename(out)


def write_json(path: Path, data: object) -> None:
    Path(path).write_text(json.dumps(data, indent=2, default=float) + "\n")


def resolved_config(config: BaseModel) -> str:
    """The YAML a command saves beside its outputs: every key of ``config``, defaults resolved."""
    return yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False)


def progress_bar(label: str, console: Console) -> Progress:
    """A transient bar ``label ━━━ done/total time-left`` on ``console`` (stderr for commands)."""
    columns = (TextColumn(label), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    return Progress(*columns, console=console, transient=True)
