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
