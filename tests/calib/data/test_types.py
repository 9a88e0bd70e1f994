"""``calib.data.types.MemorySequence``: frames in memory behave as a Sequence."""

import numpy as np
import pytest

from calib.data.types import Calibration, Frame, MemorySequence, Sequence
from calib.errors import DataError


def test_memory_sequence_indexes_and_times_its_frames():
    calibration = Calibration(K=np.eye(3), T_cam_lidar=np.eye(4))
    frames = [
        Frame(np.zeros((4, 4, 3), np.uint8), np.zeros((1, 4), np.float32), calibration, i, timestamp=0.1 * i)
        for i in range(3)
    ]
    seq = MemorySequence(frames, calibration, "three")
    assert isinstance(seq, Sequence) and len(seq) == 3 and seq.layout == "memory"
    assert seq[-1] is frames[2] and [f.index for f in seq] == [0, 1, 2]
    assert np.allclose(seq.timestamps, [0.0, 0.1, 0.2])
    with pytest.raises(IndexError):
        seq[3]


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("distortion", [0.1, 0.01, 0.001], "distortion must be 4, 5, 8, 12, 14 finite"),
        ("distortion", [np.nan, 0, 0, 0, 0], "distortion must be"),
        ("distortion", ["a", "b"], "distortion is not a list of numbers"),
        ("image_size", (0, -5), "image_size must be two positive whole numbers"),
        ("image_size", (370.5, 1224), "image_size must be two positive whole numbers"),
    ],
)
def test_calibration_refuses_what_opencv_or_the_image_cannot_take(field, value, message):
    with pytest.raises(DataError, match=message):
        Calibration(K=np.eye(3), source="calib.yaml", **{field: value})
    assert Calibration(K=np.eye(3), distortion=[0.1, 0, 0, 0], image_size=(370, 1224)).image_size == (
        370,
        1224,
    )


def test_images_of_another_size_than_the_calibration_states_are_refused(tmp_path):
    """A KITTI raw drive whose images were resized: its K is for S_rect's size, so the first
    frame read is refused, naming both sizes, rather than checked or calibrated with the wrong K."""
    import cv2

    from calib.data import open_dataset
    from tests.calib.data.test_readers import _write_kitti_raw
    from tests.conftest import make_frames

    frames = make_frames(2)
    date, _ = _write_kitti_raw(tmp_path, frames)  # S_rect_02: 624 x 188
    for png in date.rglob("image_02/data/*.png"):
        cv2.imwrite(str(png), cv2.resize(cv2.imread(str(png)), (312, 94)))
    with (
        open_dataset(date) as seq,
        pytest.raises(DataError, match="image is 312x94 but the calibration .* is for 624x188"),
    ):
        seq[0]
