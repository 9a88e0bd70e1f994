"""Agreement of per-point and per-pixel class labels under an extrinsic: the ground-truth check of
synthetic data, and a sanity check of any dataset that has both (SemanticKITTI with image labels)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from calib.data.types import Frame
from calib.projection import Visibility, project_scan

__all__ = ["LabelAgreement", "label_agreement", "sequence_label_agreement"]


@dataclass
class LabelAgreement:
    """Per-class counts of visible points whose pixel neighbourhood holds the point's class.

    Attributes:
        hits, totals: class id → count, accumulated over frames with :meth:`add`.
    """

    hits: dict[int, int] = field(default_factory=dict)
    totals: dict[int, int] = field(default_factory=dict)

    def add(self, other: LabelAgreement) -> None:
        for c, n in other.totals.items():
            self.totals[c] = self.totals.get(c, 0) + n
            self.hits[c] = self.hits.get(c, 0) + other.hits.get(c, 0)

    def rate(self, classes: set[int] | None = None) -> float:
        """Fraction agreeing over ``classes`` (all when ``None``); NaN when there are no points."""
        keys = [c for c in self.totals if classes is None or c in classes]
        total = sum(self.totals[c] for c in keys)
        return sum(self.hits[c] for c in keys) / total if total else float("nan")


def label_agreement(
    points_lidar: np.ndarray,
    labels: np.ndarray,
    image_labels: np.ndarray,
    T_cam_lidar: np.ndarray,
    K: np.ndarray,
    radius_px: int = 1,
    visibility: Visibility | None = Visibility(),
) -> LabelAgreement:
    """Project the visible points and ask whether the image labels within ``radius_px`` of each
    point's pixel include the point's class (the tolerance absorbs pixel rounding at edges).

    Args:
        points_lidar: ``(N, 3+)`` scan. labels: ``(N,)`` class per point.
        image_labels: ``(H, W)`` class per pixel. T_cam_lidar: ``(4, 4)``. K: ``(3, 3)``.
    """
    H, W = image_labels.shape
    scan = project_scan(points_lidar, T_cam_lidar, K, (H, W), visibility)
    u = np.rint(scan.uv[:, 0]).astype(int)
    v = np.rint(scan.uv[:, 1]).astype(int)
    cls = np.asarray(labels)[scan.index]
    agree = np.zeros(len(u), bool)
    for dv in range(-radius_px, radius_px + 1):
        for du in range(-radius_px, radius_px + 1):
            agree |= image_labels[np.clip(v + dv, 0, H - 1), np.clip(u + du, 0, W - 1)] == cls
    result = LabelAgreement()
    for c in np.unique(cls):
        m = cls == c
        result.totals[int(c)] = int(m.sum())
        result.hits[int(c)] = int(agree[m].sum())
    return result


def sequence_label_agreement(
    frames: Iterable[Frame], T_cam_lidar: np.ndarray | None = None
) -> LabelAgreement:
    """:func:`label_agreement` summed over frames that carry point and pixel labels, under
    ``T_cam_lidar`` (default: each frame's reference extrinsic)."""
    total = LabelAgreement()
    for f in frames:
        T = f.calibration.T_cam_lidar if T_cam_lidar is None else T_cam_lidar
        total.add(label_agreement(f.points, f.labels, f.image_labels, T, f.calibration.K))
    return total
