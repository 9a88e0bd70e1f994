"""Where calibration evidence lives: matcher residuals under the reference, split by class (the
paper's Experiments 1 and 2).

A class comes from the point's own label (SemanticKITTI ``.label``), from the image label at its
pixel, or, when a dataset has neither, from the Excess Green index thresholded by Otsu's method:
foliage where the pixel is green, background elsewhere (the paper's recipe for BLT).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np

from calib.data.classes import class_name
from calib.data.types import Frame
from calib.errors import DataError
from calib.match.correspondences import Correspondences
from calib.projection import pixel_lookup

__all__ = [
    "EXG_CLASSES",
    "ClassResiduals",
    "ClassSource",
    "ClassStats",
    "class_source",
    "classwise_average",
    "excess_green_foliage",
    "point_classes",
]

ClassSource = Literal["points", "image", "exg"]
EXG_CLASSES: dict[int, str] = {0: "background", 1: "foliage"}


def excess_green_foliage(image: np.ndarray) -> np.ndarray:
    """Foliage mask by Excess Green ``ExG = 2g − r − b`` on chromatic coordinates
    (``r = R / (R + G + B)``, ...) with Otsu's threshold over the image.

    Args:
        image: ``(H, W, 3)`` uint8 RGB.

    Returns:
        ``(H, W)`` bool, True on foliage.
    """
    rgb = image.astype(np.float32)
    r, g, b = np.moveaxis(rgb / np.maximum(rgb.sum(-1, keepdims=True), 1.0), -1, 0)
    exg = 2 * g - r - b  # in [−1, 2]
    exg8 = np.round((exg + 1) * (255 / 3)).astype(np.uint8)
    threshold, _ = cv2.threshold(exg8, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return exg8 > threshold


def class_source(frame: Frame, requested: ClassSource | Literal["auto"] = "auto") -> ClassSource:
    """The class source for ``frame``: ``requested``, or in ``auto`` the best one it has (point
    labels, then image labels, then Excess Green)."""
    has = {"points": frame.labels is not None, "image": frame.image_labels is not None, "exg": True}
    if requested == "auto":
        return next(s for s in ("points", "image", "exg") if has[s])
    if not has[requested]:
        raise DataError(frame.name or f"frame {frame.index}", f"has no {requested} labels for --classes")
    return requested


def point_classes(frame: Frame, corr: Correspondences, source: ClassSource) -> np.ndarray:
    """``(N,)`` int class id of each correspondence (ids of :data:`EXG_CLASSES` for ``exg``)."""
    if source == "points":
        return np.asarray(frame.labels)[corr.index].astype(np.int64)
    labels = np.asarray(frame.image_labels if source == "image" else excess_green_foliage(frame.image))
    if labels.shape[:2] != frame.image_size:
        H, W = frame.image_size
        raise DataError(
            frame.name or f"frame {frame.index}",
            f"image labels are {labels.shape[1]}x{labels.shape[0]} but the image is {W}x{H}: "
            "resize them (nearest neighbour) to the image first",
        )
    return pixel_lookup(labels, corr.uv).astype(np.int64)


@dataclass(frozen=True)
class ClassStats:
    """Residual statistics of one class (pixels of the dataset's images)."""

    name: str
    points: int
    mean_du: float
    mean_dv: float
    median_du: float
    median_dv: float
    median_norm: float
    median_depth_m: float
    mean_support: float | None = None


@dataclass
class ClassResiduals:
    """Accumulates ``|Δu|, |Δv|`` (and optionally the support map's value) per class name over
    frames and sequences (classes are keyed by name, so datasets with different ids combine)."""

    _abs: dict[str, list[np.ndarray]] = field(default_factory=dict)
    _depth: dict[str, list[np.ndarray]] = field(default_factory=dict)
    _support: dict[str, list[np.ndarray]] = field(default_factory=dict)

    def add(
        self,
        classes: np.ndarray,
        residual: np.ndarray,
        depth: np.ndarray,
        names: Mapping[int, str],
        support: np.ndarray | None = None,
    ) -> None:
        """Args:
        classes: ``(N,)`` class ids. residual: ``(N, 2)`` as ``(Δu, Δv)``.
        depth: ``(N,)`` camera-frame depth in metres (residuals of a time offset or a translation
            error scale with ``1 / depth``, so the class's depth explains part of its ranking).
        names: id → name (ids missing there take SemanticKITTI's names).
        support: ``(N,)`` support-map value at each point, or None.
        """
        for c in np.unique(classes):
            m, name = classes == c, names.get(int(c), class_name(int(c)))
            self._abs.setdefault(name, []).append(np.abs(residual[m]).astype(np.float32))
            self._depth.setdefault(name, []).append(depth[m].astype(np.float32))
            if support is not None:
                self._support.setdefault(name, []).append(support[m].astype(np.float32))

    def stats(self, min_points: int = 1) -> list[ClassStats]:
        """Per-class statistics of classes with at least ``min_points``, by median ``‖f‖``."""
        rows = []
        for name, chunks in self._abs.items():
            a = np.concatenate(chunks)
            if len(a) < min_points:
                continue
            mean, median = a.mean(0), np.median(a, 0)
            support = self._support.get(name)
            rows.append(
                ClassStats(
                    name,
                    len(a),
                    float(mean[0]),
                    float(mean[1]),
                    float(median[0]),
                    float(median[1]),
                    float(np.median(np.linalg.norm(a, axis=1))),
                    float(np.median(np.concatenate(self._depth[name]))),
                    float(np.concatenate(support).mean()) if support else None,
                )
            )
        return sorted(rows, key=lambda s: s.median_norm)


def classwise_average(stats: list[ClassStats]) -> tuple[float, float]:
    """The global class-wise average: the mean over classes of each class's mean ``|Δu|`` and
    ``|Δv|`` (every class counts once, however many points it has)."""
    if not stats:
        return float("nan"), float("nan")
    return float(np.mean([s.mean_du for s in stats])), float(np.mean([s.mean_dv for s in stats]))
