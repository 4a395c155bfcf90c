"""The reported standard error is honest: over many seeds, the spread of the
estimate matches it, for every sampler.

Statistic: with K seeds, (K - 1) * var_observed / sigma^2 ~ chi2(K - 1), and the
mean of the reported stderr^2 estimates sigma^2 (unbiased for every sampler).
The test accepts the ratio var_observed / mean(stderr^2) inside the chi-square
interval at 1e-4, widened by the uncertainty of mean(stderr^2) itself.
"""

import math

import numpy as np
import pytest
from scipy import stats

import aobake
from analytic import combine, polygon, quad

K = 150


@pytest.mark.parametrize("sampler", ["random", "stratified", "sobol"])
@pytest.mark.parametrize("quantity", ["ao", "obscurance"])
def test_stderr_matches_spread_over_seeds(sampler, quantity):
    # A point under a tilted disc: a visibility boundary that no grid aligns with.
    mesh = combine(polygon([0.2, 0.1, 0.8], 1.0, 17), quad([0, 0, 0], 3, 3))
    pts = np.array([[0.0, 0.0, 1e-6], [0.9, -0.4, 1e-6]])
    nrm = np.tile([0, 0, 1.0], (2, 1))
    est, var = [], []
    for seed in range(K):
        res = aobake.bake_points(mesh, pts, nrm, rays=64, seed=seed, sampler=sampler,
                                 quantities=(quantity,), max_distance=2.0, tau=1.5, threads=1)
        est.append(getattr(res, quantity))
        var.append(getattr(res, quantity + "_stderr") ** 2)
    est, var = np.array(est), np.array(var)
    for p in range(len(pts)):
        observed = est[:, p].var(ddof=1)
        reported = var[:, p].mean()
        ratio = observed / reported
        lo = stats.chi2.ppf(1e-4 / 2, K - 1) / (K - 1)
        hi = stats.chi2.ppf(1 - 1e-4 / 2, K - 1) / (K - 1)
        # mean(stderr^2) has relative error ~ std(stderr^2) / (mean sqrt(K)); widen by 4 of those.
        rel = var[:, p].std(ddof=1) / (reported * math.sqrt(K))
        assert lo / (1 + 4 * rel) <= ratio <= hi * (1 + 4 * rel), (sampler, quantity, p, ratio)
