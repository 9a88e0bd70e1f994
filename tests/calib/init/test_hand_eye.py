import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib.init.hand_eye import HandEyeConfig, UnobservableError, hand_eye
from calib.init.time_sync import interpolate_poses

EXACT = HandEyeConfig(metric_camera=True, translation_prior_m=None)


def _extrinsic() -> np.ndarray:
    X = np.eye(4)
    X[:3, :3] = Rotation.from_euler("xyz", [-92, 1.5, -88], degrees=True).as_matrix()
    X[:3, 3] = [0.05, -0.3, -0.25]
    return X


def _poses(n: int, rng: np.random.Generator, planar: bool = False, rotate: bool = True) -> np.ndarray:
    """``T_world_lidar`` of a rig: random 3D motion, or planar (yaw only, z = 0), or pure translation."""
    P = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        rotvec = rng.normal(0, 0.4, 3) if rotate else np.zeros(3)
        if planar:
            rotvec[:2] = 0
        P[i, :3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
        P[i, :3, 3] = rng.normal(0, 3, 3) * ([1, 1, 0] if planar else 1)
    return P


def _motions(P: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera motions ``A = T_cam_j_cam_i`` (metric) and LiDAR motions ``B = T_lidar_j_lidar_i``."""
    B = np.linalg.inv(P[1:]) @ P[:-1]
    return X @ B @ np.linalg.inv(X), B


def _unit(A: np.ndarray) -> np.ndarray:
    A = A.copy()
    A[:, :3, 3] /= np.linalg.norm(A[:, :3, 3], axis=1, keepdims=True)
    return A


def test_exact_motions_agree_with_opencv_calibrate_hand_eye():
    """Peer check: on exact metric motions our solver and every OpenCV method agree to 1e-6."""
    X = _extrinsic()
    P = _poses(15, np.random.default_rng(0))
    A, B = _motions(P, X)
    ours = hand_eye(A, B, EXACT).T_cam_lidar
    C_inv = X @ np.linalg.inv(P)  # T_cam_world: the static world is OpenCV's "target"
    for method in (cv2.CALIB_HAND_EYE_TSAI, cv2.CALIB_HAND_EYE_PARK, cv2.CALIB_HAND_EYE_DANIILIDIS):
        R, t = cv2.calibrateHandEye(
            P[:, :3, :3], P[:, :3, 3], C_inv[:, :3, :3], C_inv[:, :3, 3], method=method
        )
        T_lidar_cam = np.eye(4)
        T_lidar_cam[:3, :3], T_lidar_cam[:3, 3] = R, t.ravel()
        assert np.abs(np.linalg.inv(T_lidar_cam) - ours).max() < 1e-6
    assert np.abs(ours - X).max() < 1e-9


def test_unknown_scales_are_recovered_from_unit_translations():
    X = _extrinsic()
    A, B = _motions(_poses(12, np.random.default_rng(1)), X)
    result = hand_eye(_unit(A), B, HandEyeConfig(translation_prior_m=None))
    assert np.abs(result.T_cam_lidar - X).max() < 1e-8
    assert np.allclose(result.scales, np.linalg.norm(A[:, :3, 3], axis=1), atol=1e-8)
    assert result.weak == [] and result.inlier_ratio == 1.0


def test_noise_and_an_outlier_stay_small_with_the_robust_loss():
    rng = np.random.default_rng(2)
    X = _extrinsic()
    A, B = _motions(_poses(40, rng), X)
    A = _unit(A)
    for k in range(len(A)):  # 0.05° rotation noise, 0.5° direction noise
        A[k, :3, :3] = Rotation.from_rotvec(rng.normal(0, np.radians(0.05), 3)).as_matrix() @ A[k, :3, :3]
        direction = Rotation.from_rotvec(rng.normal(0, np.radians(0.5), 3)).apply(A[k, :3, 3])
        A[k, :3, 3] = direction / np.linalg.norm(direction)
    A[5, :3, :3] = Rotation.from_rotvec([0.3, 0, 0]).as_matrix() @ A[5, :3, :3]  # a VO failure
    result = hand_eye(A, B, HandEyeConfig(translation_sigma_m=0.05))  # 0.5° of ~4 m motions
    E = np.linalg.inv(X) @ result.T_cam_lidar
    assert np.degrees(np.linalg.norm(Rotation.from_matrix(E[:3, :3]).as_rotvec())) < 0.1
    assert np.linalg.norm(E[:3, 3]) * 100 < 3 * np.linalg.norm(result.std_cm) < 12  # within its own std
    assert result.inlier_ratio < 1.0


def test_planar_motion_reports_the_vertical_offset_as_unobservable():
    X = _extrinsic()
    A, B = _motions(_poses(20, np.random.default_rng(3), planar=True), X)
    result = hand_eye(_unit(A), B)
    assert [(w.kind, w.axis) for w in result.weak] == [("translation", "+z")]
    assert "translation along LiDAR +z" in str(result.weak[0])
    # everything else is still recovered
    E = np.linalg.inv(X) @ result.T_cam_lidar
    assert np.degrees(np.linalg.norm(Rotation.from_matrix(E[:3, :3]).as_rotvec())) < 1e-4
    z = X[:3, :3] @ np.array([0.0, 0.0, 1.0])  # LiDAR z in the camera frame
    residual = result.T_cam_lidar[:3, 3] - X[:3, 3]
    assert np.linalg.norm(residual - (residual @ z) * z) < 1e-4


def test_pure_translation_and_straight_lines_are_refused_with_a_report():
    X = _extrinsic()
    A, B = _motions(_poses(10, np.random.default_rng(4), rotate=False), X)
    with pytest.raises(UnobservableError, match="translation of T_cam_lidar is unobservable"):
        hand_eye(_unit(A), B)
    line = np.tile(np.eye(4), (10, 1, 1))
    line[:, 0, 3] = np.arange(10) * 1.5  # straight ahead along LiDAR x
    A, B = _motions(line, X)
    with pytest.raises(UnobservableError, match=r"straight line \(LiDAR direction \[1.0, 0.0, 0.0\]\)"):
        hand_eye(_unit(A), B)


def test_interpolation_known_answer_and_gaps():
    times = np.array([0.0, 1.0, 2.0, 5.0])
    poses = np.tile(np.eye(4), (4, 1, 1))
    poses[:, 0, 3] = [0.0, 1.0, 2.0, 5.0]
    poses[1, :3, :3] = Rotation.from_rotvec([0, 0, np.pi / 2]).as_matrix()
    out, valid = interpolate_poses(times, poses, np.array([0.5, 1.5, 3.0, -1.0]), max_gap_s=1.5)
    assert valid.tolist() == [True, True, False, False]
    assert out[0, 0, 3] == pytest.approx(0.5) and out[1, 0, 3] == pytest.approx(1.5)
    angle = np.degrees(np.linalg.norm(Rotation.from_matrix(out[0, :3, :3]).as_rotvec()))
    assert angle == pytest.approx(45.0)  # slerp halfway
    with pytest.raises(ValueError, match="strictly increasing"):
        interpolate_poses(np.array([0.0, 0.0]), poses[:2], np.array([0.0]), 1.0)
