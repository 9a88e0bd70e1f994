import numpy as np
import pytest

from calib.init.lidar_odometry import drift, lidar_odometry, sensor_range
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import load_synth_config


def _line(n, step):
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3] = step * np.arange(n)
    return T


def test_drift_known_answers():
    ref = _line(11, 1.0)
    assert drift(ref, ref)["drift_percent"] == pytest.approx(0.0)
    result = drift(_line(11, 1.1), ref)  # 10% too long a step
    assert result["path_m"] == pytest.approx(10.0)
    assert result["end_error_m"] == pytest.approx(1.0) and result["drift_percent"] == pytest.approx(10.0)
    moved = ref.copy()
    moved[:, :3, 3] += [5.0, 1.0, 0.0]  # another origin: drift is taken relative to the first pose
    assert drift(moved, ref)["end_error_m"] == pytest.approx(0.0)


def test_kiss_icp_follows_the_synthetic_street():
    synth = Synthesizer(load_synth_config("urban", small=True), 12, seed=4)
    scans = [item.frame.points for item in synth.frames(workers=2)]
    result = drift(lidar_odometry(scans, max_range_m=60.0, voxel_size_m=0.6), synth.lidar_poses())
    assert result["path_m"] > 8.0
    assert result["drift_percent"] < 5.0 and result["rotation_drift_deg"] < 1.0


def test_sensor_range_is_a_high_percentile_rounded_up():
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(1000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    scan = directions * np.linspace(1.0, 20.0, 1000)[:, None]  # ranges 1 … 20 m
    assert sensor_range([scan], percentile=50.0) == 11.0  # 10.5 m rounded up
    assert sensor_range([scan[:500], scan[500:]]) == 20.0
    with pytest.raises(ValueError, match="no points"):
        sensor_range([np.zeros((0, 3))])
