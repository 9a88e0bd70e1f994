"""``calib.data.types.MemorySequence``: frames in memory behave as a Sequence."""

import numpy as np
import pytest

from calib.data.types import Calibration, Frame, MemorySequence, Sequence


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
