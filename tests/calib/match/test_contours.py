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
