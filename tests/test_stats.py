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
