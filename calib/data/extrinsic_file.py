"""Extrinsic files: ``T_cam_lidar`` from a ``result.json`` or a text file of numbers, checked.

Accepted:

- a JSON object with the key ``T_cam_lidar``: a 4x4 (or 3x4) nested list, as ``supportnet
  calibrate`` writes in ``result.json``;
- a text file of 12 or 16 numbers, row-major ``T_cam_lidar`` (``[R | t]`` or the whole 4x4),
  whitespace- or comma-separated, over any number of lines; ``#`` starts a comment.

Refused, each with one line naming the file: a file that does not parse, rows of different
lengths, a count other than 12 or 16, NaN or infinite values, a last row other than
``[0, 0, 0, 1]``, and a rotation that is not rigid (``R Rᵀ = I`` and ``det R = +1`` within
:data:`RIGID_ATOL`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from calib.errors import DataError

__all__ = ["RIGID_ATOL", "read_extrinsic", "rigid_problem"]

RIGID_ATOL = 1e-3
"""Largest ``|R Rᵀ − I|`` entry and ``|det R − 1|`` accepted as a rotation (files print six or
more decimals; a hand-typed matrix rounded to three still passes)."""


def rigid_problem(T: np.ndarray, atol: float = RIGID_ATOL) -> str | None:
    """Why ``T`` is not a rigid ``(4, 4)`` transform, or ``None`` when it is."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        return f"must be 4x4, got shape {T.shape}"
    if not np.isfinite(T).all():
        return f"holds {int((~np.isfinite(T)).sum())} NaN or infinite value(s)"
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        return f"last row must be [0, 0, 0, 1], got {_fmt(T[3])}"
    R = T[:3, :3]
    deviation = float(np.abs(R @ R.T - np.eye(3)).max())
    if deviation > atol:
        return f"rotation is not orthonormal (|R Rᵀ − I| reaches {deviation:.3g}, tolerance {atol:g})"
    det = float(np.linalg.det(R))
    if abs(det - 1.0) > atol:
        return f"rotation has det {det:.6g}, not +1 (a reflection)"
    return None


def _fmt(values: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:g}" for v in np.asarray(values).ravel()) + "]"


def _from_json(path: Path, text: str) -> list[list[float]]:
    try:
        value = json.loads(text, parse_constant=lambda c: float(c))
    except ValueError as exc:
        raise DataError(path, f"is not valid JSON ({exc})") from None
    if not isinstance(value, dict) or "T_cam_lidar" not in value:
        keys = ", ".join(sorted(value)) if isinstance(value, dict) else type(value).__name__
        raise DataError(path, f"has no 'T_cam_lidar' key (has: {keys or 'nothing'})")
    rows = value["T_cam_lidar"]
    if not isinstance(rows, list) or not all(isinstance(r, list) for r in rows):
        raise DataError(path, "'T_cam_lidar' must be a list of rows (4x4 or 3x4)")
    for r in rows:
        for v in r:
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise DataError(path, f"'T_cam_lidar' holds {v!r}, not a number")
    return [[float(v) for v in r] for r in rows]


def _from_text(path: Path, text: str) -> list[list[float]]:
    rows = []
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].replace(",", " ").strip()
        if not line:
            continue
        try:
            rows.append([float(v) for v in line.split()])
        except ValueError:
            raise DataError(path, f"line {number} is not numbers: {line[:60]!r}") from None
    return rows


def read_extrinsic(path: Path | str) -> np.ndarray:
    """Read a ``T_cam_lidar`` (LiDAR points into the camera frame) and check it is rigid.

    Args:
        path: a ``.json`` file with the key ``T_cam_lidar`` (``result.json``), or a text file of
            12 or 16 numbers in row-major order.

    Returns:
        ``(4, 4)`` float64 ``T_cam_lidar``.

    Raises:
        DataError: one line naming the file and what is wrong with it.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "file not found" if not path.exists() else "not a regular file")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise DataError(path, "is not a text file (not UTF-8)") from None
    is_json = path.suffix.lower() == ".json" or text.lstrip().startswith("{")
    rows = _from_json(path, text) if is_json else _from_text(path, text)
    lengths = sorted({len(r) for r in rows})
    count = sum(len(r) for r in rows)
    if len(lengths) > 1:
        detail = ", ".join(f"{len(r)}" for r in rows)
        raise DataError(path, f"rows have different lengths ({detail} numbers); expected rows of 4")
    if count not in (12, 16):
        raise DataError(path, f"holds {count} numbers; expected 12 (3x4 [R | t]) or 16 (4x4), row-major")
    if len(rows) > 1 and lengths != [4]:
        raise DataError(path, f"rows hold {lengths[0]} numbers; expected rows of 4 (row-major T_cam_lidar)")
    values = np.array([v for r in rows for v in r], dtype=np.float64)
    bad = [i for i, v in enumerate(values) if not math.isfinite(v)]
    if bad:
        where = ", ".join(f"row {i // 4 + 1} column {i % 4 + 1}" for i in bad[:3])
        raise DataError(path, f"holds NaN or infinite values ({where})")
    T = np.eye(4)
    T[: count // 4] = values.reshape(-1, 4)
    problem = rigid_problem(T)
    if problem is not None:
        raise DataError(path, f"T_cam_lidar is not a rigid transform: {problem}")
    return T
