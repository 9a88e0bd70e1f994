"""Configuration of a synthetic sequence, validated (``extra="forbid"``: a typo in YAML fails)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, PositiveFloat

from calib.errors import ConfigError
from calib.synth.sensors import CameraConfig, LidarConfig
from calib.yaml_io import DEFAULTS, read_yaml, validate

__all__ = ["SMALL_CAMERA", "CameraEffectsConfig", "SynthConfig", "load_synth_config"]

SMALL_CAMERA = {"width": 624, "height": 188, "fx": 360.8, "fy": 360.8, "cx": 304.8, "cy": 86.4}
"""The small camera (KITTI's colour camera at about half resolution) that ``small=True`` and
``supportnet synth --small`` render with instead of the world's full-resolution one: 4-4.4x
fewer pixels (2-3x faster to render), for fast tests and the demo; the shipped models were
trained on it."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class TimingConfig(_Strict):
    """When each sensor samples the world."""

    rate_hz: float = Field(10.0, gt=0, le=1000)
    camera_offset_s: float = Field(0.0, ge=-10, le=10, description="camera stamp minus LiDAR stamp")
    camera_offset_drift_s: float = Field(
        0.0,
        ge=-10,
        le=10,
        description="a drifting clock: the offset changes by this much from the first frame to the last",
    )
    lidar_period_s: float = Field(0.1, gt=0, le=10, description="one LiDAR revolution")
    motion_distortion: bool = Field(False, description="cast each beam from the pose at its own time")


class WindConfig(_Strict):
    """Foliage sway: a gust wave travelling downwind plus per-leaf flutter."""

    amplitude_m: float = Field(0.0, ge=0, description="sway at the top of the canopy")
    frequency_hz: float = Field(0.8, gt=0)
    direction_deg: float = 30.0
    gust_speed_mps: float = Field(4.0, gt=0)


class LightConfig(_Strict):
    sun_elevation_deg: float = Field(45.0, gt=0, le=90)
    sun_azimuth_deg: float = 135.0
    sun: float = Field(1.0, ge=0)
    ambient: float = Field(0.35, ge=0)
    image_noise: float = Field(0.008, ge=0, description="std of additive noise, linear units")


class CameraEffectsConfig(_Strict):
    """What a real camera does to the scene's light before the image reaches the matcher (see
    :mod:`calib.synth.camera_effects`). The defaults do nothing: every effect at zero strength
    leaves the rendered bytes as they were without this group."""

    blur_px: float = Field(0.0, ge=0, le=10, description="lens blur (defocus, optics), Gaussian σ in pixels")
    vignetting: float = Field(
        0.0, ge=0, lt=1, description="light lost at the image corners (corner gain 1 − vignetting)"
    )
    exposure_std_stops: float = Field(
        0.0, ge=0, le=3, description="std of the per-frame exposure error, in stops (log2 of the gain)"
    )
    shot_noise: float = Field(
        0.0, ge=0, le=0.1, description="photon noise: variance per unit of linear signal (std √(k · x))"
    )
    jpeg_quality: int | None = Field(
        None, ge=1, le=100, description="JPEG-compress the 8-bit image at this quality; null: no compression"
    )


class ExtrinsicConfig(_Strict):
    """Camera mounting: a nominal pose and a seeded per-sequence deviation from it."""

    camera_position_m: tuple[float, float, float] = Field(
        (0.27, 0.06, -0.08), description="camera centre in the LiDAR frame (x fwd, y left, z up)"
    )
    camera_pitch_deg: float = Field(0.0, gt=-90, lt=90, description="downward tilt of the optical axis")
    jitter_cm: float = Field(3.0, ge=0)
    jitter_deg: float = Field(1.0, ge=0)


class TerrainConfig(_Strict):
    """Rolling ground: slopes of about 2π · amplitude / wavelength radians roll and pitch the vehicle."""

    amplitude_m: float = Field(0.5, ge=0)
    wavelength_m: float = Field(22.0, gt=1)


class DriveConfig(_Strict):
    speed_mps: float = Field(1.2, gt=0)
    sensor_height_m: float = Field(1.4, gt=0, description="LiDAR above the ground")
    lane_offset_m: float = Field(0.0, description="to the left of the path centreline")
    wobble_m: float = Field(0.08, ge=0, description="lateral weave amplitude")
    wobble_period_s: float = Field(10.0, gt=0)
    start_before_turn_m: float = Field(8.0, ge=0)


class VineyardLayout(_Strict):
    row_spacing_m: float = Field(2.4, gt=1)
    row_length_m: float = Field(30.0, gt=5)
    headland_m: float = Field(6.0, gt=2)
    plant_spacing_m: float = Field(1.2, gt=0.3)
    post_spacing_m: float = Field(6.0, gt=1)
    cordon_height_m: float = Field(0.9, gt=0.2)
    canopy_top_m: float = Field(1.9, gt=0.5)
    wire_heights_m: tuple[PositiveFloat, ...] = (0.9, 1.3, 1.7)
    pipe_height_m: float = Field(0.4, gt=0)
    leaves_per_shoot: int = Field(14, ge=0)
    leaf_size_m: float = Field(0.12, gt=0)


class UrbanLayout(_Strict):
    lane_width_m: float = Field(3.5, gt=2)
    parking_width_m: float = Field(2.4, ge=0)
    sidewalk_width_m: float = Field(3.0, gt=0.5)
    kerb_height_m: float = Field(0.12, ge=0)
    block_length_m: tuple[PositiveFloat, PositiveFloat] = (50.0, 90.0)
    turn_radius_m: float = Field(11.0, gt=3)
    building_height_m: tuple[PositiveFloat, PositiveFloat] = (6.0, 20.0)
    parked_car_fraction: float = Field(0.5, ge=0, le=1)
    moving_cars: int = Field(6, ge=0)
    moving_speed_mps: tuple[PositiveFloat, PositiveFloat] = (6.0, 11.0)
    tree_spacing_m: float = Field(14.0, gt=2)


class SynthConfig(_Strict):
    """Everything that defines a synthetic sequence, besides the seed and the frame count."""

    world: Literal["vineyard", "urban"]
    camera: CameraConfig = CameraConfig()
    lidar: LidarConfig = LidarConfig()
    timing: TimingConfig = TimingConfig()
    wind: WindConfig = WindConfig()
    light: LightConfig = LightConfig()
    camera_effects: CameraEffectsConfig = CameraEffectsConfig()
    extrinsic: ExtrinsicConfig = ExtrinsicConfig()
    drive: DriveConfig = DriveConfig()
    terrain: TerrainConfig = TerrainConfig()
    vineyard: VineyardLayout = VineyardLayout()
    urban: UrbanLayout = UrbanLayout()


CONFIG_DIR = DEFAULTS / "synth"


def load_synth_config(
    world: str | None = None, path: Path | None = None, small: bool = False, **overrides
) -> SynthConfig:
    """Read ``configs/synth/<world>.yaml`` (or ``path``) and validate it.

    The packaged worlds render at real pixel scale: urban at KITTI's 1242x375 (f = 721.5), the
    vineyard at the BLT ZED2's half resolution 960x540 (f = 527).

    Args:
        small: render with :data:`SMALL_CAMERA` (624x188) instead of the file's camera, and
            without the file's ``camera_effects``, scan motion distortion, laser angle errors and
            range-dependent laser gains (the shipped models were trained on clean small frames,
            the fast tests pin the matcher's accuracy on them, and the effects' strengths are
            tuned at real pixel scale); applied before ``overrides``, so an override still wins.
        overrides: top-level groups to replace, as dicts merged over the file's (e.g.
            ``wind={"amplitude_m": 0}``).

    Raises:
        DataError: the file is missing, does not parse, or does not validate.
    """
    if path is None:
        if world is None:
            raise ValueError("give a world or a config path")
        path = CONFIG_DIR / f"{world}.yaml"
    path = Path(path)
    data = read_yaml(path)
    if world is not None and data.setdefault("world", world) != world:
        raise ConfigError(path, f"describes world {data['world']!r}, not {world!r}")
    if small:
        data["camera"] = dict(SMALL_CAMERA)
        data.pop("camera_effects", None)
        data["timing"] = {**data.get("timing", {}), "motion_distortion": False}
        data["lidar"] = {**data.get("lidar", {}), "laser_angle_std_deg": 0.0, "laser_gain_range_std": 0.0}
    for key, value in overrides.items():
        data[key] = {**data.get(key, {}), **value}
    return validate(SynthConfig, data, path)
