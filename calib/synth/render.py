"""The two sensors sampling a world: a shaded camera image with per-pixel classes, and a LiDAR
scan with intensities, labels and drop-outs."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.synth.camera_effects import compress, expose
from calib.synth.materials import sky, surface, to_srgb
from calib.synth.raycast import Hits, Raycaster
from calib.synth.sensors import CameraConfig, LidarConfig, beam_directions, camera_rays, lidar_rays
from calib.synth.synth_config import CameraEffectsConfig, LightConfig

__all__ = ["Camera", "Lidar", "LidarScan", "sun_direction"]


def sun_direction(light: LightConfig) -> np.ndarray:
    """Unit vector towards the sun in the world frame (z up)."""
    el, az = np.radians(light.sun_elevation_deg), np.radians(light.sun_azimuth_deg)
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


class Camera:
    """Renders what a pinhole camera sees: sun and sky light, cast shadows, then the camera's own
    effects (blur, vignetting, exposure, noise, JPEG; :mod:`calib.synth.camera_effects`)."""

    def __init__(
        self,
        config: CameraConfig,
        light: LightConfig,
        effects: CameraEffectsConfig,
        seed: int = 0,
    ):
        self.config, self.light, self.seed, self.effects = config, light, seed, effects
        self._rays = camera_rays(config)
        self._sun = sun_direction(light)

    def render(
        self,
        caster: Raycaster,
        T_world_cam: np.ndarray,
        rng: np.random.Generator,
        effects_rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Returns ``image (H, W, 3)`` uint8 RGB and ``labels (H, W)`` uint16 class per pixel
        (0 where the ray escapes to the sky).

        Args:
            rng: the frame's generator, shared with the LiDAR (draws the read noise).
            effects_rng: a generator of the camera effects alone, so switching an effect on or
                off leaves the scan and the rest of the image as they were.
        """
        H, W = self.config.height, self.config.width
        directions = self._rays @ T_world_cam[:3, :3].T
        origin = T_world_cam[:3, 3]
        hits = caster.cast(origin, directions)
        hit = hits.hit
        rgb = np.empty((len(directions), 3), np.float32)
        rgb[~hit] = sky(directions[~hit], self._sun, self.seed)
        points = origin + directions[hit] * hits.t[hit, None]
        normal = hits.normal[hit]
        color, _ = surface(hits.material[hit], points, normal, hits.instance[hit], self.seed)
        cos_sun = normal @ self._sun
        facing = cos_sun > 0
        lit = np.zeros(len(points), bool)
        lit[facing] = ~caster.occluded(points[facing] + 0.01 * normal[facing], self._sun)
        sky_light = self.light.ambient * (0.75 + 0.25 * normal[:, 2])
        rgb[hit] = color * (sky_light + self.light.sun * np.where(lit, cos_sun, 0.0))[:, None]
        rgb = expose(rgb.reshape(H, W, 3), self.effects, effects_rng)
        # read noise, after the exposure gain: a dark frame's contrast drowns in it
        rgb += rng.normal(0.0, self.light.image_noise, rgb.shape).astype(np.float32)
        return compress(to_srgb(rgb), self.effects.jpeg_quality), hits.label.reshape(H, W)


@dataclass(frozen=True)
class LidarScan:
    """One revolution as a KITTI scan.

    Attributes:
        points: ``(N, 4)`` float32 ``x, y, z, intensity`` in the LiDAR frame (at each point's time).
        labels: ``(N,)`` uint16 class. instance: ``(N,)`` uint16.
        times: ``(N,)`` seconds relative to the scan stamp (0 when the beam points forward).
    """

    points: np.ndarray
    labels: np.ndarray
    instance: np.ndarray
    times: np.ndarray


class Lidar:
    """A spinning multi-beam LiDAR: range noise, intensity from reflectance and incidence angle,
    weak returns dropped."""

    def __init__(self, config: LidarConfig, period_s: float, seed: int = 0):
        self.config, self.period_s, self.seed = config, period_s, seed
        self.directions, self.ring, azimuth = lidar_rays(config)
        rig = np.random.default_rng(seed)  # the rig's own errors, the same in every scan
        self.gain = np.exp(rig.normal(0.0, config.laser_gain_std, config.beams))  # each laser's intensity
        # each laser's elevation and azimuth error, zero-mean so the extrinsic stays the truth: the
        # beams are cast along the true directions, the points reported along the nominal ones
        error = np.radians(rig.normal(0.0, config.laser_angle_std_deg, (2, config.beams)))
        error -= error.mean(axis=1, keepdims=True)
        self.angle_error_deg = np.degrees(error)  # (2, beams): elevation, azimuth (the truth)
        elevation = np.arcsin(np.clip(self.directions[:, 2], -1, 1)) + error[0, self.ring]
        self.cast_directions = beam_directions(elevation, azimuth + error[1, self.ring])
        # each laser's gain changes with range too, (r / 10 m)^α (drawn last: the rig's other
        # properties stay those of the same seed without it)
        self.gain_exponent = rig.normal(0.0, config.laser_gain_range_std, config.beams)
        self.azimuth_steps = len(self.directions) // config.beams
        # The sweep turns from +π to -π and passes forward (azimuth 0) at the scan's stamp
        self.times = -azimuth / (2 * np.pi) * period_s

    def _cast(self, caster: Raycaster, origins: np.ndarray, directions: np.ndarray) -> Hits:
        """Each beam's return: one ray, or with ``beam_divergence_deg`` seven across its spot (its
        centre and a hexagon at the radius that halves a uniform spot's area), grouped by the
        surface (class and instance) each hits; the beam returns the group whose hits bring back
        the most energy (count over range²) if at least two rays hit it, at their mean range."""
        if self.config.beam_divergence_deg <= 0:
            return caster.cast(origins, directions)
        radius = np.radians(self.config.beam_divergence_deg) / 2 / np.sqrt(2)
        across = np.cross(directions, [0.0, 0.0, 1.0])
        across /= np.maximum(np.linalg.norm(across, axis=1, keepdims=True), 1e-12)
        down = np.cross(directions, across)
        angles = np.arange(6) * np.pi / 3
        spot = radius * np.concatenate([[[0.0, 0.0]], np.column_stack([np.cos(angles), np.sin(angles)])])
        rays = directions[:, None] + spot[:, :1] * across[:, None] + spot[:, 1:] * down[:, None]
        rays /= np.linalg.norm(rays, axis=2, keepdims=True)
        n, s = rays.shape[:2]
        sub = caster.cast(np.repeat(origins, s, axis=0), rays.reshape(-1, 3))
        hit = sub.hit.reshape(n, s)
        t = np.where(hit, sub.t.reshape(n, s), 0.0)
        surface_id = (sub.label.astype(np.int64) << 16 | sub.instance).reshape(n, s)
        same = (surface_id[:, :, None] == surface_id[:, None, :]) & hit[:, None, :]  # (beam, ray, ray)
        energy = (same / np.where(hit, t, 1.0)[:, None, :] ** 2).sum(2)
        energy = np.where(hit & (same.sum(2) >= 2), energy, -1.0)
        beam = np.arange(n)
        best = energy.argmax(1)  # ties: the centre ray first
        returned = energy[beam, best] > 0
        members = same[beam, best]
        mean_t = (members * t).sum(1) / np.maximum(members.sum(1), 1)
        pick = beam * s + best
        return Hits(
            np.where(returned, mean_t, np.inf),
            sub.normal[pick],
            np.where(returned, sub.material[pick], 255).astype(np.uint8),
            np.where(returned, sub.label[pick], 0).astype(np.uint16),
            np.where(returned, sub.instance[pick], 0).astype(np.uint16),
        )

    def scan(self, caster: Raycaster, T_world_lidar: np.ndarray, rng: np.random.Generator) -> LidarScan:
        """Cast every beam.

        Args:
            T_world_lidar: ``(4, 4)`` pose, or ``(A, 4, 4)`` one per azimuth step (motion distortion).
        """
        T = T_world_lidar if T_world_lidar.ndim == 3 else T_world_lidar[None]
        column = np.tile(np.arange(self.azimuth_steps), self.config.beams) % len(T)
        directions = np.einsum("nij,nj->ni", T[column, :3, :3], self.cast_directions)
        origins = T[column, :3, 3]
        hits = self._cast(caster, origins, directions)
        r = hits.t + rng.normal(0.0, self.config.range_noise_m, len(directions))
        valid = hits.hit & (r < self.config.max_range_m) & (r > 0.5)
        points = origins[valid] + directions[valid] * hits.t[valid, None]
        _, reflectance = surface(
            hits.material[valid], points, hits.normal[valid], hits.instance[valid], self.seed, color=False
        )
        incidence = -np.einsum("ij,ij->i", hits.normal[valid], directions[valid])
        ring = self.ring[valid]
        gain = self.gain[ring] * (r[valid] / 10.0) ** self.gain_exponent[ring]
        intensity = np.clip(reflectance * incidence * gain + rng.normal(0, 0.01, valid.sum()), 0, 1)
        # Weak returns (dark, grazing or far) are lost: keep-probability rises with the signal
        signal = intensity * np.minimum(1.0, (25.0 / r[valid]) ** 2)
        keep = rng.uniform(0, 1, len(signal)) < np.clip((signal - 0.004) / 0.02, 0, 1)
        index = np.flatnonzero(valid)[keep]
        xyz = self.directions[index] * r[index, None]
        return LidarScan(
            np.column_stack([xyz, intensity[keep]]).astype(np.float32),
            hits.label[index],
            hits.instance[index],
            self.times[index],
        )
