from dataclasses import replace

import numpy as np
import pytest
import torch

from calib.data.types import Frame
from calib.errors import DataError
from calib.geometry import se3_exp
from calib.match.edge_alignment import EdgeAlignment, contour_points


def _frame_with(image: np.ndarray, small_urban) -> Frame:
    return Frame(image, small_urban[0].points, small_urban[0].calibration)


def _steps(size: tuple[int, int], vertical: bool) -> np.ndarray:
    """An RGB image with one step edge through its middle: vertical (left | right) or horizontal."""
    H, W = size
    image = np.full((H, W, 3), 60, np.uint8)
    if vertical:
        image[:, W // 2 :] = 200
    else:
        image[H // 2 :] = 200
    return image


def test_orientation_map_is_positive_on_vertical_edges_negative_on_horizontal(small_urban):
    size = small_urban[0].image_size
    for vertical, sign in ((True, 1.0), (False, -1.0)):
        score = EdgeAlignment([_frame_with(_steps(size, vertical), small_urban)], kind="orientation")
        edge = score.maps(2.0)[0, 0]
        H, W = size
        value = float(edge[H // 2, W // 2 - 1 : W // 2 + 1].mean())
        assert sign * value > 0.9  # the edge is the map's peak (renormalised to 1)


def _texture_over_edge(small_urban, kind: str, surround: float) -> float:
    """Random texture beside one vertical edge: the map's mean over the texture over its mean on
    the edge, under a 4 px blur."""
    H, W = small_urban[0].image_size
    image = _steps((H, W), vertical=True)
    texture = np.random.default_rng(0).integers(0, 255, (H, W // 4), np.uint8)
    image[:, : W // 4] = texture[..., None]
    score = EdgeAlignment([_frame_with(image, small_urban)], kind=kind, surround=surround)
    edge_map = score.maps(4.0)[0, 0].abs()
    inner = edge_map[H // 4 : 3 * H // 4]
    return float(inner[:, 10 : W // 4 - 10].mean() / inner[:, W // 2 - 1 : W // 2 + 1].mean())


def test_orientation_map_cancels_texture_that_magnitude_counts(small_urban):
    """Without the surround subtracted, the magnitude map rates texture about as high as an edge;
    the orientation map far lower (its angles cancel)."""
    assert _texture_over_edge(small_urban, "magnitude", surround=0.0) > 0.5
    assert _texture_over_edge(small_urban, "orientation", surround=0.0) < 0.2


@pytest.mark.parametrize("kind", ["magnitude", "orientation"])
def test_surround_cancels_texture_in_both_maps(small_urban, kind):
    assert _texture_over_edge(small_urban, kind, surround=3.0) < 0.2


def test_contour_point_lies_midway_between_the_returns_at_the_nearer_range():
    """One scan line: a wall at 5 m in front of a wall at 20 m; the occluding contour lies on the
    ray halfway between the last wall return and the first background return, at 5 m."""
    azimuth = np.radians(np.arange(-10.0, 10.0, 0.5))
    ranges = np.where(azimuth < np.radians(0.1), 5.0, 20.0)
    points = np.stack([ranges * np.cos(azimuth), ranges * np.sin(azimuth), np.zeros_like(azimuth)], -1)
    contour = contour_points(points, 10, np.random.default_rng(0))
    assert contour.shape == (1, 3)
    np.testing.assert_allclose(np.linalg.norm(contour[0]), 5.0, rtol=1e-9)
    np.testing.assert_allclose(np.degrees(np.arctan2(contour[0, 1], contour[0, 0])), 0.25, atol=1e-9)


def test_contour_points_outside_the_widened_view_are_not_drawn(small_urban):
    frame = small_urban[0]
    T = np.asarray(frame.calibration.T_cam_lidar)
    every = contour_points(frame.points, 10**6, np.random.default_rng(0))
    seen = contour_points(frame.points, 10**6, np.random.default_rng(0), (frame, T, 5.0))
    assert 0 < len(seen) < len(every)
    q = seen @ T[:3, :3].T + T[:3, 3]
    assert (q[:, 2] > 0).all()  # nothing behind the camera


def test_unknown_kind_is_refused(small_urban):
    with pytest.raises(DataError, match="kind"):
        EdgeAlignment(small_urban, kind="gradient")


def test_score_shape_over_candidates(small_urban):
    T = torch.as_tensor(small_urban[0].calibration.T_cam_lidar)
    score = EdgeAlignment(small_urban, kind="orientation")
    assert score(T.expand(5, 4, 4), 4.0).shape == (5,)
    assert score.per_frame(T, 4.0).shape == (1, 2)


def test_score_is_the_mean_map_value_under_the_projected_contours(small_urban):
    """Known answer, extrinsic by extrinsic in numpy: each contour point projected with
    ``K (R p + t)``, the map read bilinearly there (0 outside the image or within 0.5 m of the
    camera), averaged over the frame's points; several extrinsics scored in one call, one of them
    turned so that part of the contours falls outside the image."""
    score = EdgeAlignment(small_urban, 300, kind="magnitude")
    T_ref = small_urban[0].calibration.T_cam_lidar
    turns = np.array([[0, 0, 0, 0, 0, 0], [0.1, -0.05, 0.2, 0.02, -0.01, 0.03], [0, 0, 0, 0, 0.5, 0]])
    T = se3_exp(torch.as_tensor(turns, dtype=torch.float64)) @ torch.as_tensor(T_ref)
    sigma = 3.0
    got = score.per_frame(T, sigma).numpy()
    maps = score.maps(sigma)[:, 0].numpy().astype(np.float64)
    H, W = score.size
    K = np.asarray(small_urban[0].K)
    for c, T_c in enumerate(T.numpy()):
        for f in range(len(small_urban)):
            p = score.points[f][score.mask[f]].numpy()
            q = p @ T_c[:3, :3].T + T_c[:3, 3]
            u, v = (q @ K.T)[:, 0] / q[:, 2], (q @ K.T)[:, 1] / q[:, 2]
            u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
            value = np.zeros(len(p))
            for du in (0, 1):
                for dv in (0, 1):
                    w = (1 - np.abs(u - u0 - du)) * (1 - np.abs(v - v0 - dv))
                    col, row = u0 + du, v0 + dv
                    inside = (col >= 0) & (col < W) & (row >= 0) & (row < H) & (q[:, 2] > 0.5)
                    value[inside] += w[inside] * maps[f, row[inside], col[inside]]
            assert got[c, f] == pytest.approx(value.mean(), abs=2e-5)
    assert (got[2] != got[0]).all()  # the turned extrinsic reads elsewhere


@pytest.mark.parametrize("kind", ["magnitude", "orientation"])
def test_truth_scores_best_and_the_surround_sharpens_its_peak(small_urban, kind):
    """Moves of ±5 cm and ±0.5° along each axis from the true extrinsic score lower than the
    truth, and lower still relative to it once the surround is subtracted."""
    T = torch.as_tensor(small_urban[0].calibration.T_cam_lidar)
    moves = torch.zeros(12, 6, dtype=torch.float64)
    for axis in range(6):
        step = 0.05 if axis < 3 else np.radians(0.5)
        moves[2 * axis, axis], moves[2 * axis + 1, axis] = step, -step
    candidates = torch.cat([T[None], se3_exp(moves) @ T])
    sigma = 2.0 * small_urban[0].K[0, 0] / 721.0
    relative = {}
    for surround in (0.0, 3.0):
        values = EdgeAlignment(small_urban, 1200, kind=kind, surround=surround)(candidates, sigma)
        assert int(values.argmax()) == 0
        relative[surround] = float((values[1:] / values[0]).mean())
    assert relative[3.0] < relative[0.0] - 0.1


def test_median_depth_is_the_contour_points_median_and_moves_with_the_extrinsic(small_urban):
    """Known answer: the median ``z`` of the contour points in the camera frame; moving the points
    1 m farther along the optical axis moves it 1 m (all of them were drawn in front)."""
    T = np.asarray(small_urban[0].calibration.T_cam_lidar)
    score = EdgeAlignment(small_urban, view=(T, 0.0))
    z = (score.points[score.mask].numpy() @ T[:3, :3].T + T[:3, 3])[:, 2]
    assert (z > 0).all()
    assert score.median_depth(torch.as_tensor(T)) == pytest.approx(float(np.median(z)), abs=0.1)
    farther = T.copy()
    farther[2, 3] += 1.0
    assert score.median_depth(torch.as_tensor(farther)) == pytest.approx(float(np.median(z)) + 1.0, abs=0.1)


def test_median_depth_with_every_point_behind_the_camera_is_refused(small_urban):
    behind = np.asarray(small_urban[0].calibration.T_cam_lidar).copy()
    behind[2, 3] -= 1e4  # every point 10 km behind the camera
    with pytest.raises(DataError, match="in front"):
        EdgeAlignment(small_urban).median_depth(torch.as_tensor(behind))


def test_a_rigs_frames_score_as_each_camera_alone(small_urban):
    """Known answer: two frames as cameras of a rig (``T_cam_rig``), the second with a smaller
    image (cropped: the maps share the larger size, padded with zeros) and a longer focal length
    (its blur scales with it), score each extrinsic ``T`` of the rig as each frame on its own
    scores ``T_cam_rig · T``."""
    T_ref = np.asarray(small_urban[0].calibration.T_cam_lidar)
    T_rig_lidar = se3_exp(torch.tensor([0.2, -0.1, 0.3, 0.1, 1.2, -0.2], dtype=torch.float64)).numpy() @ T_ref
    T_cam_rig = T_ref @ np.linalg.inv(T_rig_lidar)
    zoomed = small_urban[1].calibration.K.copy()
    zoomed[:2, :2] *= 1.25
    alone = [
        small_urban[0],
        Frame(
            small_urban[1].image[:150, :500].copy(),
            small_urban[1].points,
            replace(small_urban[1].calibration, K=zoomed),
        ),
    ]
    rig = [Frame(f.image, f.points, replace(f.calibration, T_cam_rig=T_cam_rig)) for f in alone]
    moves = se3_exp(torch.tensor([[0, 0, 0, 0, 0, 0], [0.05, 0, -0.1, 0.01, 0.02, 0]], dtype=torch.float64))
    T = moves @ torch.as_tensor(T_rig_lidar)
    score = EdgeAlignment(rig, 10_000, kind="magnitude")
    assert score.size == small_urban[0].image_size
    for k, frame in enumerate(alone):
        single = EdgeAlignment([frame], 10_000, kind="magnitude")
        assert score.contours[k] == single.contours[0]  # every contour point kept: no draw
        expected = single.per_frame(torch.as_tensor(T_cam_rig) @ T, 3.0 * frame.K[0, 0] / alone[0].K[0, 0])
        np.testing.assert_allclose(score.per_frame(T, 3.0)[:, k].numpy(), expected[:, 0].numpy(), atol=2e-6)
    assert score.median_depth(T[0]) == pytest.approx(
        EdgeAlignment(alone, 10_000).median_depth(torch.as_tensor(T_ref)), rel=1e-6
    )
