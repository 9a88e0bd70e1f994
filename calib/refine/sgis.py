"""Which correspondences Stage 4 uses: support-guided importance sampling (SGIS, the paper's
Eq. 3) or uniform sampling (the MDPCalib baseline), both without replacement; and SGIS within
depth strata, which lets the support choose among points of like depth while each depth keeps
the share uniform sampling gives it (a translation moves a point by ``f · t / z`` pixels: near
points carry the translation, and a support map bright on far structure would starve them)."""

from __future__ import annotations

import numpy as np

__all__ = ["depth_strata", "stratified_support_sample", "support_sample", "uniform_sample"]


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


def depth_strata(depth: np.ndarray, count: int) -> np.ndarray:
    """Stratum ``0 … count-1`` of each point by its depth's quantile: ``count`` strata of (nearly)
    equal size, nearest first.

    Args:
        depth: ``(N,)`` finite depths (or ranges). count: strata, ``>= 1``.

    Returns:
        ``(N,)`` int64 labels.
    """
    depth = np.asarray(depth, dtype=np.float64)
    if depth.ndim != 1:
        raise ValueError(f"depth must have shape (N,), got {depth.shape}")
    if count < 1:
        raise ValueError(f"count must be at least 1, got {count}")
    if not np.isfinite(depth).all():
        raise ValueError("depth must be finite")
    rank = np.empty(len(depth), np.int64)
    rank[np.argsort(depth, kind="stable")] = np.arange(len(depth))
    return rank * count // max(len(depth), 1)


def stratified_support_sample(
    support: np.ndarray, strata: np.ndarray, k: int, rng: np.random.Generator, floor: float = 0.0
) -> np.ndarray:
    """:func:`support_sample` within each stratum: stratum ``b`` of ``n_b`` of the ``n`` candidates
    gets ``k · n_b / n`` of the ``k`` draws (rounded by largest remainder), what uniform sampling
    gives it on average; within it, Eq. 3 on the support.

    Args:
        support: ``(N,)`` non-negative support. strata: ``(N,)`` int labels (:func:`depth_strata`).
        k: how many to draw. rng: source of randomness. floor: added to every weight, ``>= 0``.

    Returns:
        ``(<= min(k, N),)`` sorted int64 indices (fewer where a stratum has too few of weight).
    """
    strata = np.asarray(strata)
    if strata.shape != np.shape(support):
        raise ValueError(f"strata must have the support's shape {np.shape(support)}, got {strata.shape}")
    if k < 0:
        raise ValueError(f"k must be non-negative, got k={k}")
    labels, sizes = np.unique(strata, return_counts=True)
    n = len(strata)
    if n == 0:
        return np.zeros(0, np.int64)
    share = min(k, n) * sizes / n
    quota = np.floor(share).astype(np.int64)
    quota[np.argsort(quota - share)[: min(k, n) - int(quota.sum())]] += 1  # largest remainders
    support = np.asarray(support, dtype=np.float64)
    chosen = [
        members[support_sample(support[members], int(q), rng, floor)]
        for label, q in zip(labels, quota, strict=True)
        for members in (np.flatnonzero(strata == label),)
    ]
    return np.sort(np.concatenate(chosen))
