"""Extrinsic files: ``T_cam_lidar`` from a ``result.json`` or a text file of numbers, checked.

Accepted:

- a JSON object with the key ``T_cam_lidar``: a 4x4 (or 3x4) nested list, as ``supportnet
  calibrate`` writes in ``result.json``;
- a text file of 12 or 16 numbers, row-major ``T_cam_lidar`` (``[R | t]`` or the whole 4x4),
  whitespace- or comma-separated, over any number of lines; ``#`` (or MATLAB's ``%``) starts a
  comment. numpy- and MATLAB-style matrices are read too: brackets (and ``array(...)``, a leading
  ``T =``) are dropped, commas separate numbers and semicolons separate rows
  (``[[1,0,0,0],[0,1,0,0],...]``, ``1,0,0,0;0,1,0,0;...``);
- a KITTI calibration file: a raw drive's ``calib_velo_to_cam.txt`` (``R:`` and ``T:`` lines give
  ``T_cam_lidar = [R | T]``, LiDAR to the unrectified camera 0), an odometry ``calib.txt``
  (``Tr:``, LiDAR to the rectified camera 0) or an object split's calibration
  (``Tr_velo_to_cam:``). Any other ``key: values`` file is refused with the lines it needs.

A UTF-8 byte-order mark at the start is ignored.

Refused, each with one line naming the file: a file that does not parse, rows of different
lengths, a count other than 12 or 16, NaN or infinite values, a last row other than
``[0, 0, 0, 1]``, and a rotation that is not rigid (``R Rᵀ = I`` and ``det R = +1`` within
:data:`RIGID_ATOL`).
"""

from __future__ import annotations

import json
import math
import re
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
            try:
                float(v)
            except OverflowError:  # an integer of hundreds of digits
                digits = len(str(abs(v)))
                raise DataError(
                    path, f"'T_cam_lidar' holds a {digits}-digit integer, too large for a number"
                ) from None
    return [[float(v) for v in r] for r in rows]


_KEY_LINE = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*:(.*)$")
"""A ``key: values`` line of a KITTI calibration file."""

_ASSIGNMENT = re.compile(r"^\s*[A-Za-z_][A-Za-z0-9_.]*\s*=\s*(?=[\[(a-z])")
"""A leading ``T = `` (MATLAB, Python) before a bracketed matrix."""

_ARRAY = re.compile(r"\b(?:np\.|numpy\.)?array\s*\(|\bdtype\s*=\s*[\w.]+|[\[\]()]")
"""numpy's ``array(``, ``dtype=...`` and brackets: dropped from a numpy- or MATLAB-style matrix."""

KITTI_LINES = (("Tr", 12), ("Tr_velo_to_cam", 12))
"""KITTI calibration keys holding ``T_cam_lidar`` as 12 row-major numbers (odometry, object)."""


def _strip_comment(line: str) -> str:
    return re.split(r"[#%]", line, maxsplit=1)[0]


def _from_kitti(path: Path, text: str) -> list[list[float]]:
    """``T_cam_lidar`` from a KITTI ``key: values`` calibration file (``Tr:``,
    ``Tr_velo_to_cam:``, or ``R:`` with ``T:``)."""
    values: dict[str, str] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        line = _strip_comment(line)
        if not line.strip():
            continue
        match = _KEY_LINE.match(line)
        if match is None:
            raise DataError(
                path, f"line {number} is not 'key: values' like the other lines: {line.strip()[:60]!r}"
            )
        values[match.group(1)] = match.group(2)
    keys = ", ".join(values)

    def numbers(key: str, count: int) -> list[float]:
        try:
            found = [float(v) for v in values[key].replace(",", " ").split()]
        except ValueError:
            raise DataError(path, f"the {key}: line is not numbers: {values[key].strip()[:60]!r}") from None
        if len(found) != count:
            raise DataError(path, f"the {key}: line holds {len(found)} numbers; expected {count}")
        return found

    hint = (
        "give a KITTI raw drive's calib_velo_to_cam.txt (R: and T: lines), an odometry calib.txt "
        "(Tr: line), or copy the LiDAR-to-camera line's 12 numbers into a text file"
    )
    if "imu" in path.name.lower() and "R" in values:
        raise DataError(path, f"holds the IMU-to-LiDAR transform, not LiDAR-to-camera; {hint}")
    for key, count in KITTI_LINES:
        if key in values:
            found = numbers(key, count)
            return [found[i : i + 4] for i in range(0, 12, 4)]
    if "R" in values and "T" in values:
        R, t = numbers("R", 9), numbers("T", 3)
        return [[*R[3 * i : 3 * i + 3], t[i]] for i in range(3)]
    if "R" in values or "T" in values:
        missing = "T:" if "R" in values else "R:"
        raise DataError(path, f"looks like a KITTI calib_velo_to_cam.txt but has no {missing} line")
    raise DataError(
        path, f"is a 'key: values' calibration file without a LiDAR-to-camera line (has: {keys}); {hint}"
    )


def _from_text(path: Path, text: str) -> list[list[float]]:
    lines = [_strip_comment(line) for line in text.splitlines()]
    if any(_KEY_LINE.match(line) for line in lines):
        return _from_kitti(path, text)
    rows = []
    for number, line in enumerate(lines, start=1):
        line = _ARRAY.sub(" ", _ASSIGNMENT.sub("", line)).replace(",", " ")
        for part in line.split(";"):
            part = part.strip()
            if not part:
                continue
            try:
                rows.append([float(v) for v in part.split()])
            except ValueError:
                raise DataError(path, f"line {number} is not numbers: {part[:60]!r}") from None
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
        text = path.read_text(encoding="utf-8-sig")
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
