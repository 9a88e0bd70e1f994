"""A world: static geometry built once, plus what moves (foliage in the wind, driving cars), and
the drive of the ego vehicle through it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from calib.synth.drive_path import Path, vehicle_poses
from calib.synth.raycast import Mesh
from calib.synth.synth_config import DriveConfig, WindConfig
from calib.synth.terrain import Terrain

__all__ = ["Drive", "Foliage", "Mover", "World"]


@dataclass(frozen=True)
class Foliage:
    """Leaves that sway in the wind, each moving rigidly.

    Attributes:
        mesh: rest geometry; every leaf owns the same number of consecutive vertices.
        anchor: ``(L, 3)`` leaf centres at rest (they set the gust's phase).
        sway: ``(L,)`` in ``[0, 1]``: how freely a leaf moves (0 at the cordon or trunk, 1 at the tip).
        phase: ``(L, 2)`` random flutter phases.
    """

    mesh: Mesh
    anchor: np.ndarray
    sway: np.ndarray
    phase: np.ndarray

    @staticmethod
    def concat(parts: list[Foliage]) -> Foliage:
        return Foliage(
            Mesh.concat([p.mesh for p in parts]),
            np.concatenate([p.anchor for p in parts]) if parts else np.zeros((0, 3)),
            np.concatenate([p.sway for p in parts]) if parts else np.zeros(0),
            np.concatenate([p.phase for p in parts]) if parts else np.zeros((0, 2)),
        )

    def displacement(self, t: float, wind: WindConfig) -> np.ndarray:
        """``(L, 3)`` leaf displacement at time ``t``: a gust wave travelling downwind (smooth
        in time and space) plus faster per-leaf flutter, scaled by each leaf's freedom."""
        if wind.amplitude_m == 0 or not len(self.anchor):
            return np.zeros_like(self.anchor)
        heading = np.radians(wind.direction_deg)
        downwind = np.array([np.cos(heading), np.sin(heading), 0.0])
        w = 2 * np.pi * wind.frequency_hz
        gust = np.sin(w * (t - self.anchor @ downwind / wind.gust_speed_mps))
        flutter = np.sin(2.7 * w * t + self.phase[:, 0])
        lift = np.sin(3.3 * w * t + self.phase[:, 1])
        d = (0.7 * gust + 0.3 * flutter)[:, None] * downwind + 0.3 * lift[:, None] * np.array([0, 0, 1.0])
        return wind.amplitude_m * self.sway[:, None] * d

    def at(self, t: float, wind: WindConfig) -> Mesh:
        """The leaves as they are at time ``t``."""
        m = self.mesh
        offset = np.repeat(self.displacement(t, wind), len(m.vertices) // max(len(self.anchor), 1), axis=0)
        return Mesh(m.vertices + offset, m.faces, m.material, m.label, m.instance)


@dataclass(frozen=True)
class Mover:
    """A rigid object driving along a path: ``pose(t)`` places its own-frame mesh in the world."""

    mesh: Mesh
    pose: Callable[[float], np.ndarray]

    def at(self, t: float) -> Mesh:
        return self.mesh.transformed(self.pose(t))


@dataclass(frozen=True)
class Drive:
    """The ego vehicle's motion: along ``path`` at constant speed from ``start_s``, weaving
    laterally, standing on the terrain (which rolls and pitches it)."""

    path: Path
    terrain: Terrain
    start_s: float
    config: DriveConfig

    def lidar_poses(self, t: np.ndarray) -> np.ndarray:
        """``(N, 4, 4)`` poses ``T_world_lidar`` at times ``t (N,)`` (seconds from the start)."""
        c = self.config
        t = np.asarray(t, dtype=np.float64)
        s = self.start_s + c.speed_mps * t
        w = 2 * np.pi / c.wobble_period_s
        lateral = c.lane_offset_m + c.wobble_m * np.sin(w * t)
        xy, heading = self.path.at(s, lateral)
        # Heading follows the weave: d(lateral)/ds = wobble·w·cos(w t) / speed
        heading = heading + np.arctan(c.wobble_m * w * np.cos(w * t) / c.speed_mps)
        return vehicle_poses(self.terrain, xy, heading, c.sensor_height_m)


@dataclass(frozen=True)
class World:
    """Everything a frame renders.

    Attributes:
        name: ``vineyard`` or ``urban``.
        static: geometry that never moves, built into one Embree scene per sequence.
        foliage: leaves that sway. movers: cars that drive.
        drive: the ego vehicle's motion.
        classes: class id → name of every class the world uses.
    """

    name: str
    static: Mesh
    foliage: Foliage
    drive: Drive
    classes: dict[int, str]
    movers: list[Mover] = field(default_factory=list)

    def dynamic(self, t: float, wind: WindConfig) -> Mesh:
        """The moving geometry at time ``t``."""
        return Mesh.concat([self.foliage.at(t, wind)] + [m.at(t) for m in self.movers])
