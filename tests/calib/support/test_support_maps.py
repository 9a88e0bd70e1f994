import numpy as np
import pytest

from calib.errors import DataError
from calib.match.correspondences import Correspondences
from calib.support.support_maps import SupportConfig, gaussian_sum, residual_score, support_maps
from calib.yaml_io import validate


def direct_sum(uv, weights, image_size, sigma):
    """Eq. 2 as written: a Gaussian per point evaluated at every pixel."""
    y, x = np.mgrid[0 : image_size[0], 0 : image_size[1]]
    return sum(
        w * np.exp(-((x - u) ** 2 + (y - v) ** 2) / (2 * sigma**2))
        for (u, v), w in zip(uv, weights, strict=True)
    )


def correspondences(uv, residual, confidence=None, size=(30, 40)):
    n = len(uv)
    conf = np.ones(n, np.float32) if confidence is None else confidence
    return Correspondences(np.arange(n), np.zeros((n, 3)), uv, uv + residual, conf, size)


@pytest.mark.parametrize(("sigma", "tolerance"), [(2.0, 0.03), (3.5, 0.006), (6.0, 0.002)])
def test_splatting_equals_the_direct_sum_of_eq2(sigma, tolerance):
    rng = np.random.default_rng(1)
    uv = rng.uniform([-2, -2], [41, 31], (60, 2))  # some just outside the image
    weights = rng.uniform(0, 1, 60)
    direct = direct_sum(uv, weights, (30, 40), sigma)
    fast = gaussian_sum(uv, weights, (30, 40), sigma)
    assert fast.shape == (30, 40)
    np.testing.assert_allclose(fast, direct, atol=tolerance * direct.max())


def test_gaussian_sum_rejects_bad_shapes_and_sigma():
    with pytest.raises(ValueError, match="uv"):
        gaussian_sum(np.zeros((3, 3)), np.ones(3), (5, 5), 2.0)
    with pytest.raises(ValueError, match="sigma"):
        gaussian_sum(np.zeros((3, 2)), np.ones(3), (5, 5), 0.0)


def test_scores_fall_with_the_residual():
    uv = np.array([[5.0, 5.0], [10.0, 10.0], [20.0, 20.0]])
    c = correspondences(
        uv, np.array([[0.0, 0.0], [1.5, 0.0], [3.0, 4.0]]), np.array([1.0, 0.5, 0.2], np.float32)
    )
    for score in ("gaussian", "cauchy", "gaussian_confidence"):
        a = residual_score(c, SupportConfig(score=score, tau_px=1.5))
        assert a[0] == pytest.approx(1.0) and a[0] > a[1] > a[2] >= 0
    gauss = residual_score(c, SupportConfig(score="gaussian", tau_px=1.5))
    assert gauss[1] == pytest.approx(np.exp(-0.5))
    np.testing.assert_allclose(residual_score(c, SupportConfig(score="confidence")), [1.0, 0.5, 0.2])


def test_agreement_does_not_grow_with_density_but_the_raw_sum_does():
    rng = np.random.default_rng(2)
    sparse = rng.uniform([0, 0], [20, 30], (40, 2))  # left half: 40 points, all exact
    dense = rng.uniform([20, 0], [40, 30], (400, 2))  # right half: 10x denser, all exact
    uv = np.vstack([sparse, dense])
    maps = support_maps(correspondences(uv, np.zeros_like(uv)), SupportConfig(sigma_px=3.0))
    assert maps.support.max() == pytest.approx(1.0)
    assert maps.support[10:20, 25:35].mean() > 3 * maps.support[10:20, 5:15].mean()
    covered = maps.coverage >= maps.min_coverage
    np.testing.assert_allclose(maps.agreement[covered], 1.0, atol=1e-6)
    # residuals of 3 px on the right: agreement there drops to exp(-9 / (2 * 1.5²)) ≈ 0.135
    residual = np.where(uv[:, :1] >= 20, 3.0, 0.0) * np.array([[1.0, 0.0]])
    maps = support_maps(correspondences(uv, residual), SupportConfig(sigma_px=3.0, tau_px=1.5))
    assert maps.agreement[15, 32] == pytest.approx(np.exp(-2.0), abs=1e-3)
    assert maps.agreement[15, 8] == pytest.approx(1.0, abs=1e-3)
    both = maps + maps
    np.testing.assert_allclose(both.agreement, maps.agreement, atol=1e-6)


def test_support_config_typo_fails_loudly():
    with pytest.raises(DataError, match="sigma"):
        validate(SupportConfig, {"sigma": 3}, "maps.yaml")
