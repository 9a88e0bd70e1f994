"""benchmarks/bench_laser_angles.py's arithmetic: the lasers' spread from scans of different
places, and lining up scans whose first line is partial."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_laser_angles  # noqa: E402

from calib.laser_angles import LaserAngles  # noqa: E402


def test_spread_is_the_part_scans_of_different_places_share():
    rng = np.random.default_rng(0)
    lasers = rng.normal(0.0, 0.03, 400)  # the rig's, in every scan
    scans = [lasers + rng.normal(0.0, 0.05, 400) for _ in range(4)]  # each with its own scene
    spread, pairs = bench_laser_angles.spread(scans, ["a", "a", "b", "c"])
    assert pairs == 5  # the two scans of place a are not compared
    assert abs(spread - 0.03) < 0.006
    # scans of one place share their scene too: compared, they would read it as the lasers'
    same_scene = [scans[0], scans[0] + rng.normal(0.0, 0.005, 400)]
    assert np.isnan(bench_laser_angles.spread(same_scene, ["a", "a"])[0])
    assert bench_laser_angles.spread(same_scene, ["a", "b"])[0] > 0.05


def test_aligned_shifts_a_scan_that_starts_with_a_partial_line():
    elevation = 2.0 - 0.42 * np.arange(12)
    errors = np.linspace(-0.1, 0.1, 12) ** 3 * 50  # a shape the high-pass keeps in part
    steps = np.arange(11) * 0.01
    full = LaserAngles(elevation, errors, steps)
    # the same lasers behind an extra partial line at 3.9°
    extra = LaserAngles(np.r_[3.9, elevation], np.r_[np.nan, errors], np.r_[np.nan, steps])
    el, st, width = bench_laser_angles.aligned([full, extra])
    assert width == 13  # the lines of the scan with the most: the full scan moves one line down
    assert np.isnan(el[0][0]) and np.isnan(st[0][0])
    np.testing.assert_allclose(el[0][1:], el[1][1:], atol=0.05)
    np.testing.assert_allclose(st[0][1:], st[1][1:])
