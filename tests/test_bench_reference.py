"""benchmarks/bench_reference.py's rotation fit, on exact correspondences with a known turn."""

from __future__ import annotations

import sys
from pathlib import Path

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
