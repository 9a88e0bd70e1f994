"""Low-level file readers and writers: scans, labels, images, KITTI key-value files.

Every reader validates what it returns and raises :class:`~calib.errors.DataError` naming the file
and the problem, so the CLI can answer a bad input with one line.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from calib.errors import DataError

__all__ = [
    "format_kv_line",
    "format_row",
    "lzf_decompress",
    "read_image",
    "read_kv_file",
    "read_label",
    "read_label_image",
    "read_pcd",
    "read_pcd_fields",
    "read_point_times",
    "read_scan",
    "require_file",
    "scanline_order",
    "validate_points",
    "write_bin",
    "write_image",
    "write_label",
    "write_pcd",
]

SCAN_SUFFIXES = (".bin", ".pcd", ".npy")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def require_file(path: Path) -> None:
    if not path.is_file():
        raise DataError(path, "file not found" if not path.exists() else "not a regular file")


def validate_points(points: np.ndarray, path: Path, drop_nonfinite: bool = False) -> np.ndarray:
    """Return ``(N, 4)`` float32 points or raise: an empty scan or non-finite values are errors.

    Args:
        points: ``(N, C)`` with ``C >= 3``; the fourth column is intensity (zeros when absent).
        path: the file the points came from, for the message.
        drop_nonfinite: organised clouds (PCD with HEIGHT > 1, ROS PointCloud2 with
            ``is_dense = false``) mark missing returns with NaN; those rows are dropped instead.
    """
    if points.ndim != 2 or points.shape[1] < 3:
        raise DataError(path, f"expected an (N, >=3) point array, got shape {points.shape}")
    if points.shape[1] == 3:
        points = np.concatenate([points, np.zeros((len(points), 1), points.dtype)], axis=1)
    points = np.ascontiguousarray(points[:, :4], dtype=np.float32)
    finite = np.isfinite(points).all(axis=1)
    if not finite.all():
        if not drop_nonfinite:
            raise DataError(path, f"{int((~finite).sum())} of {len(points)} points are NaN or infinite")
        points = points[finite]
    if len(points) == 0:
        raise DataError(path, "empty scan (0 points)")
    return points


def read_bin(path: Path) -> np.ndarray:
    """KITTI velodyne ``.bin``: float32 ``x, y, z, reflectance`` per point."""
    path = Path(path)
    require_file(path)
    size = path.stat().st_size
    if size % 16:
        raise DataError(path, f"truncated: {size} bytes is not a multiple of 16 (4 float32 per point)")
    return validate_points(np.fromfile(path, dtype=np.float32).reshape(-1, 4), path)


def write_bin(path: Path, points: np.ndarray) -> None:
    """Write ``(N, 4)`` points as KITTI ``.bin``."""
    np.ascontiguousarray(points[:, :4], dtype=np.float32).tofile(path)


def lzf_decompress(data: bytes, expected_size: int) -> bytes:
    """Decompress liblzf data (as in PCL's ``binary_compressed`` PCD)."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        ctrl = data[i]
        i += 1
        if ctrl < 32:  # literal run of ctrl + 1 bytes
            out += data[i : i + ctrl + 1]
            i += ctrl + 1
            continue
        length = ctrl >> 5
        if length == 7:
            if i >= n:
                raise ValueError("compressed data end inside a back reference")
            length += data[i]
            i += 1
        if i >= n:
            raise ValueError("compressed data end inside a back reference")
        start = len(out) - ((ctrl & 0x1F) << 8) - data[i] - 1
        i += 1
        length += 2
        if start < 0:
            raise ValueError("back reference before the start of the output")
        if start + length <= len(out):
            out += out[start : start + length]
        else:  # overlapping copy repeats the pattern
            for k in range(length):
                out.append(out[start + k])
    if len(out) != expected_size:
        raise ValueError(f"decompressed {len(out)} bytes, header says {expected_size}")
    return bytes(out)


_PCD_TYPES = {
    ("F", 4): "f4",
    ("F", 8): "f8",
    ("U", 1): "u1",
    ("U", 2): "u2",
    ("U", 4): "u4",
    ("U", 8): "u8",
    ("I", 1): "i1",
    ("I", 2): "i2",
    ("I", 4): "i4",
    ("I", 8): "i8",
}


def _pcd_header(raw: bytes, path: Path) -> tuple[dict[str, list[str]], int]:
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise DataError(path, "PCD header has no DATA line")
        line = raw[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        header[key.upper()] = values
        if key.upper() == "DATA":
            return header, pos


def read_pcd_fields(path: Path) -> tuple[dict[str, np.ndarray], int]:
    """Every field of a PCD v0.7 file (``ascii``, ``binary`` or ``binary_compressed``).

    Returns:
        ``{field: (N,) or (N, COUNT) array}`` and the cloud's ``HEIGHT`` (> 1 = organised).
    """
    path = Path(path)
    require_file(path)
    raw = path.read_bytes()
    header, offset = _pcd_header(raw, path)
    try:
        # PCL pads with fields named "_" (as many as it needs): each gets a name of its own
        fields = [f"_{k}" if f == "_" else f for k, f in enumerate(header["FIELDS"])]
        sizes = [int(s) for s in header["SIZE"]]
        types = header["TYPE"]
        counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
        n = int(header["POINTS"][0])
        height = int(header.get("HEIGHT", ["1"])[0])
        kind = header["DATA"][0].lower()
        dtype = np.dtype(
            [
                (f, _PCD_TYPES[(t.upper(), s)], (c,) if c > 1 else ())
                for f, s, t, c in zip(fields, sizes, types, counts, strict=True)
            ]
        )
    except (KeyError, ValueError, IndexError) as exc:
        raise DataError(path, f"PCD header does not parse ({exc})") from None
    body = raw[offset:]
    try:
        if kind == "ascii":
            table = np.loadtxt(body.decode("ascii").splitlines(), dtype=np.float64, ndmin=2)
            if n and table.shape[1] != sum(counts):
                raise ValueError(f"{table.shape[1]} columns for fields of {sum(counts)} values")
            first = np.cumsum([0, *counts[:-1]])  # a field of COUNT c spans c columns
            cloud = {}
            for f, k, c in zip(fields, first, counts, strict=True) if n else ():
                cloud[f] = table[:, k] if c == 1 else table[:, k : k + c]
        elif kind == "binary":
            array = np.frombuffer(body, dtype=dtype, count=n)
            cloud = {f: array[f] for f in fields}
        elif kind == "binary_compressed":
            comp, uncomp = np.frombuffer(body[:8], dtype="<u4")
            data = lzf_decompress(body[8 : 8 + comp], int(uncomp))
            cloud, pos = {}, 0  # field-major layout: all x, then all y, ...
            for name in fields:
                sub = dtype[name]
                cloud[name] = np.frombuffer(data, dtype=sub, count=n, offset=pos)
                pos += sub.itemsize * n
        else:
            raise DataError(path, f"unknown PCD DATA kind {kind!r}")
    except (ValueError, TypeError, IndexError) as exc:
        raise DataError(path, f"PCD body does not parse ({exc})") from None
    if n == 0:
        raise DataError(path, "empty scan (0 points)")
    return cloud, height


def read_pcd(path: Path) -> np.ndarray:
    """PCD v0.7 -> ``(N, 4)`` float32 (see :func:`read_pcd_fields`).

    Intensity is taken from ``intensity``, ``reflectivity`` or ``i`` when present, else zeros.
    NaN rows of organised clouds (``HEIGHT > 1``) are no-returns and dropped.
    """
    cloud, height = read_pcd_fields(path)
    if not {"x", "y", "z"} <= set(cloud):
        raise DataError(path, f"PCD has no x, y, z fields (fields: {' '.join(cloud)})")
    inten = next((f for f in ("intensity", "reflectivity", "i") if f in cloud), None)
    n = len(cloud["x"])
    columns = [cloud["x"], cloud["y"], cloud["z"], cloud[inten] if inten else np.zeros(n)]
    points = np.stack([np.asarray(c, dtype=np.float64).reshape(-1) for c in columns], axis=1)
    return validate_points(points, Path(path), drop_nonfinite=height > 1)


def write_pcd(path: Path, points: np.ndarray) -> None:
    """Write ``(N, 4)`` points as a binary PCD with fields x y z intensity."""
    pts = np.ascontiguousarray(points[:, :4], dtype=np.float32)
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity\n"
        "SIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
        f"WIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(pts)}\nDATA binary\n"
    )
    Path(path).write_bytes(header.encode("ascii") + pts.tobytes())


def read_npy_scan(path: Path) -> np.ndarray:
    """A ``.npy`` array ``(N, 3)`` or ``(N, >=4)``, the fourth column intensity; or a structured
    array ``(N,)`` with fields ``x``, ``y``, ``z`` and optionally ``intensity`` (``reflectivity``,
    ``i``), as ``ros_numpy`` writes a PointCloud2."""
    path = Path(path)
    require_file(path)
    try:
        array = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise DataError(path, f"not a readable .npy array ({exc})") from None
    if array.dtype.names is not None:
        names = array.dtype.names
        if not {"x", "y", "z"} <= set(names):
            raise DataError(path, f"structured array without x, y, z fields (fields: {' '.join(names)})")
        inten = next((f for f in ("intensity", "reflectivity", "i") if f in names), None)
        columns = [array[f] for f in ("x", "y", "z")] + ([array[inten]] if inten else [])
        array = np.stack([np.asarray(c, dtype=np.float64).reshape(-1) for c in columns], axis=1)
    try:
        array = np.asarray(array, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DataError(path, f"not an array of numbers ({exc})") from None
    return validate_points(array, path)


_SCAN_READERS: dict[str, Callable[[Path], np.ndarray]] = {
    ".bin": read_bin,
    ".pcd": read_pcd,
    ".npy": read_npy_scan,
}


def read_scan(path: Path) -> np.ndarray:
    """Read a LiDAR scan by suffix (``.bin``, ``.pcd``, ``.npy``) -> ``(N, 4)`` float32."""
    path = Path(path)
    reader = _SCAN_READERS.get(path.suffix.lower())
    if reader is None:
        raise DataError(path, f"unknown scan format {path.suffix!r} (expected {', '.join(SCAN_SUFFIXES)})")
    return reader(path)


def _read_per_point(path: Path, n_points: int, what: str) -> np.ndarray:
    """A raw file of one 4-byte value per point, checked against the scan's length."""
    path = Path(path)
    require_file(path)
    size = path.stat().st_size
    if size != 4 * n_points:
        raise DataError(path, f"holds {size / 4:g} {what} for a scan of {n_points} points")
    return np.fromfile(path, dtype=np.uint32)


def read_label(path: Path, n_points: int) -> np.ndarray:
    """SemanticKITTI ``.label``: uint32 per point, lower 16 bits = class -> ``(N,)`` uint16."""
    return (_read_per_point(path, n_points, "labels") & 0xFFFF).astype(np.uint16)


def read_point_times(path: Path, n_points: int) -> np.ndarray:
    """Per-point times: float32 seconds from the scan stamp, one per point -> ``(N,)`` float64."""
    return _read_per_point(path, n_points, "point times").view(np.float32).astype(np.float64)


def write_label(path: Path, labels: np.ndarray, instances: np.ndarray | None = None) -> None:
    """Write per-point class ids as SemanticKITTI ``.label``, instance ids (default 0) in the
    upper 16 bits."""
    value = np.asarray(labels, dtype=np.uint32) & 0xFFFF
    if instances is not None:
        value |= np.asarray(instances, dtype=np.uint32) << 16
    np.ascontiguousarray(value).tofile(path)


def _decode_image(path: Path, flags: int) -> np.ndarray:
    require_file(path)
    buffer = np.fromfile(path, dtype=np.uint8)
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # we raise our own error
    try:
        image = cv2.imdecode(buffer, flags) if buffer.size else None
    finally:
        cv2.utils.logging.setLogLevel(level)
    if image is None:
        raise DataError(path, "image is corrupt or not an image (could not decode)")
    return image


def read_image(path: Path) -> np.ndarray:
    """Read an image as ``(H, W, 3)`` uint8 RGB (grayscale replicated, 16-bit scaled down)."""
    path = Path(path)
    image = _decode_image(path, cv2.IMREAD_UNCHANGED)
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise DataError(path, f"unsupported image pixel type {image.dtype}")
    if image.ndim == 2:
        return np.ascontiguousarray(np.repeat(image[:, :, None], 3, axis=2))
    code = cv2.COLOR_BGRA2RGB if image.shape[2] == 4 else cv2.COLOR_BGR2RGB
    return cv2.cvtColor(image, code)


def read_label_image(path: Path) -> np.ndarray:
    """Per-pixel class ids from a single-channel 8- or 16-bit PNG -> ``(H, W)`` uint16."""
    path = Path(path)
    image = _decode_image(path, cv2.IMREAD_UNCHANGED)
    if image.ndim != 2:
        raise DataError(path, f"label image must have one channel, got shape {image.shape}")
    return image.astype(np.uint16)


def write_image(path: Path, image: np.ndarray) -> None:
    """Write ``(H, W, 3)`` uint8 RGB, or a single-channel uint8/uint16 image, by suffix."""
    path = Path(path)
    data = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    ok, encoded = cv2.imencode(path.suffix, data)
    if not ok:
        raise DataError(path, "could not encode image")
    encoded.tofile(path)


_KV_LINE = re.compile(r"^\s*([A-Za-z0-9_]+)\s*[:=]\s*(.*)$")


def read_kv_file(path: Path) -> dict[str, np.ndarray | str]:
    """KITTI-style ``key: v1 v2 ...`` files (``calib.txt``, ``calib_*.txt``).

    Numeric values become float64 arrays; other values (``calib_time``) stay strings.
    """
    path = Path(path)
    require_file(path)
    result: dict[str, np.ndarray | str] = {}
    for number, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
        if not line.strip():
            continue
        match = _KV_LINE.match(line)
        if match is None:
            raise DataError(path, f"line {number} is not 'key: values': {line.strip()[:60]!r}")
        key, value = match.groups()
        try:
            result[key] = np.array([float(v) for v in value.split()], dtype=np.float64)
        except ValueError:
            result[key] = value.strip()
    return result


def format_row(values: np.ndarray) -> str:
    """Numbers as one space-separated line, at full precision (KITTI calibration and pose files)."""
    return " ".join(f"{v:.12e}" for v in np.asarray(values, dtype=np.float64).reshape(-1)) + "\n"


def format_kv_line(key: str, values: np.ndarray) -> str:
    """One ``key: v1 v2 ...`` line of a KITTI calibration file (the inverse of :func:`read_kv_file`)."""
    return f"{key}: " + format_row(values)


def kv_matrix(values: dict, key: str, shape: tuple[int, int], path: Path) -> np.ndarray:
    """Fetch ``key`` from :func:`read_kv_file` output as a float64 matrix of ``shape``."""
    if key not in values:
        raise DataError(path, f"no {key!r} entry (has: {', '.join(sorted(values)) or 'nothing'})")
    array = values[key]
    size = shape[0] * shape[1]
    if isinstance(array, str) or array.size != size:
        raise DataError(
            path, f"{key!r} must hold {size} numbers, got {array if isinstance(array, str) else array.size}"
        )
    return array.reshape(shape)


def atomic_write_text(path: Path, text: str) -> None:
    """Write text through a temporary name and an atomic rename."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text)
    tmp.replace(path)


def scanline_order(points_lidar: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """``(N,)`` indices putting a scan stored in firing order (every laser of a column, then the
    next column: nuScenes, PJLab) into scan-line order (ring by ring, each by azimuth), the order
    KITTI's Velodyne scans are stored in and :func:`calib.features.depth_discontinuities` reads
    neighbours from when it gets no ring."""
    xyz = np.asarray(points_lidar, np.float64)
    return np.lexsort((np.arctan2(xyz[:, 1], xyz[:, 0]), np.asarray(ring)))
