import numpy as np
import pytest

from calib.refine.passes import SamplingConfig, draw
from calib.refine.sgis import depth_strata, stratified_support_sample, support_sample, uniform_sample


def test_first_draw_follows_the_support_exactly():
    """With k = 1 the draw is categorical with p_i = s_i / Σ s (Eq. 3)."""
    support = np.array([0.0, 1.0, 2.0, 5.0])
    rng = np.random.default_rng(0)
    counts = np.bincount([support_sample(support, 1, rng)[0] for _ in range(20000)], minlength=4)
    np.testing.assert_allclose(counts / 20000, support / support.sum(), atol=0.01)
    assert counts[0] == 0  # zero support is never drawn without a floor


def test_draws_are_distinct_and_without_replacement_probabilities_hold():
    """Second-draw marginal of a 2-of-3 weighted sample: P(i in sample) = p_i + Σ_j p_j p_i / (1 − p_j)."""
    support = np.array([1.0, 2.0, 7.0])
    p = support / support.sum()
    expected = p + np.array([sum(p[j] * p[i] / (1 - p[j]) for j in range(3) if j != i) for i in range(3)])
    rng = np.random.default_rng(1)
    hits = np.zeros(3)
    for _ in range(20000):
        chosen = support_sample(support, 2, rng)
        assert len(set(chosen)) == 2
        hits[chosen] += 1
    np.testing.assert_allclose(hits / 20000, expected, atol=0.01)


def test_floor_makes_zero_support_possible_and_k_is_capped():
    rng = np.random.default_rng(2)
    assert len(support_sample(np.zeros(5), 3, rng)) == 0
    assert len(support_sample(np.zeros(5), 3, rng, floor=0.01)) == 3
    assert list(support_sample(np.array([0.0, 1.0, 1.0]), 10, rng)) == [1, 2]
    assert sorted(uniform_sample(4, 10, rng)) == [0, 1, 2, 3]


def test_sampler_errors():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="non-negative"):
        support_sample(np.array([1.0, -1.0]), 1, rng)
    with pytest.raises(ValueError, match=r"\(N,\)"):
        support_sample(np.ones((2, 2)), 1, rng)
    with pytest.raises(ValueError, match="non-negative"):
        uniform_sample(3, -1, rng)


def test_a_hundred_thousand_candidates_sample_fast_enough_to_not_matter():
    rng = np.random.default_rng(3)
    chosen = support_sample(rng.random(100_000), 2000, rng)
    assert chosen.shape == (2000,) and len(np.unique(chosen)) == 2000


def test_depth_strata_are_equal_quantiles_nearest_first():
    depth = np.array([9.0, 1.0, 5.0, 3.0, 7.0, 2.0, 8.0, 4.0])
    np.testing.assert_array_equal(depth_strata(depth, 4), [3, 0, 2, 1, 2, 0, 3, 1])
    np.testing.assert_array_equal(depth_strata(depth, 1), np.zeros(8))
    sizes = np.bincount(depth_strata(np.random.default_rng(0).random(1001), 4))
    assert sizes.tolist() == [251, 250, 250, 250]
    with pytest.raises(ValueError, match="at least 1"):
        depth_strata(depth, 0)
    with pytest.raises(ValueError, match="finite"):
        depth_strata(np.array([1.0, np.inf]), 2)


def test_each_depth_stratum_keeps_uniform_sampling_share_and_support_chooses_within():
    """Support all on the far half: plain SGIS takes nearly nothing near, the stratified draw takes
    each quarter's 25 of 100, and within a quarter only the points of support (no floor)."""
    rng = np.random.default_rng(4)
    depth = rng.uniform(1, 50, 1000)
    strata = depth_strata(depth, 4)
    support = np.where(strata >= 2, 1.0, 0.0)
    support[(strata == 0) & (np.arange(1000) % 2 == 0)] = 0.2  # half of the nearest quarter
    plain = support_sample(support, 100, rng)
    chosen = stratified_support_sample(support, strata, 100, rng)
    assert np.bincount(strata[plain], minlength=4)[:2].sum() < 10
    assert np.bincount(strata[chosen], minlength=4).tolist() == [25, 0, 25, 25]  # quarter 1: no support
    assert (support[chosen] > 0).all() and len(np.unique(chosen)) == len(chosen)
    floored = stratified_support_sample(support, strata, 100, rng, floor=0.01)
    assert np.bincount(strata[floored], minlength=4).tolist() == [25, 25, 25, 25]
    with pytest.raises(ValueError, match="shape"):
        stratified_support_sample(support, strata[:10], 100, rng)


def test_stratified_draws_weigh_each_stratum_to_mean_one():
    """Eq. 4 weights scaled per stratum: the support ranks points within a depth, not across."""
    rng = np.random.default_rng(5)
    depth = rng.uniform(1, 50, 4000)
    support = np.where(depth > 25, 0.9, 0.1)
    config = SamplingConfig(per_frame=400, depth_strata=2)
    index, weight = draw(support, len(depth), config, rng, depth)
    near = depth_strata(depth, 2)[index] == 0
    assert near.sum() == 200
    np.testing.assert_allclose([weight[near].mean(), weight[~near].mean()], [1.0, 1.0])
    plain, plain_weight = draw(support, len(depth), SamplingConfig(per_frame=400), rng)
    np.testing.assert_allclose(plain_weight, support[plain] + config.floor)  # Eq. 4 as before
    with pytest.raises(ValueError, match="depth"):
        draw(support, len(depth), config, rng)
