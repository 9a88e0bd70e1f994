"""The online filter's measurement: a window's departure from the file's extrinsic and its
covariance, moved from the camera frame the solver gives it in to the LiDAR frame of the state."""

import numpy as np
import torch

from calib.geometry import se3_exp
from calib.refine.tracking import departure, departure_covariance
from tests.conftest import kitti_like_extrinsic


def test_departure_covariance_is_the_departures_own_to_first_order():
    T_file = kitti_like_extrinsic()
    T = (
        se3_exp(torch.tensor([0.01, -0.02, 0.005, 0.002, 0.001, -0.003], dtype=torch.float64)).numpy()
        @ T_file
    )
    # the departure's Jacobian in the solver's left perturbation T = exp(δ) · T, by central differences
    J = np.zeros((6, 6))
    for k in range(6):
        step = np.zeros(6)
        step[k] = 1e-6
        plus, minus = (se3_exp(torch.from_numpy(s)).numpy() @ T for s in (step, -step))
        J[:, k] = (departure(plus, T_file) - departure(minus, T_file)) / 2e-6
    # a solver covariance that is weak along the camera's z (depth), strong across it
    stds = np.array([0.01, 0.01, 0.06, 0.0009, 0.0009, 0.0035])
    R_cam = np.diag(stds**2)
    R_lidar = departure_covariance(R_cam, T)
    expected = J @ R_cam @ J.T  # the departure's own; equal to first order in its size (2 cm, 0.2°)
    scale = np.sqrt(np.outer(np.diag(expected), np.diag(expected)))
    assert np.all(np.abs(R_lidar - expected) < 0.01 * scale)  # within 1 % in correlation
    # the weak axis lands on the LiDAR's x (forward), not on its z as the camera-frame matrix says
    assert np.argmax(np.diag(R_lidar)[:3]) == 0 and np.argmax(np.diag(R_cam)[:3]) == 2
