"""The synthetic worlds render at real pixel scale by default (urban: KITTI's colour camera 02,
vineyard: BLT's ZED2 at half resolution); ``small=True`` keeps the old 624x188 camera for speed,
without the camera effects."""

import numpy as np
import pytest

from calib.data.label_agreement import sequence_label_agreement
from calib.projection import project_scan
from calib.synth.generate import RIGID_CLASSES, Synthesizer
from calib.synth.synth_config import SMALL_CAMERA, CameraEffectsConfig, load_synth_config

FULL = {
    "urban": {"width": 1242, "height": 375, "fx": 721.5, "fy": 721.5, "cx": 609.6, "cy": 172.9},
    "vineyard": {"width": 960, "height": 540, "fx": 527.0, "fy": 527.0, "cx": 479.5, "cy": 269.5},
}
STILL = {"wind": {"amplitude_m": 0.0}, "timing": {"camera_offset_s": 0.0}}


@pytest.mark.parametrize("world", ["urban", "vineyard"])
def test_the_default_camera_is_full_resolution(world):
    assert load_synth_config(world).camera.model_dump() == FULL[world]


@pytest.mark.parametrize("world", ["urban", "vineyard"])
def test_small_gives_the_old_camera_without_effects_and_leaves_the_rest(world):
    small, full = load_synth_config(world, small=True), load_synth_config(world)
    assert small.camera.model_dump() == SMALL_CAMERA
    assert small.camera_effects == CameraEffectsConfig() != full.camera_effects
    assert not small.timing.motion_distortion
    assert full.timing.motion_distortion == (world == "urban")  # KITTI's scans are not de-skewed
    assert small.lidar.laser_angle_std_deg == 0.0 < full.lidar.laser_angle_std_deg
    assert small.lidar.laser_gain_range_std == 0.0 < full.lidar.laser_gain_range_std
    exclude = {
        "camera": True,
        "camera_effects": True,
        "timing": {"motion_distortion"},
        "lidar": {"laser_angle_std_deg", "laser_gain_range_std"},
    }
    assert small.model_dump(exclude=exclude) == full.model_dump(exclude=exclude)
    blurred = load_synth_config(world, small=True, camera_effects={"blur_px": 0.5})
    assert blurred.camera_effects.blur_px == 0.5


def test_a_camera_override_wins_over_small():
    config = load_synth_config("urban", small=True, camera={"width": 320}, wind={"amplitude_m": 0.0})
    assert config.camera.model_dump() == {**SMALL_CAMERA, "width": 320}
    assert config.wind.amplitude_m == 0.0


@pytest.mark.parametrize("world", ["urban", "vineyard"])
def test_one_full_resolution_frame_is_consistent_with_its_intrinsics(world):
    """The image has the configured size and the reference extrinsic with the written K puts the
    LiDAR points inside it, across its width, on pixels of their own class."""
    config = load_synth_config(world, **STILL)
    frame = Synthesizer(config, 1, seed=5).render(0).frame
    camera = config.camera
    assert frame.image.shape == (camera.height, camera.width, 3)
    assert frame.image_labels.shape == (camera.height, camera.width)
    np.testing.assert_allclose(frame.K, camera.K)
    scan = project_scan(frame.points, frame.calibration.T_cam_lidar, frame.K, frame.image.shape[:2], None)
    assert len(scan.index) > 5000
    assert np.ptp(scan.uv[:, 0]) > 0.9 * camera.width  # the scan spans the view from edge to edge
    assert sequence_label_agreement([frame]).rate(RIGID_CLASSES) >= 0.95
