"""Which correspondences Stage 4 uses: support-guided importance sampling (SGIS, the paper's
Eq. 3) or uniform sampling (the MDPCalib baseline), both without replacement."""

from __future__ import annotations

import numpy as np

__all__ = ["support_sample", "uniform_sample"]


def uniform_sample(n: int, k: int, rng: np.random.Generator) -> np.ndarray:
    """``min(k, n)`` distinct indices of ``range(n)``, each subset equally likely."""
    if n < 0 or k < 0:
        raise ValueError(f"n and k must be non-negative, got n={n}, k={k}")
    return np.sort(rng.choice(n, size=min(k, n), replace=False))


def support_sample(support: np.ndarray, k: int, rng: np.random.Generator, floor: float = 0.0) -> np.ndarray:
    """``k`` distinct indices drawn one after another with ``p_i = w_i / Σ_j w_j`` over those not
    yet drawn, ``w_i = s_i + floor`` (Eq. 3; the floor keeps zero-support points possible).

    Efraimidis–Spirakis: with ``u_i ~ U(0, 1)`` the ``k`` largest keys ``log(u_i) / w_i`` are
    exactly such a sample, in O(n) with a partial sort, so 100k candidates cost milliseconds.
    Points of zero weight are never drawn (fewer than ``k`` come back when too few have weight).

    Args:
        support: ``(N,)`` non-negative support ``s_i`` of each candidate.
        k: how many to draw.
        rng: source of randomness. floor: added to every weight, ``>= 0``.

    Returns:
        ``(min(k, #positive),)`` sorted int64 indices.
    """
    w = np.asarray(support, dtype=np.float64) + floor
    if w.ndim != 1:
        raise ValueError(f"support must have shape (N,), got {w.shape}")
    if k < 0 or floor < 0:
        raise ValueError(f"k and floor must be non-negative, got k={k}, floor={floor}")
    if not np.isfinite(w).all() or (w < 0).any():
        raise ValueError("support must be finite and non-negative")
    positive = np.flatnonzero(w > 0)
    k = min(k, len(positive))
    if k == 0:
        return np.zeros(0, np.int64)
    keys = np.log(rng.random(len(positive))) / w[positive]
    chosen = np.argpartition(-keys, k - 1)[:k] if k < len(positive) else np.arange(len(positive))
    return np.sort(positive[chosen])
