import numpy as np
import pytest

from calib.laser_angles import LaserAngles, high_pass, laser_angle_errors

HEIGHT_M = 1.73  # the LiDAR above a flat ground


def _room_scan(error_deg: np.ndarray, lasers: int = 48, step_deg: float = 0.1) -> np.ndarray:
    """A scan stored ring by ring (rings 0.42° apart from +2°, top first): vertical walls at a
    horizontal distance ``12 + 4 cos 2a`` (oblique to the rays almost everywhere) and a flat
    ground 1.73 m below; each laser cast along its nominal direction turned by its errors
    ``error_deg (2, lasers)`` (elevation, azimuth), its returns reported along the nominal one."""
    elevation, azimuth = np.meshgrid(
        np.radians(2.0 - 0.42 * np.arange(lasers)), np.radians(np.arange(-180, 180, step_deg)), indexing="ij"
    )
    true_el = elevation + np.radians(error_deg[0])[:, None]
    true_az = azimuth + np.radians(error_deg[1])[:, None]
    wall = (12 + 4 * np.cos(2 * true_az)) / np.cos(true_el)
    ground = np.where(true_el < 0, HEIGHT_M / np.sin(-np.minimum(true_el, -1e-9)), np.inf)
    r = np.minimum(wall, ground)
    return np.column_stack(
        [
            (r * np.cos(elevation) * np.cos(azimuth)).ravel(),
            (r * np.cos(elevation) * np.sin(azimuth)).ravel(),
            (r * np.sin(elevation)).ravel(),
            np.full(r.size, 0.3),
        ]
    )


def _errors(seed: int, std_deg: float = 0.12, lasers: int = 48) -> np.ndarray:
    error = np.random.default_rng(seed).normal(0.0, std_deg, (2, lasers))
    return error - error.mean(axis=1, keepdims=True)


def test_recovers_known_laser_angle_errors():
    error = _errors(0)
    found = laser_angle_errors(_room_scan(error))
    assert isinstance(found, LaserAngles)
    lasers = error.shape[1]
    assert found.line_elevation_deg.shape == found.elevation_deg.shape == (lasers,)
    assert found.azimuth_step_deg.shape == (lasers - 1,)
    np.testing.assert_allclose(found.line_elevation_deg, 2.0 - 0.42 * np.arange(lasers), atol=0.02)
    # elevation: the lines that meet the ground, up to their common part (the plane takes it)
    seen = np.isfinite(found.elevation_deg)
    assert seen.sum() >= 20
    assert not seen[:8].any()  # the upper lines meet only the walls
    # ... and up to what the plane's fitted height cannot tell apart: a constant and a term in tan θ
    basis = np.column_stack([np.ones(seen.sum()), np.tan(-np.radians(found.line_elevation_deg[seen]))])
    truth = error[0, seen] - basis @ np.linalg.lstsq(basis, error[0, seen], rcond=None)[0]
    np.testing.assert_allclose(found.elevation_deg[seen], truth, atol=0.01)
    # azimuth: each line's error less the one above it, where both meet the walls
    steps = np.isfinite(found.azimuth_step_deg)
    assert steps.sum() >= 10
    np.testing.assert_allclose(found.azimuth_step_deg[steps], np.diff(error[1])[steps], atol=0.01)


def test_ideal_lasers_read_zero():
    found = laser_angle_errors(_room_scan(np.zeros((2, 48))))
    assert np.nanmax(np.abs(found.elevation_deg - np.nanmean(found.elevation_deg))) < 0.005
    assert np.nanmax(np.abs(found.azimuth_step_deg)) < 0.005


def test_scans_not_stored_line_by_line_are_refused():
    points = _room_scan(_errors(1, lasers=16), lasers=16, step_deg=0.4)
    assert laser_angle_errors(points) is not None
    assert laser_angle_errors(points[np.random.default_rng(0).permutation(len(points))]) is None


def test_high_pass_keeps_what_changes_from_line_to_line():
    trend = np.linspace(-0.3, 0.3, 40)  # a road's slow shape over the lines
    spikes = np.zeros(40)
    spikes[[5, 17, 30]] = [0.1, -0.08, 0.12]
    out = high_pass(np.stack([trend + spikes, trend]))
    assert out.shape == (2, 40)
    np.testing.assert_allclose(out[0, [5, 17, 30]], [0.1, -0.08, 0.12], atol=0.02)
    assert np.abs(out[1]).max() < 1e-9
    with_gap = trend + spikes
    with_gap[3] = np.nan
    assert np.isnan(high_pass(with_gap)[3])


@pytest.mark.parametrize("columns", [3, 4])
def test_reads_scans_with_or_without_intensity(columns):
    points = _room_scan(_errors(2))[:, :columns]
    assert laser_angle_errors(points) is not None
