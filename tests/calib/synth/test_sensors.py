import numpy as np
import pytest
import torch
from pydantic import ValidationError

from calib.features import depth_discontinuities
from calib.projection import project_points
from calib.synth.sensors import CameraConfig, LidarConfig, camera_rays, lidar_rays


def test_camera_rays_project_back_to_their_pixels():
    camera = CameraConfig(width=40, height=30)
    rays = camera_rays(camera)
    assert rays.shape == (1200, 3)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0)
    uv, _ = project_points(torch.as_tensor(rays * 7.0), torch.as_tensor(camera.K))
    v, u = np.divmod(np.arange(1200), 40)
    np.testing.assert_allclose(uv.numpy(), np.column_stack([u, v]), atol=1e-9)


def test_lidar_pattern_matches_the_configuration():
    lidar = LidarConfig()
    directions, ring, azimuth = lidar_rays(lidar)
    assert directions.shape == (64 * 1800, 3) and ring.shape == azimuth.shape == (64 * 1800,)
    elevation = np.degrees(np.arcsin(directions[:, 2]))
    assert elevation.max() == pytest.approx(2.0) and elevation.min() == pytest.approx(-24.9)
    assert np.all(np.diff(ring) >= 0), "stored ring by ring"
    step = np.degrees(np.abs(np.diff(azimuth[ring == 0])))
    np.testing.assert_allclose(step, 0.2)


def test_ring_order_gives_scan_line_neighbours():
    """Scans written in this order are what depth_discontinuities expects without rings."""
    lidar = LidarConfig(beams=4, elevation_max_deg=-1.0, elevation_min_deg=-4.0)
    directions, ring, _ = lidar_rays(lidar)
    ranges = np.full(len(directions), 10.0)
    ranges[(np.abs(directions[:, 1]) < 0.02) & (directions[:, 0] > 0)] = 4.0  # a thin pole straight ahead
    points = directions * ranges[:, None]
    nearer, _ = depth_discontinuities(points)
    assert len(nearer) == 2 * 4, "both silhouette edges of the pole on every ring"
    np.testing.assert_array_equal(np.sort(depth_discontinuities(points, ring)[0]), np.sort(nearer))


def test_configs_reject_typos_and_bad_values():
    with pytest.raises(ValidationError, match="beems"):
        LidarConfig(beems=32)
    with pytest.raises(ValidationError, match="elevation_min_deg must be below"):
        LidarConfig(elevation_min_deg=5.0)
    with pytest.raises(ValidationError):
        CameraConfig(width=0)
