import numpy as np
import pytest

from calib.errors import DataError
from calib.match.correspondences import Correspondences
from calib.support.class_residuals import (
    EXG_CLASSES,
    ClassResiduals,
    class_source,
    classwise_average,
    excess_green_foliage,
    point_classes,
)
from tests.conftest import make_frames


def test_excess_green_separates_leaves_from_soil_and_sky():
    image = np.empty((40, 60, 3), np.uint8)
    image[:] = (120, 100, 80)  # soil
    image[:10] = (150, 180, 230)  # sky
    image[15:30, 10:40] = (60, 140, 50)  # leaves
    rng = np.random.default_rng(0)
    noisy = np.clip(image + rng.normal(0, 3, image.shape), 0, 255).astype(np.uint8)
    expected = np.zeros((40, 60), bool)
    expected[15:30, 10:40] = True
    np.testing.assert_array_equal(excess_green_foliage(noisy), expected)


def test_class_source_prefers_point_labels_and_refuses_missing_ones():
    frame = make_frames(1)[0]
    assert class_source(frame) == "points"
    frame.labels = None
    assert class_source(frame) == ("image" if frame.image_labels is not None else "exg")
    frame.image_labels = None
    assert class_source(frame) == "exg"
    with pytest.raises(DataError, match="no image labels"):
        class_source(frame, "image")


def test_point_classes_read_the_label_at_each_rounded_pixel():
    frame = make_frames(1)[0]
    frame.image_labels = np.zeros(frame.image_size, np.uint16)
    frame.image_labels[:, 300:] = 71
    uv = np.array([[299.4, 10.0], [299.6, 10.0], [700.0, 5.0]])  # the last one clips to the border
    corr = Correspondences(np.arange(3), np.zeros((3, 3)), uv, uv, np.ones(3), frame.image_size)
    np.testing.assert_array_equal(point_classes(frame, corr, "image"), [0, 71, 71])
    np.testing.assert_array_equal(point_classes(frame, corr, "points"), frame.labels[:3])


def test_image_labels_of_another_size_are_refused_not_clipped():
    """Masks at 640x640 for 624x188 images (SemanticBLT's masks are not its images' size): read at
    the image's pixels they would clip every point right of column 639 to that column."""
    frame = make_frames(1)[0]
    frame.image_labels = np.zeros((640, 640), np.uint16)
    uv = np.array([[10.0, 10.0]])
    corr = Correspondences(np.arange(1), np.zeros((1, 3)), uv, uv, np.ones(1), frame.image_size)
    with pytest.raises(DataError, match="image labels are 640x640 but the image is 624x188"):
        point_classes(frame, corr, "image")


def test_class_statistics_known_answer():
    acc = ClassResiduals()
    residual = np.array([[1.0, -2.0], [-3.0, 0.0], [0.5, 0.5], [0.0, -1.5], [2.0, 2.0]])
    acc.add(np.array([1, 1, 0, 0, 0]), residual[:5], np.array([2.0, 4.0, 10, 20, 30]), EXG_CLASSES)
    acc.add(np.array([1]), np.array([[-2.0, 1.0]]), np.array([6.0]), EXG_CLASSES)
    foliage, background = sorted(acc.stats(), key=lambda s: s.name)[::-1]
    assert foliage.name == "foliage" and foliage.points == 3
    assert (foliage.mean_du, foliage.mean_dv, foliage.median_du, foliage.median_dv) == (2.0, 1.0, 2.0, 1.0)
    assert foliage.median_depth_m == 4.0 and background.median_depth_m == 20.0
    assert background.median_norm == 1.5  # of 0.71, 1.5, 2.83
    assert [s.name for s in acc.stats()] == ["background", "foliage"]  # by median ‖f‖
    assert classwise_average(acc.stats()) == pytest.approx(((2.0 + 2.5 / 3) / 2, (1.0 + 4 / 3) / 2))
