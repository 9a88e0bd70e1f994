"""Pictures people look at: LiDAR projections coloured by depth on the image, maps, charts."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from matplotlib import colormaps

from calib.projection import ProjectedScan
from calib.support.class_residuals import ClassStats, classwise_average

__all__ = [
    "DEPTH_CMAP",
    "MAX_DEPTH_M",
    "class_residual_chart",
    "colour_bar",
    "colour_bar_height",
    "colour_name",
    "colour_names",
    "colourise",
    "depth_bar",
    "draw_projection",
    "learning_curves",
    "map_picture",
    "named_colours",
    "tag",
    "trajectories_chart",
    "with_colour_bar",
]

DEPTH_CMAP = "turbo"
MAX_DEPTH_M = 40.0
""":func:`draw_projection` colours depth 0 .. ``MAX_DEPTH_M`` with ``DEPTH_CMAP`` (farther points
take the far end's colour)."""


def colourise(values: np.ndarray, cmap: str = "viridis") -> np.ndarray:
    """``values (...)`` in [0, 1] (clipped) as ``(..., 3)`` uint8 RGB of a matplotlib colour map."""
    return (colormaps[cmap](np.clip(values, 0, 1))[..., :3] * 255).astype(np.uint8)


def draw_projection(
    image: np.ndarray, projected: ProjectedScan, max_depth: float = MAX_DEPTH_M, radius: int | None = None
) -> np.ndarray:
    """The visible points of a scan drawn on ``image (H, W, 3)`` uint8, coloured by depth with
    ``DEPTH_CMAP`` (turbo: 0 m dark purple, then blue, cyan, green, yellow, orange, and red from
    about 0.9 · ``max_depth``; ``max_depth`` and beyond dark red). Returns a new image;
    :func:`depth_bar` is its legend and :func:`colour_name` names the colour of one depth."""
    out = image.copy()
    colours = colourise(projected.depth / max_depth, DEPTH_CMAP)
    radius = radius if radius is not None else max(1, round(image.shape[1] / 1000))
    for (u, v), colour in zip(np.round(projected.uv).astype(int), colours, strict=True):
        cv2.circle(out, (int(u), int(v)), radius, tuple(int(c) for c in colour), -1)
    return out


def colour_name(rgb: np.ndarray | tuple[int, int, int]) -> str:
    """The everyday name of one uint8 RGB colour (``black``, ``white``, ``grey``, ``red``,
    ``orange``, ``yellow``, ``green``, ``cyan``, ``blue``, ``purple``, ``magenta``), by hue,
    saturation and value; captions name colours with it, so a test can find them in the picture."""
    return colour_names(np.asarray(rgb, dtype=np.uint8).reshape(1, 3))[0]


_HUES = (
    (15, "red"),
    (40, "orange"),
    (70, "yellow"),
    (160, "green"),
    (195, "cyan"),
    (260, "blue"),
    (292, "purple"),
    (335, "magenta"),
    (361, "red"),
)


def colour_names(rgb: np.ndarray) -> np.ndarray:
    """``rgb (N, 3)`` uint8 -> ``(N,)`` colour names (:func:`colour_name`), as an object array."""
    hsv = cv2.cvtColor(rgb.reshape(-1, 1, 3), cv2.COLOR_RGB2HSV_FULL).reshape(-1, 3).astype(float)
    hue, sat, val = hsv[:, 0] * 360 / 256, hsv[:, 1] / 255, hsv[:, 2] / 255
    names = np.empty(len(rgb), dtype=object)
    bounds = np.array([b for b, _ in _HUES])
    names[:] = np.array([n for _, n in _HUES], dtype=object)[np.searchsorted(bounds, hue, side="right")]
    grey = sat < 0.2
    names[grey] = "grey"
    names[grey & (val > 0.85)] = "white"
    names[val < 0.15] = "black"
    return names


def named_colours(picture: np.ndarray, min_pixels: int = 20) -> set[str]:
    """The :func:`colour_name` of every colour covering at least ``min_pixels`` pixels of
    ``picture (H, W, 3)`` uint8."""
    rgb = picture.reshape(-1, 3).astype(np.uint32)
    packed, counts = np.unique(rgb[:, 0] << 16 | rgb[:, 1] << 8 | rgb[:, 2], return_counts=True)
    colours = np.column_stack([packed >> 16, packed >> 8 & 255, packed & 255]).astype(np.uint8)
    names = colour_names(colours)
    return {n for n in set(names) if counts[names == n].sum() >= min_pixels}


def colour_bar_height(width: int) -> int:
    """Height in pixels of the :func:`colour_bar` strip under a picture ``width`` pixels wide."""
    return max(44, round(width * 0.05))


def _text_width(text: str, scale: float) -> int:
    return cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, max(1, round(scale * 2)))[0][0]


def _text(image: np.ndarray, text: str, x: int, y: int, scale: float, anchor: str = "left") -> None:
    thickness = max(1, round(scale * 2))
    w = _text_width(text, scale)
    x = {"left": x, "centre": x - w // 2, "right": x - w}[anchor]
    cv2.putText(
        image, text, (int(x), int(y)), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thickness, cv2.LINE_AA
    )


def colour_bar(width: int, cmap: str, low: str, high: str, title: str) -> np.ndarray:
    """A legend strip ``(colour_bar_height(width), width, 3)`` uint8: the colour map as a ramp
    from its low end (left) to its high end (right), ``low`` and ``high`` written under its ends and
    ``title`` under its middle (ASCII text, made smaller where the strip is narrow)."""
    height = colour_bar_height(width)
    bar = np.full((height, width, 3), 255, np.uint8)
    pad = max(3, height // 10)
    x0, x1 = round(width * 0.12), round(width * 0.88)
    ramp_h = height // 2 - pad
    bar[pad : pad + ramp_h, x0:x1] = colourise(np.linspace(0.0, 1.0, x1 - x0), cmap)[None]
    cv2.rectangle(bar, (x0 - 1, pad - 1), (x1, pad + ramp_h), (0, 0, 0), 1)
    scale = max(0.3, height / 95)
    fits = lambda s: _text_width(low, s) + _text_width(title, s) + _text_width(high, s) + 4 * pad <= x1 - x0  # noqa: E731
    while scale > 0.3 and not fits(scale):
        scale *= 0.9
    baseline = height - pad - 1
    _text(bar, low, x0, baseline, scale)
    _text(bar, high, x1, baseline, scale, "right")
    if fits(scale):
        _text(bar, title, (x0 + x1) // 2, baseline, scale, "centre")
    return bar


def with_colour_bar(picture: np.ndarray, cmap: str, low: str, high: str, title: str) -> np.ndarray:
    """``picture (H, W, 3)`` with its :func:`colour_bar` underneath: ``(H + bar, W, 3)``."""
    return np.concatenate([picture, colour_bar(picture.shape[1], cmap, low, high, title)], axis=0)


def map_picture(
    values: np.ndarray, title: str, cmap: str = "viridis", low: float = 0.0, high: float = 1.0
) -> np.ndarray:
    """A map ``values (H, W)`` coloured with ``cmap`` from ``low`` to ``high`` (clipped), with its
    colour bar underneath: ``(H + bar, W, 3)`` uint8."""
    shown = colourise((np.asarray(values, dtype=np.float64) - low) / (high - low), cmap)
    return with_colour_bar(shown, cmap, f"{low:g}", f"{high:g}", title)


def depth_bar(width: int, max_depth: float = MAX_DEPTH_M) -> np.ndarray:
    """The legend of :func:`draw_projection`'s colours, ``width`` pixels wide."""
    return colour_bar(width, DEPTH_CMAP, "0 m (near)", f"{max_depth:g} m+ (far)", "LiDAR point depth")


def tag(image: np.ndarray, text: str) -> np.ndarray:
    """``image`` with ``text`` (ASCII) in white on a black box in its top-left corner; a new image."""
    out = image.copy()
    scale = max(0.45, image.shape[1] / 1800)
    thickness = max(1, round(scale * 2))
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thickness)
    pad = max(3, h // 3)
    cv2.rectangle(out, (0, 0), (w + 2 * pad, h + base + 2 * pad), (0, 0, 0), -1)
    cv2.putText(
        out, text, (pad, pad + h), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), thickness, cv2.LINE_AA
    )
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


def trajectories_chart(lidar_poses: np.ndarray, camera_poses: np.ndarray, path: Path, title: str) -> None:
    """Stage 1's two trajectories as a PNG, from above (x, z) and from the side (z, y), in the
    camera-0 frame: ``lidar_poses (N, 4, 4)`` (LiDAR odometry, a line in matplotlib's first colour,
    blue) and ``camera_poses (M, 4, 4)`` (visual odometry keyframes, dots joined by a line in its
    second colour, orange)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for ax, (a, b), label in zip(
        axes, ((0, 2), (2, 1)), ("from above (x, z)", "from the side (z, y)"), strict=True
    ):
        ax.plot(
            lidar_poses[:, a, 3], lidar_poses[:, b, 3], "-", color="C0", label="LiDAR odometry (KISS-ICP)"
        )
        ax.plot(
            camera_poses[:, a, 3],
            camera_poses[:, b, 3],
            ".-",
            color="C1",
            ms=3,
            label="visual odometry keyframes",
        )
        ax.set(title=label, xlabel="xyz"[a] + " m", ylabel="xyz"[b] + " m")
        ax.axis("equal")
        ax.grid(alpha=0.3)
    axes[1].invert_yaxis()  # camera y points down
    axes[0].legend(fontsize=8)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
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
