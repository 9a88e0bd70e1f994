"""Pictures people look at: LiDAR projections coloured by depth on the image, maps, charts."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from matplotlib import colormaps

from calib.projection import ProjectedScan
from calib.support.class_residuals import ClassStats, classwise_average

__all__ = ["class_residual_chart", "colourise", "draw_projection", "learning_curves"]


def colourise(values: np.ndarray, cmap: str = "viridis") -> np.ndarray:
    """``values (...)`` in [0, 1] (clipped) as ``(..., 3)`` uint8 RGB of a matplotlib colour map."""
    return (colormaps[cmap](np.clip(values, 0, 1))[..., :3] * 255).astype(np.uint8)


def draw_projection(
    image: np.ndarray, projected: ProjectedScan, max_depth: float = 40.0, radius: int | None = None
) -> np.ndarray:
    """The visible points of a scan drawn on ``image (H, W, 3)`` uint8, turbo-coloured by depth
    (near = blue, ``max_depth`` and beyond = red). Returns a new image."""
    out = image.copy()
    colours = colourise(projected.depth / max_depth, "turbo")
    radius = radius if radius is not None else max(1, round(image.shape[1] / 1000))
    for (u, v), colour in zip(np.round(projected.uv).astype(int), colours, strict=True):
        cv2.circle(out, (int(u), int(v)), radius, tuple(int(c) for c in colour), -1)
    return out


def class_residual_chart(stats: list[ClassStats], path: Path, title: str) -> None:
    """The paper's class-wise chart as a PNG: per class, the mean ``|Δu|`` (top) and ``|Δv|``
    (bottom) as bars, red above the global class-wise average (dashed) and grey below, and the
    per-class median as a line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [s.name for s in stats]
    x = np.arange(len(stats))
    fig, axes = plt.subplots(2, 1, figsize=(max(5.0, 0.9 * len(stats) + 2), 6), sharex=True)
    for ax, label, means, medians, average in zip(
        axes,
        ("|Δu|", "|Δv|"),
        ([s.mean_du for s in stats], [s.mean_dv for s in stats]),
        ([s.median_du for s in stats], [s.median_dv for s in stats]),
        classwise_average(stats),
        strict=True,
    ):
        colours = ["tab:red" if m > average else "0.6" for m in means]
        ax.bar(x, means, color=colours, label=f"mean {label}")
        ax.axhline(average, color="k", linestyle="--", linewidth=1, label=f"class-wise average {average:.2f}")
        ax.plot(x, medians, "o-", color="k", linewidth=1.2, markersize=4, label=f"median {label}")
        ax.set_ylabel(f"{label} (px)")
        ax.legend(fontsize=8, loc="upper left")
        ax.grid(axis="y", alpha=0.3)
    axes[-1].set_xticks(x, names, rotation=30, ha="right")
    axes[0].set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def learning_curves(metrics_csv: Path, path: Path) -> None:
    """Training and validation loss (left) and every other validation metric (right) per epoch,
    from Lightning's ``metrics.csv``, as a PNG: Pearson r / Spearman ρ / MAE for the support
    predictor, endpoint errors by class for the flow matcher."""
    import csv

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series: dict[str, dict[int, float]] = {}
    with open(metrics_csv, newline="") as f:
        for row in csv.DictReader(f):
            for key, value in row.items():
                if value and key not in ("epoch", "step") and row.get("epoch"):
                    series.setdefault(key, {})[int(row["epoch"])] = float(value)
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.6))
    for key in sorted(series):
        ax = left if key in ("train/loss_epoch", "val/loss") else right if key.startswith("val/") else None
        if ax is not None:
            epochs = sorted(series[key])
            ax.plot(epochs, [series[key][e] for e in epochs], marker=".", label=key)
    left.set(xlabel="epoch", title="loss")
    right.set(xlabel="epoch", title="validation (held-out sequences)")
    right.set_ylim(bottom=0)
    for ax in (left, right):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
