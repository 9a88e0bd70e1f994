"""The predicted support's per-frame memory: a frame is its image, not its position or name."""

from collections import deque
from types import SimpleNamespace

import numpy as np

from calib.data.types import Calibration, Frame
from supportnet.runtime.support_sources import PredictedSupport


class MeanPredictor:
    """A stand-in model whose map is the image's mean everywhere (each image its own value)."""

    contract = SimpleNamespace(extra={})

    def predict(self, image: np.ndarray) -> np.ndarray:
        return np.full((1, *image.shape[:2]), float(image.mean()), np.float32)


def test_a_stream_of_caller_built_frames_never_gets_another_images_map():
    """Frames built by a caller (index 0, no name) through a window of five, each image freed when
    it leaves: Python hands a new image the id of a freed one, which an id-keyed memory took for
    the old image (53 of 200 maps stale in the review's run)."""
    support = PredictedSupport("onnx", MeanPredictor())
    calibration = Calibration(K=np.eye(3))
    window = deque(maxlen=5)
    stale = 0
    for k in range(200):
        frame = Frame(np.full((8, 12, 3), k % 250, np.uint8), np.zeros((1, 4), np.float32), calibration)
        window.append(frame)
        stale += int(support(frame)[0, 0] != k % 250)
    assert stale == 0
