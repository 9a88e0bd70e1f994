"""``calib.match.contours``: contour samples of a scan (known answers on a box before a wall) and
the score's shapes and block sums."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from calib.data import Frame
from calib.match.contours import ContourConfig, ContourScore, horizontal_edges, vertical_edges


def test_contour_score_shapes(small_urban):
    T = small_urban[0].calibration.T_cam_lidar
    score = ContourScore(small_urban, T)
    sigma = score.sigma_px(0.25)
    Ts = torch.as_tensor(np.stack([T, T, T]))
    values = score.values(Ts, sigma)
    assert values.shape == (3, 2, 2, score.points.shape[2])
    assert score.per_frame(Ts, sigma).shape == (3, 2)
    assert score.score(Ts, sigma).shape == (3,)
    sums, ids = score.block_sums(Ts, sigma)
    assert sums.shape == (3, len(ids))
    # the block contributions add up to the score
    assert torch.allclose(sums.sum(1), score.score(Ts, sigma))
    assert float(score.weights.sum()) == pytest.approx(1.0)


def test_contours_of_a_box_in_front_of_a_wall():
    """A scan-line ordered scan of a wall 20 m ahead with a 2 m-wide box 10 m ahead: vertical
    edges at the box's sides, horizontal ones at its top, midway between the returns."""
    rings = np.radians(np.arange(-10.0, 6.01, 0.4))
    azimuths = np.radians(np.arange(-20.0, 20.0, 0.2))
    points = []
    for elevation in rings:
        for azimuth in azimuths:
            direction = np.array(
                [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)]
            )
            box = 10.0 / direction[0]
            hit = box * direction
            depth = box if abs(hit[1]) < 1.0 and hit[2] < 0.5 else 20.0 / direction[0]
            points.append(depth * direction)
    points = np.array(points)
    sides = horizontal_edges(points)
    assert len(sides) > 10
    assert np.allclose(np.abs(sides[:, 1] / sides[:, 0] * 10.0), 1.0, atol=0.05)  # at |y| = 1 m on the box
    tops, silhouettes, spacing = vertical_edges(points)
    assert spacing == pytest.approx(0.4, abs=0.01) and len(tops) > 5 and len(silhouettes) == 0
    assert np.allclose(tops[:, 2] / tops[:, 0] * 10.0, 0.5, atol=0.05)  # the top at z = 0.5 m


def test_too_few_samples_are_refused(small_urban):
    from calib.errors import NumericalError

    empty = [Frame(small_urban[0].image, small_urban[0].points[:10], small_urban[0].calibration)]
    with pytest.raises(NumericalError, match="too few contour samples"):
        ContourScore(empty, small_urban[0].calibration.T_cam_lidar, ContourConfig())


def test_a_rigs_frames_score_as_each_camera_alone(small_urban):
    """Known answer: two frames as cameras of a rig (``T_cam_rig``), the second with a smaller
    image (its maps padded with zeros to the first's size) and a longer focal length (its blur
    scales with it), score each extrinsic ``T`` of the rig, frame by frame and in each image
    block, as each frame on its own scores ``T_cam_rig · T``; a rig's camera beside a camera on
    its own is refused."""
    from dataclasses import replace

    from calib.errors import DataError
    from calib.geometry import se3_exp

    T_ref = np.asarray(small_urban[0].calibration.T_cam_lidar)
    T_rig_lidar = se3_exp(torch.tensor([0.2, -0.1, 0.3, 0.1, 1.2, -0.2], dtype=torch.float64)).numpy() @ T_ref
    T_cam_rig = T_ref @ np.linalg.inv(T_rig_lidar)
    zoomed = small_urban[1].calibration.K.copy()
    zoomed[:2, :2] *= 1.25
    second = replace(small_urban[1].calibration, K=zoomed)
    alone = [small_urban[0], Frame(small_urban[1].image[:150, :500].copy(), small_urban[1].points, second)]
    rig = [Frame(f.image, f.points, replace(f.calibration, T_cam_rig=T_cam_rig)) for f in alone]
    config = ContourConfig(max_samples=100_000)  # every sample kept: no draw
    moves = se3_exp(torch.tensor([[0, 0, 0, 0, 0, 0], [0.05, 0, -0.1, 0.01, 0.02, 0]], dtype=torch.float64))
    T = moves @ torch.as_tensor(T_rig_lidar)
    score = ContourScore(rig, T_rig_lidar, config)
    sigma = score.sigma_px(0.3)
    for k, frame in enumerate(alone):
        single = ContourScore([frame], T_ref, config)
        assert score.counts[k] == single.counts[0]
        expected = single.per_frame(torch.as_tensor(T_cam_rig) @ T, sigma * frame.K[0, 0] / alone[0].K[0, 0])
        np.testing.assert_allclose(score.per_frame(T, sigma)[:, k].numpy(), expected[:, 0].numpy(), atol=2e-6)
        n = single.points.shape[2]  # the rig's samples are the frame's own, zero-padded further
        used = single.weights[:, 0] > 0
        cells = config.blocks[0] * config.blocks[1]
        rig_blocks = score.block[:, k, :n][used] - 2 * k * cells  # the block ids of frame k start there
        assert torch.equal(rig_blocks, single.block[:, 0][used])
    with pytest.raises(DataError, match="rig"):
        ContourScore([rig[0], alone[1]], T_rig_lidar, config)
