import numpy as np
import pytest

from calib.refine.sgis import support_sample, uniform_sample


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
