import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from calib.geometry import se3_exp
from calib.init.time_sync import interpolate_poses, stamp_offset

R_CAM_LIDAR = Rotation.from_euler("xyz", [-90, 0, -90], degrees=True).as_matrix()


def drive(turning: bool, seconds: float = 12.0, rate: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """LiDAR stamps and poses of a car at 8 m/s that (``turning``) swings its yaw rate between
    ±0.5 rad/s every few seconds, else drives straight."""
    times = np.arange(0, seconds, 1 / rate)
    poses = [np.eye(4)]
    for t in times[1:]:
        yaw_rate = 0.5 * np.sin(2 * np.pi * t / 4.0) if turning else 0.0
        poses.append(poses[-1] @ se3_exp(torch.tensor([8.0, 0, 0, 0, 0, yaw_rate]) / rate).numpy())
    return times, np.stack(poses)


def camera_motions(times, poses, lag_s, step=3):
    """Keyframe pairs ``i → i + step`` as the camera saw them (its rotation is the LiDAR's, seen
    through the mount), stamped ``lag_s`` later than the LiDAR's clock."""
    pairs = np.array([[times[i], times[i + step]] for i in range(2, len(times) - step - 2, step)])
    at, _ = interpolate_poses(times, poses, pairs.ravel(), 1.0)
    at = at.reshape(-1, 2, 4, 4)
    lidar = np.linalg.inv(at[:, 1, :3, :3]) @ at[:, 0, :3, :3]
    return pairs + lag_s, R_CAM_LIDAR @ lidar @ R_CAM_LIDAR.T


def test_a_30ms_stamp_lag_is_found_from_turns_without_the_extrinsic():
    times, poses = drive(turning=True)
    stamps, rotations = camera_motions(times, poses, 0.030)
    found = stamp_offset(times, poses, stamps, rotations)
    assert found.offset_s == pytest.approx(0.030, abs=0.002)
    assert found.std_s < 0.005 and found.pairs >= 30


def test_a_straight_drive_cannot_tell_the_lag():
    times, poses = drive(turning=False)
    stamps, rotations = camera_motions(times, poses, 0.030)
    assert stamp_offset(times, poses, stamps, rotations).std_s == np.inf


def test_too_few_motions_or_wrong_shapes_are_refused():
    times, poses = drive(turning=True)
    stamps, rotations = camera_motions(times, poses, 0.0)
    with pytest.raises(ValueError, match="camera motions"):
        stamp_offset(times, poses, stamps[:2], rotations[:2])
    with pytest.raises(ValueError, match=r"\(M, 2\)"):
        stamp_offset(times, poses, stamps[:, 0], rotations)


def test_a_barely_turning_drive_does_not_claim_a_lag_it_cannot_tell():
    """A weave of 0.002 rad at 0.08 Hz with 0.02° / 0.05° noise on the LiDAR's and the camera's
    rotations: the cost kinks at every LiDAR stamp, and a three-point curvature read such a kink
    as a sharp minimum (1 ms claimed, up to 100 ms off). The spread must cover the error."""
    from scipy.spatial.transform import Rotation as Rot

    dt, duration = 0.001, 20.0
    fine = np.arange(0, duration, dt)
    yaw = 0.002 * np.sin(0.5 * fine)

    def pose(q):
        k = np.clip(np.round(q / dt).astype(int), 0, len(fine) - 1)
        P = np.tile(np.eye(4), (len(k), 1, 1))
        P[:, :3, :3] = Rot.from_euler("z", yaw[k][:, None]).as_matrix()
        P[:, 0, 3] = 2 * fine[k]
        return P

    covered = 0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        times = np.arange(0.3, duration - 0.5, 0.1)
        lidar = pose(times)
        lidar[:, :3, :3] = (
            Rot.from_rotvec(rng.normal(0, np.radians(0.02), (len(times), 3))).as_matrix() @ lidar[:, :3, :3]
        )
        i = np.arange(0, len(times) - 3, 3)
        ends = np.stack([times[i], times[i + 3]], 1)
        P = pose(ends.ravel()).reshape(-1, 2, 4, 4)
        R = (np.linalg.inv(P[:, 1]) @ P[:, 0])[:, :3, :3]
        R = Rot.from_rotvec(rng.normal(0, np.radians(0.05), (len(R), 3))).as_matrix() @ R
        found = stamp_offset(times, lidar, ends, R, max_gap_s=0.15)
        covered += abs(found.offset_s) <= 3 * found.std_s  # the true lag is 0
    assert covered >= 9
