"""Paths the vehicle follows (rows and streets with turns) and its poses on the terrain."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from calib.synth.terrain import Terrain

__all__ = ["Path", "vehicle_poses"]


class Path:
    """A planar centreline sampled densely, parametrised by arc length ``s``.

    Args:
        points: ``(M, 2)`` samples, closely spaced.
    """

    def __init__(self, points: np.ndarray):
        self.points = np.asarray(points, dtype=np.float64)
        seg = np.diff(self.points, axis=0)
        self.s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(seg, axis=1))])
        heading = np.arctan2(seg[:, 1], seg[:, 0])
        self.heading = np.unwrap(np.concatenate([heading, heading[-1:]]))
        self._tree = cKDTree(self.points)

    @staticmethod
    def from_segments(
        start: tuple[float, float], heading: float, segments: list[tuple[float, float]], step: float = 0.1
    ) -> Path:
        """Chain straights and circular arcs.

        Args:
            segments: ``(length_m, turn_rad)`` pairs; ``turn_rad = 0`` is a straight, otherwise an
                arc turning left (positive) or right (negative) over ``length_m``.
        """
        points = [np.asarray(start, dtype=np.float64)]
        psi = heading
        for length, turn in segments:
            n = max(int(np.ceil(length / step)), 1)
            for _ in range(n):
                psi_mid = psi + 0.5 * turn / n
                points.append(points[-1] + (length / n) * np.array([np.cos(psi_mid), np.sin(psi_mid)]))
                psi += turn / n
        return Path(np.stack(points))

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def at(self, s: np.ndarray, lateral: np.ndarray | float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Position ``(..., 2)`` at arc length ``s``, ``lateral`` metres to the left, and heading."""
        s = np.clip(s, 0.0, self.length)
        xy = np.stack([np.interp(s, self.s, self.points[:, i]) for i in (0, 1)], -1)
        psi = np.interp(s, self.s, self.heading)
        left = np.stack([-np.sin(psi), np.cos(psi)], -1)
        return xy + np.asarray(lateral)[..., None] * left, psi

    def distance(self, xy: np.ndarray) -> np.ndarray:
        """Distance from each ``(..., 2)`` point to the centreline (to the nearest sample)."""
        d, _ = self._tree.query(np.asarray(xy).reshape(-1, 2))
        return d.reshape(np.shape(xy)[:-1])


def vehicle_poses(terrain: Terrain, xy: np.ndarray, heading: np.ndarray, height: float) -> np.ndarray:
    """Poses ``T_world_sensor`` of a sensor ``height`` metres above a vehicle standing on the terrain.

    The body's z axis is the terrain normal (the vehicle rolls and pitches with the ground), its x
    axis the heading projected onto the ground plane, y = z × x (x forward, y left, z up).

    Args:
        xy: ``(N, 2)`` ground positions. heading: ``(N,)`` yaw in radians.

    Returns:
        ``(N, 4, 4)``.
    """
    grad = terrain.gradient(xy[:, 0], xy[:, 1])
    z_axis = np.column_stack([-grad, np.ones(len(xy))])
    z_axis /= np.linalg.norm(z_axis, axis=1, keepdims=True)
    forward = np.column_stack([np.cos(heading), np.sin(heading), np.zeros(len(xy))])
    x_axis = forward - np.einsum("ij,ij->i", forward, z_axis)[:, None] * z_axis
    x_axis /= np.linalg.norm(x_axis, axis=1, keepdims=True)
    y_axis = np.cross(z_axis, x_axis)
    T = np.tile(np.eye(4), (len(xy), 1, 1))
    T[:, :3, :3] = np.stack([x_axis, y_axis, z_axis], -1)
    ground = np.column_stack([xy, terrain.height(xy[:, 0], xy[:, 1])])
    T[:, :3, 3] = ground + height * z_axis
    return T
