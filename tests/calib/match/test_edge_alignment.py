import numpy as np
import pytest
import torch

from calib.data.types import Frame
from calib.errors import DataError
from calib.match.edge_alignment import EdgeAlignment


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


def test_orientation_map_cancels_texture_that_magnitude_counts(small_urban):
    """Random texture beside one vertical edge: under a 4 px blur the magnitude map rates the
    texture about as high as the edge, the orientation map far lower (its angles cancel)."""
    H, W = small_urban[0].image_size
    image = _steps((H, W), vertical=True)
    texture = np.random.default_rng(0).integers(0, 255, (H, W // 4), np.uint8)
    image[:, : W // 4] = texture[..., None]
    frame = _frame_with(image, small_urban)
    ratios = {}
    for kind in ("magnitude", "orientation"):
        edge_map = EdgeAlignment([frame], kind=kind).maps(4.0)[0, 0].abs()
        inner = edge_map[H // 4 : 3 * H // 4]
        ratios[kind] = float(inner[:, 10 : W // 4 - 10].mean() / inner[:, W // 2 - 1 : W // 2 + 1].mean())
    assert ratios["magnitude"] > 0.5
    assert ratios["orientation"] < 0.2


def test_unknown_kind_is_refused(small_urban):
    with pytest.raises(DataError, match="kind"):
        EdgeAlignment(small_urban, kind="gradient")


def test_score_shape_over_candidates(small_urban):
    T = torch.as_tensor(small_urban[0].calibration.T_cam_lidar)
    score = EdgeAlignment(small_urban, kind="orientation")
    assert score(T.expand(5, 4, 4), 4.0).shape == (5,)
    assert score.per_frame(T, 4.0).shape == (1, 2)
