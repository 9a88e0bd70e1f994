"""Maps folders on disk, read back safely.

``supportnet maps`` (offline maps) and ``supportnet predict`` (predicted maps) write a folder
holding ``frames/NNNNNN.npz`` (one per frame), ``sequence.npz`` (the whole sequence) and
``summary.json``, whose ``dataset_fingerprint`` is :meth:`~calib.data.types.Sequence.fingerprint`
of the sequence they were made from. Everything that reads such a folder for a sequence
(``predict --maps``, ``calibrate --support offline:MAPS``, ``analyze --maps``, training) calls
:func:`check_maps_fingerprint` first and loads arrays through :func:`load_sequence_maps` /
:func:`load_frame_maps`, which turn any unreadable, truncated or incomplete file into one line.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from pathlib import Path

import numpy as np

from calib.data.types import Sequence
from calib.errors import DataError

__all__ = [
    "FINGERPRINT_KEY",
    "SUMMARY",
    "check_maps_fingerprint",
    "dataset_identity",
    "load_frame_maps",
    "load_npz",
    "load_sequence_maps",
    "stored_identity",
]

SUMMARY = "summary.json"
FINGERPRINT_KEY = "dataset_fingerprint"
"""The key of ``summary.json`` (maps, predictions, training runs) that holds the fingerprint."""


def dataset_identity(seq: Sequence) -> dict[str, object]:
    """What an output stores about the sequence it was made from (``summary.json`` keys)."""
    return {
        FINGERPRINT_KEY: seq.fingerprint(),
        "dataset": seq.name,
        "layout": seq.layout,
        "camera": seq.camera or None,
        "frames": len(seq),
    }


def stored_identity(folder: Path) -> dict:
    """``summary.json`` of a maps (or predictions) folder.

    Raises:
        DataError: no folder, no ``summary.json``, or one that does not parse.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(folder, "maps folder not found; make maps with `supportnet maps`")
    path = folder / SUMMARY
    if not path.is_file():
        raise DataError(folder, f"has no {SUMMARY}: not a finished `supportnet maps` folder; remake the maps")
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise DataError(path, f"does not parse ({exc}); remake the maps with `supportnet maps`") from None
    if not isinstance(summary, dict):
        raise DataError(path, "is not a JSON object; remake the maps with `supportnet maps`")
    return summary


def _describe(summary: dict) -> str:
    name = summary.get("dataset") or summary.get("data") or "?"
    sequence = summary.get("sequence")
    if sequence and not summary.get("dataset"):
        name = f"{name} sequence {sequence}"
    return str(name)


def check_maps_fingerprint(maps_dir: Path, seq: Sequence) -> None:
    """Refuse maps (or predictions) made from another dataset than ``seq``.

    Args:
        maps_dir: a folder written by ``supportnet maps`` or ``supportnet predict``.
        seq: the sequence the maps are about to be used with.

    Raises:
        DataError: one line naming the maps folder and both datasets when the fingerprints
            differ; asking to remake them when the folder has no fingerprint (older maps).
    """
    maps_dir = Path(maps_dir)
    summary = stored_identity(maps_dir)
    stored = summary.get(FINGERPRINT_KEY)
    if not isinstance(stored, str) or not stored:
        raise DataError(
            maps_dir,
            "carries no dataset fingerprint (made by an older supportnet); "
            "remake the maps with `supportnet maps`",
        )
    ours = seq.fingerprint()
    if stored != ours:
        raise DataError(
            maps_dir,
            f"was made from another dataset ({_describe(summary)}, fingerprint {stored}) than "
            f"{seq.name} (fingerprint {ours}); make maps of this dataset with `supportnet maps`",
        )


def load_npz(path: Path, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The arrays ``keys`` of an ``.npz`` file, each finite and 2-D, all of one shape.

    Raises:
        DataError: a missing, truncated or corrupt file (not a zip, a bad CRC, a bad array
            header), a missing array, or arrays that are not finite ``(H, W)`` maps.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "not found" if not path.exists() else "not a regular file")
    try:
        with np.load(path, allow_pickle=False) as stored:
            missing = [k for k in keys if k not in stored.files]
            if missing:
                have = ", ".join(stored.files) or "nothing"
                raise DataError(path, f"has no {', '.join(missing)} array (has: {have}); remake the maps")
            arrays = {k: np.asarray(stored[k]) for k in keys}
    except DataError:
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as exc:
        problem = f"is not a readable maps file ({type(exc).__name__}: {exc}); remake the maps"
        raise DataError(path, problem) from None
    shapes = {a.shape for a in arrays.values()}
    for key, array in arrays.items():
        if array.ndim != 2 or not np.issubdtype(array.dtype, np.number):
            raise DataError(path, f"{key!r} is not a 2-D map (shape {array.shape}, {array.dtype})")
        if not np.isfinite(array).all():
            raise DataError(path, f"{key!r} holds NaN or infinite values; remake the maps")
    if len(shapes) > 1:
        raise DataError(path, f"arrays have different shapes {sorted(shapes)}")
    return arrays


def load_sequence_maps(maps_dir: Path, keys: tuple[str, ...] = ("support",)) -> dict[str, np.ndarray]:
    """``sequence.npz`` of a maps folder (see :func:`load_npz`)."""
    maps_dir = Path(maps_dir)
    if not maps_dir.is_dir():
        raise DataError(maps_dir, "maps folder not found; make maps with `supportnet maps`")
    if not (maps_dir / "sequence.npz").exists():
        raise DataError(maps_dir / "sequence.npz", "not found; make maps with `supportnet maps`")
    return load_npz(maps_dir / "sequence.npz", keys)


def load_frame_maps(
    maps_dir: Path, index: int, keys: tuple[str, ...] = ("raw", "coverage")
) -> dict[str, np.ndarray]:
    """``frames/NNNNNN.npz`` of frame ``index`` of a maps folder (see :func:`load_npz`)."""
    path = Path(maps_dir) / "frames" / f"{index:06d}.npz"
    if not path.is_file() and not path.exists():
        raise DataError(path, f"missing: the maps do not cover frame {index}")
    return load_npz(path, keys)
