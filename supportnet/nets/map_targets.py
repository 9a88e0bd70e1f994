"""How close a predicted support map is to the offline one, where the offline one is defined
(numpy; the same numbers in training's validation and in the shipped model's card)."""

from __future__ import annotations

import numpy as np
from scipy.stats import spearmanr

__all__ = ["agreement_scores", "offline_target"]


def agreement_scores(prediction: np.ndarray, target: np.ndarray, weight: np.ndarray) -> dict[str, float]:
    """Weighted MAE, weighted Pearson r and (unweighted) Spearman ρ over pixels with weight > 0.

    Args:
        prediction, target, weight: the same shape (any); ``weight`` ≥ 0 (the coverage-based loss
            weight: zero where the offline map has no LiDAR evidence).

    Returns:
        ``{"mae", "pearson", "spearman", "pixels"}``; r and ρ are NaN when either side is constant.
    """
    if not (prediction.shape == target.shape == weight.shape):
        raise ValueError(f"shapes differ: {prediction.shape}, {target.shape}, {weight.shape}")
    keep = weight > 0
    x, y, w = (np.asarray(a, np.float64)[keep] for a in (prediction, target, weight))
    if w.size < 2:
        raise ValueError("fewer than 2 pixels with positive weight")
    w = w / w.sum()
    mx, my = w @ x, w @ y
    cov = w @ ((x - mx) * (y - my))
    var = (w @ (x - mx) ** 2) * (w @ (y - my) ** 2)
    pearson = cov / np.sqrt(var) if var > 0 else float("nan")
    spearman = spearmanr(x, y).statistic if np.ptp(x) > 0 and np.ptp(y) > 0 else float("nan")
    return {
        "mae": float(w @ np.abs(x - y)),
        "pearson": float(pearson),
        "spearman": float(spearman),
        "pixels": int(keep.sum()),
    }


def offline_target(
    raw: np.ndarray, coverage: np.ndarray, kind: str, min_coverage: float = 0.5, weight_cap: float = 4.0
) -> tuple[np.ndarray, np.ndarray]:
    """What the predictor learns from one frame's offline maps, and where (training and scoring).

    Args:
        raw: ``(H, W)`` Eq. 2 sum ``Σ aG``. coverage: ``(H, W)`` ``Σ G``.
        kind: ``agreement`` (``Σ aG / Σ G``) or ``support`` (Eq. 2 normalised by its peak).
        min_coverage: no target where the coverage is below this.
        weight_cap: the weight is the coverage, capped here (no LiDAR there, no target there).

    Returns:
        ``target (H, W)`` float32 in [0, 1] and ``weight (H, W)`` float32 ≥ 0.
    """
    covered = coverage >= min_coverage
    if kind == "agreement":
        target = np.where(covered, raw / np.maximum(coverage, 1e-12), 0.0)
    elif kind == "support":
        peak = raw.max(initial=0.0)
        target = raw / peak if peak > 0 else raw
    else:
        raise ValueError(f"kind must be agreement or support, got {kind!r}")
    weight = np.where(covered, np.minimum(coverage, weight_cap), 0.0)
    return np.clip(target, 0, 1).astype(np.float32), weight.astype(np.float32)
