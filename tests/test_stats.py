"""aobake.stats: the quantiles and the error-bar construction, against scipy and by hand."""

import numpy as np
import pytest
from scipy import special

from aobake import stats


@pytest.mark.parametrize("confidence", [0.5, 0.8, 0.9, 0.95, 0.99, 0.999])
def test_t_quantile_matches_scipy(confidence):
    dofs = [*range(1, 64), 100, 255, 1023, 4095, 10**6]
    ours = stats.t_quantile(confidence, np.array(dofs, dtype=float))
    ref = special.stdtrit(np.array(dofs), 0.5 + confidence / 2)
    np.testing.assert_allclose(ours, ref, rtol=1e-8)
    assert stats.t_quantile(confidence, 7.9) == stats.t_quantile(confidence, 7)  # rounded down


def test_normal_quantile():
    assert stats.normal_quantile(0.95) == pytest.approx(1.959963984540054, rel=1e-12)


def test_error_bars_rule_of_three_when_all_rays_agree():
    n = 256
    mean = np.array([1.0, 0.0, 0.5])
    se = np.array([0.0, 0.0, 0.02])
    stderr, low, high = stats.error_bars(mean, se, n, 7, 0.95)
    h0 = 1 - 0.05 ** (1 / n)
    np.testing.assert_allclose(stderr, [1 / n, 1 / n, 0.02])
    np.testing.assert_allclose(low, [1 - h0, 0.0, 0.5 - np.hypot(stats.t_quantile(0.95, 7) * 0.02, h0)])
    np.testing.assert_allclose(high[:2], [1.0, h0])
    assert h0 == pytest.approx(-np.log(0.05) / n, rel=0.01)  # the "rule of three", ~3/n


def test_error_bars_without_spread_is_the_whole_range():
    stderr, low, high = stats.error_bars(np.array([1.0]), np.array([0.5]), 1, 0, 0.95)
    assert low[0] == 0.0 and high[0] == 1.0 and stderr[0] == 0.5


def test_exact_values_have_zero_width():
    stderr, low, high = stats.exact(np.array([1.0, 0.3]))
    assert np.all(stderr == 0) and np.array_equal(low, high)


def test_the_ratio_spread_is_the_replicate_means_spread_where_counts_are_equal():
    """With every replicate counting n values, the ratio estimator is the mean of the
    replicate means and its linearised stderr their sample spread over sqrt(G), exactly;
    a pixel where one replicate counted anything has nothing to measure (dof 0)."""
    rng = np.random.default_rng(5)
    groups, n = 4, 16
    y = rng.binomial(n, 0.3, size=(50, groups)).astype(np.float64)
    c = np.full((50, groups), float(n))
    mean = y.sum(axis=1) / c.sum(axis=1)
    se, dof = stats.ratio_spread(y, c, mean)
    np.testing.assert_allclose(se, np.std(y / n, axis=1, ddof=1) / np.sqrt(groups),
                               rtol=1e-12)
    assert (dof == groups - 1).all()
    c[0, 1:] = 0.0
    y[0, 1:] = 0.0
    assert stats.ratio_spread(y, c, y.sum(axis=1) / np.maximum(c.sum(axis=1), 1))[1][0] == 0


def test_pooled_error_bars_without_a_spread_are_the_worst_case():
    mean = np.array([0.3, 0.3])
    se = np.array([0.01, 0.0])
    dof = np.array([3, 0])
    err, low, high = stats.pooled_error_bars(mean, se, dof, np.array([16.0, 16.0]),
                                             np.array([64, 64]), False, 0.95)
    assert err[0] == 0.01 and err[1] == 0.5 / 4.0  # 0.5 / sqrt(16 positions)
    assert (low[1], high[1]) == (0.0, 1.0)
    exact = stats.pooled_error_bars(mean, se, dof, np.array([16.0, 16.0]),
                                    np.array([64, 64]), True, 0.95)
    assert (exact[0] == 0).all() and (exact[1] == mean).all() and (exact[2] == mean).all()
