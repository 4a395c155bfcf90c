"""The reported standard error is honest: over many seeds, the spread of the
estimate matches it, for every sampler.

Statistic: with K seeds, (K - 1) * var_observed / sigma^2 ~ chi2(K - 1), and the
mean of the reported stderr^2 estimates sigma^2 (unbiased for every sampler).
The test accepts the ratio var_observed / mean(stderr^2) inside the chi-square
interval at 1e-4, widened by the uncertainty of mean(stderr^2) itself.
"""

import functools
import math

import numpy as np
import pytest
from scipy import stats

import aobake
from aobake.samplers.base import REPLICATES
from analytic import combine, polygon, quad, up

#: statistical: many seeds per case (the fast tier, pytest -m "not slow", skips them)
pytestmark = pytest.mark.slow

K = 150


def assert_calibrated(observed: float, stderr2: np.ndarray, label) -> None:
    """observed variance over K seeds vs the K reported stderr^2 values (K,)."""
    reported = stderr2.mean()
    ratio = observed / reported
    lo = stats.chi2.ppf(1e-4 / 2, K - 1) / (K - 1)
    hi = stats.chi2.ppf(1 - 1e-4 / 2, K - 1) / (K - 1)
    # mean(stderr^2) has relative error ~ std(stderr^2) / (mean sqrt(K)); widen by 4 of those.
    rel = stderr2.std(ddof=1) / (reported * math.sqrt(K))
    assert lo / (1 + 4 * rel) <= ratio <= hi * (1 + 4 * rel), (label, ratio)


#: two floor points under a tilted disc: a visibility boundary that no grid aligns with
POINTS = np.array([[0.0, 0.0, 1e-6], [0.9, -0.4, 1e-6]])


@functools.lru_cache(maxsize=None)
def bakes_over_seeds(sampler: str, quantity: str) -> list:
    """K bakes (seeds 0..K-1) of POINTS under a tilted disc (cached: each point's test
    reads the same bakes).  Bent normals come with AO: its escape counts give the degrees
    of freedom of their stderr."""
    mesh = combine(polygon([0.2, 0.1, 0.8], 1.0, 17), quad([0, 0, 0], 3, 3))
    nrm = up(len(POINTS))
    quantities = ("ao", quantity) if quantity == "bent-normal" else (quantity,)
    return [aobake.bake_points(mesh, POINTS, nrm, rays=64, seed=seed, sampler=sampler,
                               quantities=quantities, max_distance=2.0, tau=1.5, threads=1)
            for seed in range(K)]


@pytest.mark.parametrize("point", range(len(POINTS)))
@pytest.mark.parametrize("quantity", ["ao", "obscurance"])
def test_stderr_matches_spread_over_seeds(sampler, quantity, point):
    results = bakes_over_seeds(sampler, quantity)
    est = np.array([getattr(res, quantity)[point] for res in results])
    var = np.array([getattr(res, quantity + "_stderr")[point] ** 2 for res in results])
    assert_calibrated(est.var(ddof=1), var, (sampler, quantity, point))


@pytest.mark.parametrize("point", range(len(POINTS)))
def test_bent_normal_angular_stderr_matches_spread_over_seeds(sampler, point):
    """The reported angular stderr (radians) matches the angles by which the bent normal
    scatters around its mean over seeds.

    The scatter is 2-D (the tangent plane of the mean direction): sum over seeds of the
    squared angle / sigma^2 has between K - 1 and 2 (K - 1) degrees of freedom depending
    on how round the error ellipse is; the test uses the wider chi2(K - 1) interval.

    The reported stderr is the measured one raised by t_nu(C) / z(C) for its nu degrees of
    freedom (escaping rays - 1 with ``random``; R - 1 with QMC, where at 64 rays each of the
    R replicates of 64 / R rays has an escape at these points, AO 0.41 and 0.62), so that
    z(C) of it is a cone at C (aobake.stats.normal_equivalent; that coverage is
    tests/test_bent_normal_coverage.py); the raise is divided out here.
    """
    results = bakes_over_seeds(sampler, "bent-normal")
    bent = np.array([res.bent_normal[point] for res in results])  # (K, 3)
    reported = np.array([res.bent_normal_stderr[point] for res in results])  # (K,)
    assert np.all(reported > 0) and np.all(reported < np.pi / 2)
    if sampler == "random":
        dof = np.array([round(res.ao[point] * res.rays[point]) - 1 for res in results])
    else:
        dof = np.full(K, min(REPLICATES, 64) - 1)
    raise_ = stats.t.ppf(0.975, dof) / stats.norm.ppf(0.975)  # the default confidence 0.95
    var = (reported / raise_) ** 2
    mean = bent.mean(axis=0)
    mean /= np.linalg.norm(mean)
    perp = bent - np.outer(bent @ mean, mean)  # ~ angle vectors, radians
    assert_calibrated(np.square(perp).sum() / (K - 1), var, (sampler, point))
