"""Sensor models of the synthetic worlds: the rays a pinhole camera and a spinning LiDAR cast.

Frames: the LiDAR frame is x forward, y left, z up; the camera frame is x right, y down,
z forward (DESIGN.md). Rays are unit directions in the sensor's own frame.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = ["CameraConfig", "LidarConfig", "camera_rays", "lidar_rays"]


class CameraConfig(BaseModel):
    """Pinhole camera; the defaults are KITTI's colour camera at half resolution."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    width: int = Field(624, gt=0, le=8192)
    height: int = Field(188, gt=0, le=8192)
    fx: float = Field(360.8, gt=0)
    fy: float = Field(360.8, gt=0)
    cx: float = 304.8
    cy: float = 86.4

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


class LidarConfig(BaseModel):
    """Spinning multi-beam LiDAR; the defaults are a 64-beam HDL-64E-like pattern."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    beams: int = Field(64, gt=0, le=1024)
    elevation_max_deg: float = Field(2.0, ge=-90, le=90)
    elevation_min_deg: float = Field(-24.9, ge=-90, le=90)
    azimuth_step_deg: float = Field(0.2, ge=0.01, le=10)
    range_noise_m: float = Field(0.01, ge=0)
    max_range_m: float = Field(120.0, gt=0)
    laser_gain_std: float = Field(
        0.12,
        ge=0,
        le=1,
        description="std of each laser's log intensity gain, fixed per rig: real scanners' lasers "
        "answer one surface differently (KITTI's HDL-64: 0.14), which draws intensity edges "
        "along the scan lines",
    )
    laser_gain_range_std: float = Field(
        0.0,
        ge=0,
        le=2,
        description="std of each laser's exponent α in a gain that also varies with range, "
        "(r / 10 m)^α, fixed per rig: real lasers' intensity curves differ with range and "
        "brightness, so levelling one gain per laser leaves stripes along the scan lines "
        "(calib.features.ring_stripes: KITTI's HDL-64 1.2-1.4, PJLab 1.7-2.2; 0.15 gives the "
        "urban world 1.3, as KITTI raw, and the vineyard 1.7; 0: about 1.1)",
    )
    laser_angle_std_deg: float = Field(
        0.12,
        ge=0,
        le=2,
        description="std of each laser's elevation and azimuth error, fixed per rig and zero-mean "
        "over the lasers: the points are reported along the nominal beams but measured along the "
        "true ones, as a factory calibration leaves them (KITTI's HDL-64 shows 0.024° in elevation "
        "and under 0.01° in azimuth in its own scans, bench_laser_angles: the urban world's 0.025; "
        "the vineyard keeps 0.12, which brings the matcher's error there within 1.5x of real "
        "KITTI's, bench_realism)",
    )

    beam_divergence_deg: float = Field(
        0.0,
        ge=0,
        le=2,
        description="full angle of each beam's spot: a beam that grazes an object's edge is cast as "
        "seven rays across its spot and returns the surface most of its energy comes back from "
        "(hits over range²), at least two of the seven, reported along its centre, so objects "
        "reach past their silhouettes by about a sixth of the spot's angle, as real returns do "
        "(a Velodyne HDL-64's spot: about 0.1°); 0: one ray",
    )

    @model_validator(mode="after")
    def _elevations_ordered(self) -> LidarConfig:
        if self.elevation_min_deg >= self.elevation_max_deg:
            raise ValueError("elevation_min_deg must be below elevation_max_deg")
        return self


def camera_rays(camera: CameraConfig) -> np.ndarray:
    """Unit rays through every pixel centre, row-major.

    Returns:
        ``(H * W, 3)`` float64 directions in the camera frame; pixel ``(u, v)`` is row
        ``v * W + u``.
    """
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], -1)
    rays = rays.reshape(-1, 3)
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def lidar_rays(lidar: LidarConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Beam directions of one revolution, stored ring by ring (as KITTI scans are).

    Returns:
        ``directions (B * A, 3)`` unit vectors in the LiDAR frame, ``ring (B * A,)`` beam index
        from the top beam down, and ``azimuth (B * A,)`` in radians, sweeping from +π to -π
        (clockwise seen from above, as a Velodyne turns: azimuth falls with time).
    """
    elevation = np.radians(np.linspace(lidar.elevation_max_deg, lidar.elevation_min_deg, lidar.beams))
    steps = int(round(360.0 / lidar.azimuth_step_deg))
    azimuth = np.pi - np.arange(steps) * (2 * np.pi / steps)
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")
    ring = np.repeat(np.arange(lidar.beams), steps)
    return beam_directions(el.reshape(-1), az.reshape(-1)), ring, az.reshape(-1)


def beam_directions(elevation: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """``(N, 3)`` unit vectors in the LiDAR frame (x forward, z up) at ``elevation (N,)`` and
    ``azimuth (N,)`` radians."""
    return np.stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], -1
    )
