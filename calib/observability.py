"""What an estimate's covariance says it could not pin down: the principal directions of its
translation and rotation blocks whose standard deviation passes a threshold, in the LiDAR frame.
Stage 1 reports them for the motion, Stage 4 for the correspondences."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["WeakDirection", "weak_directions"]

AXES = ("x", "y", "z")


@dataclass(frozen=True)
class WeakDirection:
    """A direction of the extrinsic the data hardly constrains.

    Attributes:
        kind: ``translation`` or ``rotation``.
        std: its standard deviation (cm or degrees).
        direction_lidar: unit ``(3,)`` in the LiDAR frame (for a rotation: the axis).
        axis: the LiDAR axis it is closest to (``+z``), or ``""`` when none within 25°.
    """

    kind: str
    std: float
    direction_lidar: np.ndarray
    axis: str

    def __str__(self) -> str:
        unit = "cm" if self.kind == "translation" else "°"
        where = f"LiDAR {self.axis}" if self.axis else f"LiDAR direction {np.round(self.direction_lidar, 2)}"
        return f"{self.kind} along {where} (std {self.std:.2f} {unit})"

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "std": self.std,
            "direction_lidar": self.direction_lidar.tolist(),
            "axis": self.axis,
            "text": str(self),
        }


def weak_directions(
    cov_translation: np.ndarray,
    cov_rotation: np.ndarray,
    R_cam_lidar: np.ndarray,
    limit_cm: float,
    limit_deg: float,
) -> list[WeakDirection]:
    """Principal directions of each ``(3, 3)`` block (metres², radians², camera frame) whose std
    exceeds ``limit_cm`` / ``limit_deg``, expressed in the LiDAR frame through ``R_cam_lidar``,
    largest first within each kind."""
    weak = []
    for kind, block, scale, limit in (
        ("rotation", cov_rotation, np.degrees(1.0), limit_deg),
        ("translation", cov_translation, 100.0, limit_cm),
    ):
        values, vectors = np.linalg.eigh(np.asarray(block, np.float64))
        for value, vector in sorted(zip(values, vectors.T, strict=True), key=lambda p: -p[0]):
            std = float(np.sqrt(max(value, 0.0)) * scale)
            if std > limit:
                lidar = R_cam_lidar.T @ vector  # camera-frame direction into the LiDAR frame
                lidar = lidar * np.sign(lidar[np.argmax(np.abs(lidar))])
                best = int(np.argmax(np.abs(lidar)))
                axis = f"+{AXES[best]}" if abs(lidar[best]) > np.cos(np.radians(25)) else ""
                weak.append(WeakDirection(kind, std, lidar, axis))
    return weak
