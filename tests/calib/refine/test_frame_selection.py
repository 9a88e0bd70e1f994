"""Frame selection by information (calib/refine/frame_selection.py)."""

import dataclasses

import numpy as np
import pytest
from pydantic import ValidationError

from calib.pipeline import Calibrator
from calib.refine.frame_selection import FrameSelectionConfig, contour_information, select_informative
from calib.refine.passes import CalibrateConfig

K = np.array([[360.0, 0, 320], [0, 360, 100], [0, 0, 1]])
T = np.array([[0.0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]])  # LiDAR x forward


def _scan(objects: list[tuple[float, float, float, float, float]]) -> np.ndarray:
    """First hits of a 64-ring scan on boxes ``(depth, y_min, y_max, z_min, z_max)`` facing the
    LiDAR, in front of a wall 30 m ahead; stored ring by ring (scan-line order)."""
    azimuth, elevation = np.meshgrid(np.radians(np.arange(-40, 40, 0.2)), np.radians(np.arange(-15, 5, 0.4)))
    d = np.stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], -1
    )
    d = d.reshape(-1, 3)
    t = 30.0 / d[:, 0]
    for depth, y0, y1, z0, z1 in objects:
        s = depth / d[:, 0]
        y, z = d[:, 1] * s, d[:, 2] * s
        hit = (y > y0) & (y < y1) & (z > z0) & (z < z1) & (s < t)
        t = np.where(hit, s, t)
    return np.column_stack([d * t[:, None], np.ones(len(d))]).astype(np.float32)


def test_select_informative_known_answer():
    a = np.diag([1.0, 1, 1, 1e-6, 1e-6, 1e-6])
    b = np.diag([1e-6, 1e-6, 1e-6, 1, 1, 1])
    # a and 0.9·a together pin three directions twice; a and b pin all six
    assert select_informative([a, 0.9 * a, b], 2) == [0, 2]
    assert select_informative([a, b], 5) == [0, 1]


def test_contour_information_sees_which_edges_a_frame_has():
    poles = _scan([(6.0, y, y + 0.3, -2.0, 3.0) for y in (-3.0, -1.0, 1.5)])  # vertical edges only
    boxes = _scan([(6.0, -3.0, -1.0, -2.0, 0.5), (8.0, 1.0, 3.0, -2.0, 1.0)])  # both kinds
    info_poles, info_boxes = (contour_information(s, T, K, (200, 640)) for s in (poles, boxes))
    for info in (info_poles, info_boxes):
        assert info.shape == (6, 6)
        assert np.allclose(info, info.T)
        assert np.linalg.eigvalsh(info).min() > -1e-6 * np.trace(info)
    # vertical translation (camera y) is fixed by horizontal edges, which the poles lack
    assert info_boxes[1, 1] > 5 * info_poles[1, 1]
    assert select_informative([info_poles, info_boxes], 1) == [1]


def test_selection_config_is_validated():
    with pytest.raises(ValidationError):
        FrameSelectionConfig(method="best")
    with pytest.raises(ValidationError):
        FrameSelectionConfig(candidates=0)


def test_calibrator_uses_the_informative_frames(small_urban):
    frames = [small_urban[0]] * 6
    empty = dataclasses.replace(frames[0], points=frames[0].points[:0])
    sequence = [frames[0], empty, frames[0], empty, empty, frames[0]]
    config = CalibrateConfig(frames=2, passes=1, sampling={"per_frame": 300}, selection={"candidates": 3})
    result = Calibrator(config=config).calibrate(sequence, T_init=frames[0].calibration.T_cam_lidar)
    assert set(result.frame_indices) <= {0, 2, 5} and len(result.frame_indices) == 2
    spread = config.model_copy(update={"selection": FrameSelectionConfig(method="spread")})
    assert Calibrator(config=spread).calibrate(
        sequence, T_init=frames[0].calibration.T_cam_lidar
    ).frame_indices == [0, 5]


def test_a_rig_cameras_information_is_about_the_rigs_move(small_urban):
    """Known answer: a camera in a rig (``T_cam_rig = L``) tells about the rig's move ``δ_r`` what
    it tells about its own, ``δ_c = Ad(L) δ_r`` (``exp(δ_c) L = L exp(δ_r)``): its information is
    ``Ad(L)ᵀ I_c Ad(L)``, so that the informations of a rig's cameras add up."""
    import cv2

    frame = small_urban[0]
    T_cam = np.asarray(frame.calibration.T_cam_lidar)
    L = np.eye(4)
    L[:3, :3] = cv2.Rodrigues(np.array([0.3, -1.2, 0.4]))[0]
    L[:3, 3] = [0.5, -0.2, 1.1]
    T_rig = np.linalg.inv(L) @ T_cam
    own = contour_information(frame.points, T_cam, frame.K, frame.image_size)
    R, t = L[:3, :3], L[:3, 3]
    skew = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    Ad = np.block([[R, skew @ R], [np.zeros((3, 3)), R]])  # twists (ρ, ω), translation first
    in_rig = contour_information(frame.points, T_rig, frame.K, frame.image_size, L)
    np.testing.assert_allclose(in_rig, Ad.T @ own @ Ad, rtol=1e-9, atol=1e-6 * np.abs(own).max())
