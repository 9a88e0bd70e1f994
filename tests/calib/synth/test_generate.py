import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from calib.data import open_dataset
from calib.data.label_agreement import sequence_label_agreement
from calib.errors import DataError
from calib.features import level_laser_gains, ring_stripes, scan_lines
from calib.geometry import calibration_error, perturb
from calib.synth.generate import RIGID_CLASSES, Synthesizer, reference_extrinsic, write_sequence
from calib.synth.raycast import Mesh, Raycaster
from calib.synth.render import Lidar
from calib.synth.sensors import LidarConfig
from calib.synth.shapes import boxes
from calib.synth.synth_config import ExtrinsicConfig, load_synth_config

SMALL = {
    "camera": {"width": 312, "height": 94, "fx": 180.4, "fy": 180.4, "cx": 152.4, "cy": 43.2},
    "lidar": {"beams": 32, "azimuth_step_deg": 0.4},
}


def small(world, **overrides):
    return load_synth_config(world, **{**SMALL, **overrides})


def test_reference_extrinsic_varies_by_seed_within_the_jitter():
    config = ExtrinsicConfig()
    nominal = reference_extrinsic(ExtrinsicConfig(jitter_cm=0, jitter_deg=0), np.random.default_rng(0))
    np.testing.assert_allclose(np.linalg.inv(nominal)[:3, 3], config.camera_position_m, atol=1e-12)
    errors = [
        calibration_error(nominal, reference_extrinsic(config, np.random.default_rng(s))) for s in range(5)
    ]
    for e in errors:
        assert 0.5 * 3.0 - 1e-6 <= float(e.translation_cm) <= 3.0 + 1e-6
        assert 0.5 - 1e-6 <= float(e.rotation_deg) <= 1.0 + 1e-6
    assert len({round(float(e.translation_cm), 6) for e in errors}) == 5


def test_unknown_key_in_a_world_config_fails_loudly(tmp_path):
    bad = tmp_path / "w.yaml"
    bad.write_text("world: vineyard\nwind: {amplitud_m: 0.1}\n")
    with pytest.raises(DataError, match="wind.amplitud_m"):
        load_synth_config(path=bad)
    with pytest.raises(DataError, match="not 'urban'"):
        load_synth_config("urban", bad)


@pytest.mark.parametrize("world", ["vineyard", "urban"])
def test_ground_truth_labels_agree_at_a_still_moment(world):
    synth = Synthesizer(small(world, wind={"amplitude_m": 0.0}, timing={"camera_offset_s": 0.0}), 3, seed=5)
    frames = [item.frame for item in synth.frames()]
    total = sequence_label_agreement(frames)
    assert total.rate(RIGID_CLASSES) >= 0.95
    # A wrong extrinsic (2° off) breaks the agreement: the check can fail
    wrong = perturb(synth.T_cam_lidar, 0.0, 2.0, torch.Generator().manual_seed(0))
    off = sequence_label_agreement(frames, wrong)
    assert off.rate(RIGID_CLASSES) < total.rate(RIGID_CLASSES) - 0.05


@pytest.mark.parametrize("world", ["vineyard", "urban"])
def test_each_laser_has_its_own_intensity_gain_and_levelling_finds_it(world):
    """Real lasers answer one surface differently (KITTI: 14 % between rings); the synthetic
    LiDAR's gains are a property of the rig, and levelling recovers them from one scan."""

    def implied_gains(std):
        lidar = {**SMALL["lidar"], "laser_gain_std": std, "laser_gain_range_std": 0.0}
        synth = Synthesizer(small(world, lidar=lidar), 1, seed=4)
        points = synth.render(0).frame.points
        line = scan_lines(points)
        assert line is not None and line.max() + 1 == 32  # every laser returns in these worlds
        levelled = level_laser_gains(points)
        ratio = points[:, 3] / np.maximum(levelled[:, 3], 1e-9)
        return np.log([np.median(ratio[line == k]) for k in range(32)]), np.log(synth.lidar.gain)

    implied, true = implied_gains(0.2)
    assert np.std(true) > 0.1 and np.corrcoef(implied, true)[0, 1] > 0.9
    implied, true = implied_gains(0.0)
    np.testing.assert_array_equal(true, 0.0)
    assert np.std(implied) < 0.05


@pytest.mark.parametrize("world", ["vineyard", "urban"])
def test_range_dependent_laser_gains_leave_stripes_that_levelling_cannot_remove(world):
    """A gain that changes with range differently for each laser (real intensity curves) stays
    striped along the scan lines once one gain per laser is levelled; without it the levelled
    scan is not (``ring_stripes`` near 1), and the small worlds leave it out."""

    def stripes(std):
        lidar = {**SMALL["lidar"], "laser_gain_range_std": std}
        return ring_stripes(Synthesizer(small(world, lidar=lidar), 1, seed=4).render(0).frame.points)

    assert stripes(0.0) < 1.2
    assert stripes(0.3) > stripes(0.0) + 0.3
    assert load_synth_config(world, small=True).lidar.laser_gain_range_std == 0.0
    assert load_synth_config(world).lidar.laser_gain_range_std > 0


def test_laser_angle_errors_belong_to_the_rig_and_leave_the_extrinsic_true():
    """Each laser is cast off its nominal beam by a fixed elevation and azimuth error (the
    points are reported along the nominal beams); zero-mean over the lasers, the same each scan."""
    config = LidarConfig(beams=32, azimuth_step_deg=0.4, laser_angle_std_deg=0.2)
    lidar, again = Lidar(config, 0.1, seed=3), Lidar(config, 0.1, seed=3)
    np.testing.assert_array_equal(lidar.cast_directions, again.cast_directions)
    elevation = np.degrees(np.arcsin(lidar.cast_directions[:, 2]) - np.arcsin(lidar.directions[:, 2]))
    per_laser = elevation.reshape(32, -1)
    np.testing.assert_allclose(per_laser, np.repeat(per_laser[:, :1], per_laser.shape[1], 1), atol=1e-6)
    assert abs(per_laser[:, 0].mean()) < 1e-6 and 0.1 < per_laser[:, 0].std() < 0.3
    ideal = Lidar(LidarConfig(beams=32, azimuth_step_deg=0.4, laser_angle_std_deg=0.0), 0.1, seed=3)
    np.testing.assert_allclose(ideal.cast_directions, ideal.directions, atol=1e-12)


def test_beam_divergence_reaches_past_a_silhouette_by_part_of_the_spot():
    """A pole 10 m ahead of a wall at 30 m: one ray per beam returns the pole only within its
    silhouette; a 0.4° spot returns it up to half the hexagon's radius beyond (two of its seven
    rays on the pole bring back more energy than five on the wall), never farther."""
    pole = Mesh.of(boxes(np.array([[10.0, 0, 0]]), np.array([[0.2, 0.5, 10]])), 1, 80, 1)
    wall = Mesh.of(boxes(np.array([[30.0, 0, 0]]), np.array([[0.2, 40, 20]])), 1, 50, 2)
    caster = Raycaster([pole, wall])
    silhouette = np.degrees(np.arctan2(0.25, 9.9))
    beyond = []
    for divergence in (0.0, 0.4):
        config = LidarConfig(
            beams=8, elevation_max_deg=2, elevation_min_deg=-2, azimuth_step_deg=0.01,
            laser_gain_std=0, laser_angle_std_deg=0, range_noise_m=0, beam_divergence_deg=divergence,
        )  # fmt: skip
        scan = Lidar(config, 0.1, seed=0).scan(caster, np.eye(4), np.random.default_rng(0))
        on_pole = scan.points[scan.labels == 80]
        azimuth = np.degrees(np.abs(np.arctan2(on_pole[:, 1], on_pole[:, 0])))
        ahead = np.linalg.norm(on_pole[:, :3], axis=1) * np.cos(np.radians(azimuth))
        np.testing.assert_allclose(ahead, 9.9, atol=0.01)  # the pole's range, along the beam's centre
        beyond.append(azimuth.max() - silhouette)
    reach = np.degrees(np.radians(0.4) / 2 / np.sqrt(2)) / 2  # half the hexagon's radius: 0.07°
    assert beyond[0] <= 0.01
    assert reach - 0.02 <= beyond[1] <= reach + 0.01


def test_wind_and_time_offset_lower_foliage_agreement():
    rates = []
    for amplitude, offset in ((0.0, 0.0), (0.3, 0.1)):
        synth = Synthesizer(
            small("vineyard", wind={"amplitude_m": amplitude}, timing={"camera_offset_s": offset}), 2, seed=2
        )
        rates.append(sequence_label_agreement(item.frame for item in synth.frames()).rate({70}))
    assert rates[1] < rates[0] - 0.02


def _digest(folder: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            h.update(p.relative_to(folder).as_posix().encode())
            h.update(p.read_bytes())
    return h.hexdigest()


def test_same_seed_same_bytes_and_the_reader_gets_the_ground_truth(tmp_path):
    config = small("urban", timing={"motion_distortion": True})
    a = write_sequence(Synthesizer(config, 3, seed=9), tmp_path / "a", "04", workers=2)
    b = write_sequence(Synthesizer(config, 3, seed=9), tmp_path / "b", "04", workers=1)
    assert _digest(a) == _digest(b)
    c = write_sequence(Synthesizer(config, 3, seed=10), tmp_path / "c", "04")
    assert _digest(a) != _digest(c)
    seq = open_dataset(tmp_path / "a", sequence="04")
    meta = json.loads((a / "meta.json").read_text())
    np.testing.assert_allclose(seq.calibration.T_cam_lidar, meta["T_cam_lidar"], atol=1e-9)
    np.testing.assert_allclose(seq.poses, Synthesizer(config, 3, seed=9).lidar_poses(), atol=1e-9)
    frame = seq.frame(1)
    assert frame.image.shape == (94, 312, 3) and frame.image_labels.shape == (94, 312)
    assert set(np.unique(frame.labels)) <= set(int(k) for k in meta["classes"])
    period = config.timing.lidar_period_s
    assert frame.point_times.min() >= -period / 2 - 1e-6 and frame.point_times.max() <= period / 2 + 1e-6
    assert np.diff(seq.timestamps) == pytest.approx(np.full(2, 0.1))
    instances = np.fromfile(a / "labels" / "000001.label", np.uint32) >> 16
    assert instances.max() > 0  # instance ids in the upper 16 bits


def test_independent_checker_accepts_a_default_sequence(tmp_path):
    checker = Path(__file__).resolve().parents[4] / "shared" / "checks" / "check_synth.py"
    if not checker.is_file():
        pytest.skip("the shared checker is not present on this machine")
    seq = write_sequence(
        Synthesizer(load_synth_config("vineyard", small=True), 3, seed=1), tmp_path, "00", workers=2
    )
    result = subprocess.run([sys.executable, str(checker), str(seq), "0.90"], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
