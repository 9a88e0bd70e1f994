"""Procedural noise evaluated at world coordinates, so a texture stays fixed on its surface
whichever view renders it (visual odometry needs features that repeat across frames)."""

from __future__ import annotations

import numpy as np

__all__ = ["fbm", "value_noise"]

_TABLE_SIZE = 1 << 16
_PRIMES = np.array([73856093, 19349663, 83492791], dtype=np.int64)
_WORD = 1 << 32

Key = int | tuple[int, ...]
"""A lattice's seed: an integer, or a tuple of them (``(seed, purpose, index)``), each in [0, 2³²)."""


def _key(seed: Key) -> tuple[int, ...]:
    key = tuple(int(k) for k in seed) if isinstance(seed, tuple) else (int(seed),)
    if not all(0 <= k < _WORD for k in key):
        raise ValueError(f"noise seeds are integers in [0, 2^32), got {seed!r}")
    return key


def _table(key: tuple[int, ...]) -> np.ndarray:
    # the length goes first, so (a, b) and (a, b, 0) differ (a SeedSequence pads with zeros)
    return np.random.default_rng([0x5EED, len(key), *key]).random(_TABLE_SIZE, dtype=np.float32)


_TABLES: dict[tuple[int, ...], np.ndarray] = {}
_MAX_TABLES = 512  # 256 KB each; a long run over many seeds starts the cache afresh


def value_noise(points: np.ndarray, scale: float, seed: Key = 0) -> np.ndarray:
    """Smooth lattice noise: random values on a cubic lattice of spacing ``scale``, blended
    trilinearly with a smoothstep.

    Args:
        points: ``(N, 3)`` world coordinates in metres.
        scale: lattice spacing in metres (the size of a blob).
        seed: picks the random lattice: an integer or a tuple of integers, each in [0, 2³²);
            distinct keys give independent lattices.

    Returns:
        ``(N,)`` float32 in ``[0, 1]``.
    """
    key = _key(seed)
    table = _TABLES.get(key)
    if table is None:
        if len(_TABLES) >= _MAX_TABLES:
            _TABLES.clear()
        table = _TABLES.setdefault(key, _table(key))
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


def fbm(points: np.ndarray, scale: float, octaves: int = 3, seed: Key = 0) -> np.ndarray:
    """Fractal sum of :func:`value_noise` octaves, each half the size and half the weight; octave
    ``o`` uses the lattice ``(*seed, o)``, so no two keys share an octave.

    Returns:
        ``(N,)`` float32 in ``[0, 1]``.
    """
    key = _key(seed)
    total = np.zeros(len(points), dtype=np.float32)
    weight, norm = 1.0, 0.0
    for octave in range(octaves):
        total += weight * value_noise(points, scale / 2**octave, (*key, octave))
        norm += weight
        weight *= 0.5
    return total / norm
