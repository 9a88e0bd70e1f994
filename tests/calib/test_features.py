import numpy as np
import pytest

from calib.features import (
    depth_discontinuities,
    horizontal_gradient,
    level_laser_gains,
    ring_spacing_deg,
    ring_spacing_profile,
    ring_stripes,
    scan_lines,
)


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


def test_missing_returns_between_neighbours_hide_no_contour():
    """Missing returns stored in place, as (0, 0, 0) or at a beam's origin 3 cm off the centre,
    beside the pole and within the wall: the same contours, at the returns' own indices (before,
    a zero beside the pole broke the pole's edge from its wall, and a zero is no contour)."""
    points, pole, leaf = _pole_scene()
    zeros = np.array(
        [40, pole[0] - 1, pole[-1] + 1]
    )  # mid-wall, before the pole's first return, after its last
    stored = np.insert(points, zeros, 0.0, axis=0)
    stored[zeros[2] + 2, :3] = [0.03, 0.0, 0.01]  # each insertion moves the later ones by one
    kept = np.flatnonzero(np.linalg.norm(stored[:, :3], axis=1) > 0.05)
    nearer, farther = depth_discontinuities(stored)
    expected_nearer, expected_farther = depth_discontinuities(points)
    assert sorted(nearer.tolist()) == sorted(kept[expected_nearer].tolist())
    assert sorted(farther.tolist()) == sorted(kept[expected_farther].tolist())
    assert len(nearer) == 2


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


def test_ring_spacing_profile_follows_uneven_rings():
    """A Pandar64-like scan: rings 1° apart below -6° and 0.17° apart above; the profile reads each
    spacing where it holds, and the median would read 0.17° everywhere."""
    elevation = np.concatenate([-15 + 1.0 * np.arange(9), -6 + 0.167 * np.arange(48)])
    azimuth, elevation = np.meshgrid(np.radians(np.arange(-180, 180, 0.2)), np.radians(elevation))
    points = np.column_stack(
        [10 * np.cos(azimuth).ravel(), 10 * np.sin(azimuth).ravel(), 10 * np.tan(elevation).ravel()]
    )
    rings = ring_spacing_profile(points)
    np.testing.assert_allclose(
        rings.at(np.array([-12.0, -9.0, -3.0, 1.0])), [1.0, 1.0, 0.167, 0.167], atol=0.01
    )
    assert ring_spacing_deg(points) == pytest.approx(0.167, abs=0.01)
    assert len(ring_spacing_profile(_rings(1.0, 1)).elevation_deg) == 0
    assert ring_spacing_profile(_rings(1.0, 1)).at(3.0) == 0.0


def _striped_scan(gains: np.ndarray, azimuth_step_deg: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """A scan stored ring by ring (rings 0.4° apart, top first, azimuth from -180°): a room whose
    range and reflectance vary smoothly, each ring's intensity scaled by its laser's gain.
    Returns the points and the reflectance before the gains."""
    count = len(gains)
    elevation, azimuth = np.meshgrid(
        np.radians(2.0 - 0.4 * np.arange(count)),
        np.radians(np.arange(-180, 180, azimuth_step_deg)),
        indexing="ij",
    )
    ranges = 12 + 4 * np.cos(2 * azimuth)
    reflectance = 0.3 + 0.1 * np.sin(3 * azimuth) + 0.05 * np.cos(7 * azimuth) * np.sin(elevation * 20)
    points = np.column_stack(
        [
            (ranges * np.cos(elevation) * np.cos(azimuth)).ravel(),
            (ranges * np.cos(elevation) * np.sin(azimuth)).ravel(),
            (ranges * np.sin(elevation)).ravel(),
            (reflectance * gains[:, None]).ravel(),
        ]
    )
    return points, reflectance.ravel()


def test_scan_lines_known_answer():
    points, _ = _striped_scan(np.ones(32))
    expected = np.repeat(np.arange(32), len(points) // 32)
    np.testing.assert_array_equal(scan_lines(points), expected)
    front = np.abs(np.degrees(np.arctan2(points[:, 1], points[:, 0]))) < 45  # cropped to a camera's view
    np.testing.assert_array_equal(scan_lines(points[front]), expected[front])
    # a gap of missing returns (open sky) jumps forward and does not start a line
    gap = (np.degrees(np.arctan2(points[:, 1], points[:, 0])) % 60) > 20
    np.testing.assert_array_equal(scan_lines(points[gap]), expected[gap])


def test_missing_returns_stored_as_zeros_change_no_line_and_no_ring():
    """Organised clouds (Ouster's drivers, many converters) keep a missing return in its place as
    (0, 0, 0), or at its beam's origin a few centimetres off the centre. A fifth of the returns so
    stored, and the scan moved by 5 mm (a deskew, or the points moved to the camera's time): the
    same 32 lines and ring spacing as the scan without them, each zero in the line of the return
    stored before it (before, every zero's azimuth about the moved centre started a line, and the
    split was refused)."""
    points, _ = _striped_scan(np.ones(32))
    expected = np.repeat(np.arange(32), len(points) // 32)
    missing = np.random.default_rng(2).random(len(points)) < 0.2
    missing[0] = False
    stored = points.copy()
    stored[missing, :3] = 0.0
    stored[missing & (np.arange(len(points)) % 2 == 0), :3] = [0.03, 0.0, 0.01]  # beam origins
    stored[:, :3] += [0.004, -0.003, 0.002]
    measured = np.flatnonzero(~missing)
    before = measured[np.searchsorted(measured, np.arange(len(points)), side="right") - 1]
    np.testing.assert_array_equal(scan_lines(stored), expected[before])
    assert (expected[before] != expected).sum() < 32  # only zeros that open a line move
    assert ring_spacing_deg(stored) == pytest.approx(0.4, abs=0.01)
    assert ring_spacing_profile(stored).at(0.0) == pytest.approx(0.4, abs=0.01)


def test_scan_lines_refuses_other_orders():
    points, _ = _striped_scan(np.ones(32))
    assert scan_lines(points[np.random.default_rng(0).permutation(len(points))]) is None
    assert scan_lines(points[: 4 * len(points) // 32]) is None  # fewer than 8 lines
    by_azimuth = np.lexsort((np.arange(len(points)) // 1800, np.tile(np.arange(1800), 32)))
    assert scan_lines(points[by_azimuth]) is None  # stored per firing, as some drivers do


def test_level_laser_gains_recovers_the_reflectance():
    gains = np.exp(np.random.default_rng(1).normal(0.0, 0.15, 32))
    points, reflectance = _striped_scan(gains)
    levelled = level_laser_gains(points)
    ratio = levelled[:, 3] / reflectance
    # one gain is left for the scan, and a trend over the lasers (taken for the incidence angle)
    k = np.arange(len(points)) // (len(points) // 32)
    trend = np.polyval(np.polyfit(np.arange(32), np.log(gains), 1), k)
    assert np.std(np.log(ratio) - trend) < 0.005
    np.testing.assert_array_equal(levelled[:, :3], points[:, :3].astype(np.float32))


def test_level_laser_gains_keeps_scans_it_cannot_split():
    points, _ = _striped_scan(np.exp(np.random.default_rng(2).normal(0.0, 0.15, 32)))
    shuffled = points[np.random.default_rng(0).permutation(len(points))]
    np.testing.assert_array_equal(level_laser_gains(shuffled), shuffled.astype(np.float32))
    np.testing.assert_array_equal(level_laser_gains(points[:, :3]), points[:, :3].astype(np.float32))


def _noisy(points: np.ndarray, seed: int = 3) -> np.ndarray:
    """``points`` with 2 % multiplicative noise on the intensity (a return's own scatter)."""
    noisy = points.copy()
    noisy[:, 3] *= np.exp(np.random.default_rng(seed).normal(0.0, 0.02, len(points)))
    return noisy


def test_ring_stripes_near_one_where_the_lasers_differ_by_a_gain_alone():
    points, _ = _striped_scan(np.exp(np.random.default_rng(1).normal(0.0, 0.15, 32)))
    assert 0.9 < ring_stripes(_noisy(points)) < 1.2


def test_ring_stripes_sees_gains_that_vary_with_range():
    """A gain per laser that also changes with range (``(r / 12)^α``, ``α`` per laser) cannot be
    levelled by one factor per laser: stripes stay, and the ratio rises far above 1."""
    points, _ = _striped_scan(np.exp(np.random.default_rng(1).normal(0.0, 0.15, 32)))
    laser = np.arange(len(points)) // (len(points) // 32)
    alpha = np.random.default_rng(2).normal(0.0, 1.0, 32)
    striped = points.copy()
    striped[:, 3] *= (np.linalg.norm(points[:, :3], axis=1) / 12.0) ** alpha[laser]
    assert ring_stripes(_noisy(striped)) > 2 * ring_stripes(_noisy(points))


def test_ring_stripes_none_where_lines_or_intensity_are_missing():
    points, _ = _striped_scan(np.ones(32))
    assert ring_stripes(points[np.random.default_rng(0).permutation(len(points))]) is None
    assert ring_stripes(points[:, :3]) is None
