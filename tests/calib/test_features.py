import numpy as np
import pytest

from calib.features import depth_discontinuities, horizontal_gradient, ring_spacing_deg


def _ring(elevation_deg: float, ranges: np.ndarray, azimuth_deg: np.ndarray) -> np.ndarray:
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    return np.column_stack(
        [
            ranges * np.cos(el) * np.cos(az),
            ranges * np.cos(el) * np.sin(az),
            ranges * np.sin(el),
            np.zeros_like(ranges),
        ]
    )


def _pole_scene(elevation_deg=0.0):
    """One scan line: a wall at 10 m, a pole at 4 m over azimuth [-1°, 1°], a lone return at 5 m."""
    azimuth = np.arange(-30.0, 30.0, 0.2)
    ranges = np.full(len(azimuth), 10.0)
    pole = np.abs(azimuth) <= 1.0
    ranges[pole] = 4.0
    leaf = int(np.argmin(np.abs(azimuth - 15.0)))
    ranges[leaf] = 5.0
    return _ring(elevation_deg, ranges, azimuth), np.nonzero(pole)[0], leaf


def test_pole_in_front_of_wall_known_answer():
    points, pole, leaf = _pole_scene()
    nearer, farther = depth_discontinuities(points)
    assert sorted(nearer.tolist()) == [pole[0], pole[-1]]
    assert sorted(farther.tolist()) == [pole[0] - 1, pole[-1] + 1]
    assert leaf not in nearer, "an isolated return has no surface beside it"


def test_ring_sorting_recovers_an_unordered_scan():
    lower, pole_lo, _ = _pole_scene(-2.0)
    upper, pole_up, _ = _pole_scene(0.0)
    points = np.vstack([lower, upper])
    ring = np.repeat([0, 1], len(lower))
    shuffle = np.random.default_rng(0).permutation(len(points))
    nearer, _ = depth_discontinuities(points[shuffle], ring[shuffle])
    expected = {pole_lo[0], pole_lo[-1], len(lower) + pole_up[0], len(lower) + pole_up[-1]}
    assert set(shuffle[nearer].tolist()) == expected
    # without rings the shuffled order has no scan-line neighbours: nothing is found
    assert len(depth_discontinuities(points[shuffle])[0]) == 0


def test_horizontal_gradient_sees_vertical_edges_only():
    image = np.zeros((40, 60, 3), np.uint8)
    image[:, 30:] = 200  # vertical edge at column 30
    image[20:, :] += 50  # horizontal edge at row 20
    g = horizontal_gradient(image, reference_width=60)
    assert g.shape == (40, 60) and g.max() <= 1.0
    assert g[10, 29:31].max() > 0.9
    assert g[19:21, 5].max() < 0.05


def _rings(spacing_deg: float, count: int) -> np.ndarray:
    """A spinning LiDAR's scan of a 10 m cylinder around it: ``count`` rings ``spacing_deg`` apart."""
    azimuth, elevation = np.meshgrid(
        np.radians(np.arange(-180, 180, 0.2)), np.radians(-20 + spacing_deg * np.arange(count))
    )
    return np.column_stack(
        [10 * np.cos(azimuth).ravel(), 10 * np.sin(azimuth).ravel(), 10 * np.tan(elevation).ravel()]
    )


def test_ring_spacing_known_answers():
    assert ring_spacing_deg(_rings(0.4, 64)) == pytest.approx(0.4, abs=0.01)  # KITTI's HDL-64
    assert ring_spacing_deg(_rings(1.33, 32)) == pytest.approx(1.33, abs=0.01)  # nuScenes' HDL-32
    assert ring_spacing_deg(_rings(1.0, 1)) == 0.0
