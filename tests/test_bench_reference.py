"""benchmarks/bench_reference.py's rotation fit, on exact correspondences with a known turn."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bench_reference  # noqa: E402

from calib.match.correspondences import Correspondences  # noqa: E402
from calib.projection import project_points, transform_points  # noqa: E402

K = np.array([[720.0, 0, 620], [0, 720, 190], [0, 0, 1]])


def _project(points_lidar: np.ndarray, T: np.ndarray) -> np.ndarray:
    uv, _ = project_points(
        transform_points(torch.as_tensor(T), torch.as_tensor(points_lidar)), torch.as_tensor(K)
    )
    return uv.numpy()


@pytest.mark.parametrize("outliers", [0.0, 0.2])
def test_rotation_fit_recovers_a_known_turn(outliers):
    """Matches made under the reference turned by 0.3° about the camera's y axis (and 0.1° about
    x): the fit finds that turn, with a fifth of the matches 30 px astray as well."""
    rng = np.random.default_rng(4)
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]
    T[:3, 3] = [0.05, -0.1, -0.3]
    n = 600
    points = np.column_stack([rng.uniform(5, 40, n), rng.uniform(-8, 8, n), rng.uniform(-1.5, 2, n)])
    omega = np.radians([0.1, 0.3, 0.0])
    matched = _project(points, bench_reference.turned(T, omega))
    astray = rng.random(n) < outliers
    matched[astray] += rng.normal(0, 30, (astray.sum(), 2))
    corr = Correspondences(
        np.arange(n), points, _project(points, T), matched, np.ones(n, np.float32), (375, 1242)
    )
    fit = bench_reference.rotation_fit([corr], T, K, scale_px=2.0)
    np.testing.assert_allclose(np.degrees(fit), np.degrees(omega), atol=0.01 if outliers else 0.002)


def test_with_rotation_of_takes_the_rotation_and_keeps_the_translation():
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.2, 0.3]
    other = bench_reference.turned(np.eye(4), np.radians([0.0, 2.0, 0.0]))
    other[:3, 3] = [5.0, 5.0, 5.0]
    mixed = bench_reference.with_rotation_of(T, other)
    np.testing.assert_array_equal(mixed[:3, :3], other[:3, :3])
    np.testing.assert_array_equal(mixed[:3, 3], T[:3, 3])
    np.testing.assert_array_equal(mixed[3], [0, 0, 0, 1])


def test_views_parse_name_and_crop():
    assert bench_reference._views("pjlab-1:1,2,30,40 kitti:0,0,5,6") == [
        ("pjlab-1", (1, 2, 30, 40)),
        ("kitti", (0, 0, 5, 6)),
    ]


@pytest.mark.parametrize(
    "text", ["pjlab-1:1,2,30", "pjlab-1", ":1,2,30,40", "pjlab-1:30,2,1,40", "a:1,2,x,4"]
)
def test_views_refuse_a_malformed_crop_with_its_item(text):
    with pytest.raises(ValueError, match="expected NAME:x0,y0,x1,y1"):
        bench_reference._views(text)


def test_crop_parses_four_integers_and_refuses_an_empty_box():
    assert bench_reference._crop("450,840,780,1090") == (450, 840, 780, 1090)
    for text in ("450,840,780", "450,840,450,1090", "a,1,2,3"):
        with pytest.raises(ValueError, match="expected x0,y0,x1,y1"):
            bench_reference._crop(text)


@pytest.mark.parametrize("near_m", [None, 30.0])
def test_picture_sets_one_zoomed_panel_per_extrinsic_side_by_side(tmp_path, frames, near_m):
    """Three extrinsics, a 100x50 crop zoomed 3x: three 300x150 panels and two 16 px gaps; the
    returns drawn change the crop's pixels (coloured by intensity, or by depth near enough)."""
    frame = frames[0]
    T = frame.calibration.T_cam_lidar
    path = tmp_path / "panels.png"
    bench_reference.picture(frame, [T, T, T], (200, 40, 300, 90), path, near_m=near_m)
    image = cv2.imread(str(path))
    assert image.shape == (150, 3 * 300 + 2 * 16, 3)
    crop = cv2.resize(frame.image[40:90, 200:300, ::-1], None, fx=3, fy=3, interpolation=cv2.INTER_NEAREST)
    assert (image[:, :300] != crop).any()  # returns drawn
    np.testing.assert_array_equal(image[:, 300:316], 255)  # the gap


@pytest.mark.parametrize("near_m", [None, 0.6])
def test_picture_of_a_crop_without_returns_is_the_image_alone(tmp_path, frames, near_m):
    """No return in the crop (or none nearer than ``near_m``): the panels are the zoomed crop
    itself, not an error (OpenCV colours an empty array as ``None``)."""
    frame = frames[0]
    T = frame.calibration.T_cam_lidar.copy()
    if near_m is None:  # every return behind the camera: none in view
        T[:3, 3] += [0.0, 0.0, -1e3]
    path = tmp_path / "panels.png"
    bench_reference.picture(frame, [T], (200, 40, 300, 90), path, near_m=near_m)
    crop = cv2.resize(frame.image[40:90, 200:300, ::-1], None, fx=3, fy=3, interpolation=cv2.INTER_NEAREST)
    np.testing.assert_array_equal(cv2.imread(str(path)), crop)
