from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calib.data import Calibration, Frame
from calib.data.real_fixtures import realdata_root

KITTI_K = np.array([[360.0, 0.0, 311.5], [0.0, 360.0, 93.5], [0.0, 0.0, 1.0]])


def kitti_like_extrinsic() -> np.ndarray:
    """LiDAR (x forward, y left, z up) -> camera (x right, y down, z forward), KITTI-like offset."""
    T = np.eye(4)
    T[:3, :3] = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    T[:3, 3] = [0.01, -0.08, -0.27]
    return T


def make_frames(n: int = 3, seed: int = 0, size: tuple[int, int] = (188, 624)) -> list[Frame]:
    """Random frames with one KITTI-like calibration: images, points in front, labels."""
    rng = np.random.default_rng(seed)
    calibration = Calibration(K=KITTI_K, T_cam_lidar=kitti_like_extrinsic(), image_size=size)
    frames = []
    for i in range(n):
        points = np.column_stack(
            [
                rng.uniform(2, 30, 500),
                rng.uniform(-10, 10, 500),
                rng.uniform(-1.5, 2, 500),
                rng.uniform(0, 1, 500),
            ]
        ).astype(np.float32)
        frames.append(
            Frame(
                image=rng.integers(0, 255, (*size, 3), dtype=np.uint8),
                points=points,
                calibration=calibration,
                index=i,
                timestamp=100.0 + 0.1 * i,
                labels=rng.choice([10, 40, 50, 70, 80], 500).astype(np.uint16),
                image_labels=rng.choice([10, 40, 50, 70, 80], size).astype(np.uint16),
            )
        )
    return frames


@pytest.fixture
def frames() -> list[Frame]:
    return make_frames()


@pytest.fixture(scope="session")
def realdata() -> Path:
    root = realdata_root()
    if root is None:
        pytest.skip("real fixtures absent: ../shared/realdata not found and SUPPORTNET_REALDATA unset")
    return root
