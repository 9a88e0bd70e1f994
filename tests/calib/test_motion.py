import numpy as np
import pytest
import torch

from calib.geometry import se3_exp
from calib.motion import ScanMotion, motions_from_poses, sweep_times, twist_spread


def driving(speed: float = 8.0, yaw_rate: float = 0.3) -> np.ndarray:
    """A body twist: forward along the LiDAR's x at ``speed`` m/s, turning at ``yaw_rate`` rad/s."""
    return np.array([speed, 0.0, 0.0, 0.0, 0.0, yaw_rate])


def test_still_motion_changes_nothing():
    points = np.random.default_rng(0).normal(size=(50, 3))
    still = ScanMotion.still()
    assert not still.before.any() and not still.after.any()
    np.testing.assert_array_equal(still.at(points, 0.02), points)
    np.testing.assert_allclose(still.deskew(points, np.linspace(-0.05, 0.05, 50)), points)


def test_pose_follows_the_geodesic_on_each_side_of_the_stamp():
    motion = ScanMotion(driving(4.0, -0.2), driving(8.0, 0.3))
    for t, twist in ((-0.03, motion.before), (0.05, motion.after)):
        expected = se3_exp(torch.as_tensor(t * twist)).numpy()
        np.testing.assert_allclose(motion.pose(t), expected, atol=1e-12)
    assert motion.pose(np.zeros((4, 2))).shape == (4, 2, 4, 4)  # broadcasts over any shape of times


def test_a_point_moved_to_its_own_time_is_where_it_was_measured():
    """Deskewing to the stamp and moving back to each point's time is the identity."""
    rng = np.random.default_rng(1)
    points, times = rng.uniform(-20, 20, (200, 3)), rng.uniform(-0.05, 0.1, 200)
    motion = ScanMotion(driving(6.0, -0.1), driving(9.0, 0.4))
    stamp = motion.deskew(points, times)
    back = np.stack([motion.at(q[None], t)[0] for q, t in zip(stamp, times, strict=True)])
    np.testing.assert_allclose(back, points, atol=1e-9)


def test_known_answer_a_static_point_seen_from_a_car_driving_straight():
    """At 10 m/s a point 20 m ahead is 19.8 m ahead 20 ms later."""
    motion = ScanMotion(driving(10.0, 0.0), driving(10.0, 0.0))
    np.testing.assert_allclose(motion.at(np.array([[20.0, 1.0, 0.5]]), 0.02), [[19.8, 1.0, 0.5]], atol=1e-12)


def test_time_derivative_is_minus_the_twist_applied_to_the_point():
    """``dp(t)/dt = −(ω × p + v)``, as the solver's δt Jacobian column assumes; finite differences."""
    motion = ScanMotion(driving(7.0, 0.2), np.array([9.0, 0.3, -0.1, 0.02, -0.03, 0.5]))
    q = np.random.default_rng(2).uniform(-30, 30, (20, 3))
    for t in (-0.02, 0.013):
        h = 1e-6
        numeric = (motion.at(q, t + h) - motion.at(q, t - h)) / (2 * h)
        twist = motion.twist(t)
        p = motion.at(q, t)
        np.testing.assert_allclose(numeric, -(np.cross(twist[3:], p) + twist[:3]), rtol=1e-6, atol=1e-6)


def test_motions_from_poses_recover_the_twists_of_a_piecewise_geodesic_trajectory():
    twists = [driving(5.0, 0.1), driving(8.0, -0.3), driving(6.0, 0.2)]
    stamps = np.array([0.0, 0.1, 0.2, 0.3])
    poses = [np.eye(4)]
    for twist, dt in zip(twists, np.diff(stamps), strict=True):
        poses.append(poses[-1] @ se3_exp(torch.as_tensor(dt * twist)).numpy())
    motions = motions_from_poses(np.stack(poses), stamps)
    assert len(motions) == 4
    np.testing.assert_allclose(motions[1].before, twists[0], atol=1e-9)
    np.testing.assert_allclose(motions[1].after, twists[1], atol=1e-9)
    np.testing.assert_allclose(motions[0].before, twists[0], atol=1e-9)  # the ends repeat their neighbour
    np.testing.assert_allclose(motions[3].after, twists[2], atol=1e-9)


def test_bad_inputs_are_refused_with_the_reason():
    with pytest.raises(ValueError, match="finite"):
        ScanMotion(np.zeros(5), np.zeros(6))
    with pytest.raises(ValueError, match="F >= 2"):
        motions_from_poses(np.eye(4)[None], np.zeros(1))
    with pytest.raises(ValueError, match="increase"):
        motions_from_poses(np.stack([np.eye(4)] * 3), np.array([0.0, 0.1, 0.1]))


def test_twist_spread_known_answer():
    """Two scans at 6 and 10 m/s, one turning at 0.2 rad/s: 2 m/s and 0.1 rad/s from the means."""
    motions = [
        ScanMotion(driving(6.0, 0.0), driving(6.0, 0.0)),
        ScanMotion(driving(10.0, 0.2), driving(10.0, 0.2)),
    ]
    assert twist_spread(motions) == pytest.approx((2.0, 0.1))
    assert twist_spread([ScanMotion(driving(8.0, 0.3), driving(8.0, 0.3))] * 4) == (0.0, 0.0)


def test_sweep_times_from_the_azimuth_equal_the_synthetic_lidars_recorded_times():
    """The synthetic LiDAR turns clockwise and faces forward at the stamp, as KITTI's HDL-64."""
    from calib.synth.generate import Synthesizer
    from calib.synth.synth_config import load_synth_config

    config = load_synth_config("urban", small=True, timing={"motion_distortion": True})
    frame = Synthesizer(config, 1, seed=3).render(0).frame
    times = sweep_times(frame.points, config.timing.lidar_period_s, clockwise=True)
    assert frame.point_times is not None and len(times) == len(frame.point_times)
    half_step = 0.5 * config.lidar.azimuth_step_deg / 360 * config.timing.lidar_period_s
    wrapped = np.abs(times - frame.point_times) % config.timing.lidar_period_s  # ±π is one instant
    assert np.minimum(wrapped, config.timing.lidar_period_s - wrapped).max() < half_step + 1e-6


def test_sweep_times_known_answers():
    ahead, left, behind = [10.0, 0, 0], [0, 10.0, 0], [-10.0, 0.001, 0]
    points = np.array([ahead, left, behind])
    np.testing.assert_allclose(sweep_times(points, 0.1, clockwise=True), [0.0, -0.025, -0.05], atol=1e-5)
    np.testing.assert_allclose(sweep_times(points, 0.1, clockwise=False), [0.0, 0.025, 0.05], atol=1e-5)
    np.testing.assert_allclose(sweep_times(points, 0.1, stamp_azimuth_deg=90.0)[1], 0.0, atol=1e-12)
