"""Procedural noise evaluated at world coordinates, so a texture stays fixed on its surface
whichever view renders it (visual odometry needs features that repeat across frames)."""

from __future__ import annotations

import numpy as np

__all__ = ["fbm", "value_noise"]

_TABLE_SIZE = 1 << 16
_PRIMES = np.array([73856093, 19349663, 83492791], dtype=np.int64)


def _table(seed: int) -> np.ndarray:
    return np.random.default_rng([seed, 0x5EED]).random(_TABLE_SIZE, dtype=np.float32)


_TABLES: dict[int, np.ndarray] = {}


def value_noise(points: np.ndarray, scale: float, seed: int = 0) -> np.ndarray:
    """Smooth lattice noise: random values on a cubic lattice of spacing ``scale``, blended
    trilinearly with a smoothstep.

    Args:
        points: ``(N, 3)`` world coordinates in metres.
        scale: lattice spacing in metres (the size of a blob).
        seed: picks the random lattice.

    Returns:
        ``(N,)`` float32 in ``[0, 1]``.
    """
    table = _TABLES.get(seed)
    if table is None:
        table = _TABLES.setdefault(seed, _table(seed))
    p = np.asarray(points, dtype=np.float64) / scale
    cell = np.floor(p)
    f = (p - cell).astype(np.float32)
    f = f * f * (3.0 - 2.0 * f)
    cell = cell.astype(np.int64) * _PRIMES
    out = np.zeros(len(p), dtype=np.float32)
    for dx in (0, 1):
        hx = cell[:, 0] + dx * _PRIMES[0]
        wx = f[:, 0] if dx else 1.0 - f[:, 0]
        for dy in (0, 1):
            hxy = hx ^ (cell[:, 1] + dy * _PRIMES[1])
            wxy = wx * (f[:, 1] if dy else 1.0 - f[:, 1])
            for dz in (0, 1):
                h = (hxy ^ (cell[:, 2] + dz * _PRIMES[2])) & (_TABLE_SIZE - 1)
                out += wxy * (f[:, 2] if dz else 1.0 - f[:, 2]) * table[h]
    return out


def fbm(points: np.ndarray, scale: float, octaves: int = 3, seed: int = 0) -> np.ndarray:
    """Fractal sum of :func:`value_noise` octaves, each half the size and half the weight.

    Returns:
        ``(N,)`` float32 in ``[0, 1]``.
    """
    total = np.zeros(len(points), dtype=np.float32)
    weight, norm = 1.0, 0.0
    for octave in range(octaves):
        total += weight * value_noise(points, scale / 2**octave, seed + octave)
        norm += weight
        weight *= 0.5
    return total / norm
