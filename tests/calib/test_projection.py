import numpy as np
import pytest
import torch

from calib.projection import (
    Visibility,
    measured,
    project_points,
    project_scan,
    render_image,
    transform_points,
    unproject_points,
    zbuffer_visibility,
)
from tests.conftest import KITTI_K, kitti_like_extrinsic


def test_projection_of_points_from_known_pixels_returns_them():
    K = torch.as_tensor(KITTI_K)
    uv = torch.tensor([[0.0, 0.0], [311.5, 93.5], [623.0, 187.0], [100.25, 50.75]], dtype=torch.float64)
    depth = torch.tensor([1.0, 5.0, 30.0, 12.5], dtype=torch.float64)
    uv_back, depth_back = project_points(unproject_points(uv, depth, K), K)
    torch.testing.assert_close(uv_back, uv)
    torch.testing.assert_close(depth_back, depth)


def test_projection_known_answer_principal_point_and_broadcast():
    K = torch.as_tensor(KITTI_K)
    uv, depth = project_points(torch.tensor([[[0.0, 0.0, 4.0], [1.0, 0.5, 2.0]]], dtype=torch.float64), K)
    torch.testing.assert_close(uv[0, 0], torch.tensor([311.5, 93.5], dtype=torch.float64))
    torch.testing.assert_close(uv[0, 1], torch.tensor([311.5 + 180.0, 93.5 + 90.0], dtype=torch.float64))
    assert uv.shape == (1, 2, 2) and depth.shape == (1, 2)


def test_transform_points_matches_homogeneous_product():
    T = torch.as_tensor(kitti_like_extrinsic())
    p = torch.randn(10, 3, dtype=torch.float64)
    hom = torch.cat([p, torch.ones(10, 1, dtype=torch.float64)], 1) @ T.T
    torch.testing.assert_close(transform_points(T, p), hom[:, :3])


def test_shape_errors():
    with pytest.raises(ValueError, match=r"\(\.\.\., N, 3\)"):
        project_points(torch.zeros(4, 2), torch.eye(3))
    with pytest.raises(ValueError, match="odd"):
        Visibility(window=4)


def _wall_and_square(step=0.02):
    """A wall at 10 m and a 1 m square plate at 4 m in front of it, sampled like a dense scan."""
    g = np.arange(-3, 3, step)
    wall = np.array([[x, y, 10.0] for x in g for y in g[::2]])
    s = np.arange(-0.5, 0.5, step * 2)
    plate = np.array([[x, y, 4.0] for x in s for y in s])
    return wall, plate


def test_zbuffer_removes_points_behind_a_nearer_surface_only():
    wall, plate = _wall_and_square()
    pts = np.vstack([wall, plate])
    K = torch.tensor([[300.0, 0, 320], [0, 300.0, 240], [0, 0, 1]], dtype=torch.float64)
    uv, depth = project_points(torch.as_tensor(pts), K)
    visible = zbuffer_visibility(uv, depth, (480, 640)).numpy()
    wall_visible = visible[: len(wall)]
    behind_plate = (np.abs(wall[:, 0]) < 0.2 * 2.5) & (
        np.abs(wall[:, 1]) < 0.2 * 2.5
    )  # well inside the plate's shadow
    assert visible[len(wall) :].all(), "the nearer plate must stay visible"
    assert not wall_visible[behind_plate].any(), "wall points behind the plate must be hidden"
    far_from_plate = (np.abs(wall[:, 0]) > 2.0) | (np.abs(wall[:, 1]) > 2.0)
    assert wall_visible[far_from_plate].all()
    # a one-pixel z-buffer lets background leak through the plate's sampling gaps
    leaky = zbuffer_visibility(uv, depth, (480, 640), Visibility(window=1)).numpy()
    assert leaky[: len(wall)][behind_plate].sum() > 0


def test_zbuffer_keeps_a_ground_plane():
    """Sloped surfaces (ground seen at a grazing angle) must not occlude themselves."""
    rng = np.random.default_rng(0)
    ground_lidar = np.column_stack([rng.uniform(3, 25, 4000), rng.uniform(-8, 8, 4000), np.full(4000, -1.7)])
    proj = project_scan(ground_lidar, kitti_like_extrinsic(), KITTI_K, (188, 624))
    in_view = project_scan(ground_lidar, kitti_like_extrinsic(), KITTI_K, (188, 624), visibility=None)
    assert len(proj.index) >= 0.97 * len(in_view.index)


def test_points_behind_camera_and_outside_image_dropped():
    pts = np.array([[5.0, 0, 0, 0.5], [-5.0, 0, 0, 0.5], [5.0, 50.0, 0, 0.5]])
    proj = project_scan(pts, kitti_like_extrinsic(), KITTI_K, (188, 624))
    assert proj.index.tolist() == [0]
    assert proj.intensity.tolist() == [0.5]
    # indices refer to the whole scan, whatever lies behind the camera before a visible point
    mixed = np.array(
        [[-5.0, 0, 0, 0.1], [5.0, 50.0, 0, 0.2], [5.0, 0, 0, 0.3], [-9.0, 1, 0, 0.4], [8.0, 1, 0, 0.6]]
    )
    proj = project_scan(mixed, kitti_like_extrinsic(), KITTI_K, (188, 624), visibility=None)
    assert proj.index.tolist() == [2, 4]
    assert proj.intensity.tolist() == [0.3, 0.6]
    points_cam = mixed[[2, 4], :3] @ kitti_like_extrinsic()[:3, :3].T + kitti_like_extrinsic()[:3, 3]
    assert np.allclose(proj.depth, points_cam[:, 2])


def test_missing_returns_are_never_projected():
    """Organised clouds store a missing return as (0, 0, 0) or at its beam's origin, centimetres
    from the centre. With the LiDAR's centre 1 m ahead of the camera, in view, none is kept (before,
    every one fell on the centre's pixel); a return at 12 cm is kept."""
    T = kitti_like_extrinsic()
    T[2, 3] = 1.0
    assert 0 < T[0, 3] / T[2, 3] * KITTI_K[0, 0] + KITTI_K[0, 2] < 624  # the centre's pixel lies in view
    pts = np.array([[0.0, 0, 0, 0], [5.0, 0, 0, 0.5], [0.03, 0, 0.01, 0], [0.0, 0, 0, 0], [0.12, 0, 0, 0.2]])
    for visibility in (None, Visibility()):
        assert project_scan(pts, T, KITTI_K, (188, 624), visibility).index.tolist() == [1, 4]
    assert measured(pts).tolist() == [False, True, False, False, True]


def test_render_image_keeps_nearest_value_per_pixel():
    uv = torch.tensor([[2.0, 1.0], [2.2, 0.9], [0.0, 0.0]], dtype=torch.float64)
    depth = torch.tensor([5.0, 3.0, 7.0], dtype=torch.float64)
    values = torch.tensor([0.1, 0.9, 0.4], dtype=torch.float64)
    img = render_image(uv, depth, (3, 4), values)
    assert img.shape == (3, 4)
    assert img[1, 2].item() == pytest.approx(0.9)
    assert img[0, 0].item() == pytest.approx(0.4)
    assert (img != 0).sum() == 2
    proj_depth = render_image(uv, depth, (3, 4))
    assert proj_depth[1, 2].item() == pytest.approx(3.0)
    channels = render_image(uv, depth, (3, 4), torch.stack([values, 10 * values], 1))
    assert channels.shape == (3, 4, 2)  # several values of the same nearest point, one z-buffer
    assert torch.allclose(channels[..., 0], img) and torch.allclose(channels[..., 1], 10 * img)


def test_projected_scan_images(frames):
    f = frames[0]
    proj = project_scan(f.points, f.calibration.T_cam_lidar, f.K, f.image_size)
    depth_img, inten_img = proj.depth_image(), proj.intensity_image()
    assert depth_img.shape == f.image_size and depth_img.dtype == np.float32
    assert (depth_img > 0).sum() <= len(proj.index)
    assert np.all(depth_img[depth_img > 0] >= proj.depth.min() - 1e-5)
    assert inten_img.shape == f.image_size
    both = proj.depth_and_intensity_images()  # one z-buffer, the same pixels win
    np.testing.assert_array_equal(both[0], depth_img)
    np.testing.assert_array_equal(both[1], inten_img)
