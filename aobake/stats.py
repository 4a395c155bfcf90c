"""Standard errors of Monte-Carlo means, and their aggregation over texel samples.

Two kinds of sample sets (``SampleSet.iid``):

* i.i.d. rays (``random``): the per-ray sample variance is honest,
  stderr = sqrt(s^2 / n).
* randomised QMC (``stratified``, ``sobol``): the rays of one replicate are not
  independent, the R replicates are; stderr = sqrt(var(replicate means) / R).

With a single ray or a single replicate there is no spread to measure; the error
reported then is the worst case for a contribution in [0, 1], 1 / (2 sqrt(n)), and the
interval is [0, 1].  ``error_bars`` turns a measured spread into the reported stderr
and interval.
"""

from __future__ import annotations

import functools
import math

import numpy as np


def mean_and_spread(f: np.ndarray, iid: bool):
    """f (k, R, m) per-ray contributions in [0, 1] -> (mean (k,), se (k,), dof) float64.

    ``se`` is the measured standard error (0 when every ray or replicate agrees), ``dof``
    its degrees of freedom (n - 1 i.i.d., R - 1 replicates; 0 = nothing to measure).
    """
    total, m2 = sums(f, iid)
    return spread_of_sums(total, m2, f.shape[2], iid)


def sums(f: np.ndarray, iid: bool):
    """f (k, R, m) -> (total (k, R), m2 (k, R)) float64: the additive statistics of each
    replicate's m contributions, their sum and (i.i.d. only, else 0) the sum of squared
    deviations from their mean.  Rays streamed in pieces combine with :func:`merge_sums`."""
    m = f.shape[2]
    f = f.astype(np.float64)
    total = f.sum(axis=2)
    if not iid:
        return total, np.zeros_like(total)
    return total, np.square(f - (total / m)[..., None]).sum(axis=2)


def merge_sums(a: tuple, b: tuple, na: int, nb: int) -> tuple:
    """The (total, m2) of na contributions ``a`` followed by nb contributions ``b`` (Chan et
    al.'s pairwise update: no cancellation, whatever the count)."""
    delta = b[0] / nb - a[0] / na
    return a[0] + b[0], a[1] + b[1] + np.square(delta) * (na * nb / (na + nb))


def spread_of_sums(total: np.ndarray, m2: np.ndarray, m: int, iid: bool):
    """(mean, se, dof) of replicates of m contributions from their :func:`sums`."""
    k, groups = total.shape
    n = groups * m
    if iid:
        mean = total.sum(axis=1) / n
        if n < 2:
            return mean, np.full(k, 1.0 / (2.0 * np.sqrt(n))), 0
        var = m2.sum(axis=1) / (n - 1)
        return mean, np.sqrt(var / n), n - 1
    return replicate_spread(total / m, n)


def replicate_spread(group_means: np.ndarray, n: int):
    """group_means (k, R) float64 replicate means of n rays in all -> (mean, se, dof)."""
    k, groups = group_means.shape
    mean = group_means.sum(axis=1) / groups
    if groups < 2:
        return mean, np.full(k, 1.0 / (2.0 * np.sqrt(n))), 0
    var = np.square(group_means - mean[:, None]).sum(axis=1) / (groups - 1)
    return mean, np.sqrt(var / groups), groups - 1


def binary_spread(counts: np.ndarray, m: int, iid: bool):
    """mean_and_spread for 0/1 contributions from exact counts.

    counts : (k, R) float64 number of 1s among the m rays of each replicate.
    """
    k, groups = counts.shape
    n = groups * m
    if iid:
        # i.i.d. 0/1 samples: sample variance = n/(n-1) p (1 - p).
        mean = counts.sum(axis=1) / n
        if n < 2:
            return mean, np.full(k, 1.0 / (2.0 * np.sqrt(n))), 0
        return mean, np.sqrt(mean * (1.0 - mean) / (n - 1)), n - 1
    return replicate_spread(counts / m, n)


def rule_of_three(n, confidence: float):
    """Half-width no interval over n rays may fall below: 1 - (1 - C)^(1/n), about 3/n at 95%.

    If every one of n rays misses a region (the spread sees nothing), the region's weight
    is below this with confidence C, whatever the sampler (P(all miss) <= (1 - p)^n).
    """
    return 1.0 - (1.0 - confidence) ** (1.0 / np.asarray(n, dtype=np.float64))


def error_bars(mean: np.ndarray, se: np.ndarray, n, dof, confidence: float):
    """The reported error and interval of a mean of n rays in [0, 1] with measured se.

    Returns (stderr, low, high), each (k,) float64:

    * stderr = se where the spread is measured, 1/n where it is 0 (every ray or replicate
      agrees: 1/n is the resolution of n rays, and for 0/1 contributions the smallest
      nonzero spread there is, so this is max(se, 1/n) for AO): one standard error,
      RMS-calibrated where the value is not at a visibility extreme, never 0 where the
      value can be wrong;
    * [low, high] = clip(mean -+ h, 0, 1) with h = sqrt((t se)^2 + h0^2), t the Student
      quantile with ``dof`` degrees of freedom and h0 = ``rule_of_three(n)``: the t
      interval where the spread is informative, the rule of three where it is not (all
      rays or replicates agree).  Measured coverage: docs/conventions.md.
    ``dof`` may be an array (texels); dof < 1 (nothing to measure) gives [0, 1].
    """
    n = np.asarray(n, dtype=np.float64)
    stderr = np.where(se > 0, se, 1.0 / n)
    dof = np.asarray(dof, dtype=np.float64)
    t = t_quantile(confidence, np.maximum(dof, 1.0))
    h = np.sqrt(np.square(t * se) + np.square(rule_of_three(n, confidence)))
    h = np.where(dof >= 1, h, 1.0)
    return stderr, np.clip(mean - h, 0.0, 1.0), np.clip(mean + h, 0.0, 1.0)


def ratio_spread(y: np.ndarray, c: np.ndarray, mean: np.ndarray):
    """The standard error of a ratio estimator over G replicates: (se (k,), dof (k,)).

    y (k, G) float64 each replicate's sum of values, c (k, G) its count of values (rays
    of a pixel's covered positions), mean (k,) the pooled ratio sum(y) / sum(c).  The
    linearised (delta-method) variance of sum_g Y_g / sum_g C_g: sum_g (Y_g - v C_g)^2 /
    (G (G - 1) Cbar^2), Cbar the mean count; G - 1 degrees of freedom where at least two
    replicates counted any value, else 0 (nothing to measure).  A box-filtered pixel's
    error (``aobake.targets.view``, ``aobake.targets.view_box``): the replicates are
    independent, the count of each (the part of the pixel it saw) random."""
    groups = y.shape[1]
    z = y - mean[:, None] * c
    c_bar = c.sum(axis=1) / groups
    c_bar = np.where(c_bar > 0, c_bar, 1.0)  # (a pixel that counted nothing is blank)
    se = np.sqrt(np.square(z).sum(axis=1) / (groups * max(groups - 1, 1) * np.square(c_bar)))
    dof = np.where(np.count_nonzero(c, axis=1) >= 2, groups - 1, 0)
    return se, dof


def pooled_error_bars(mean: np.ndarray, se: np.ndarray, dof, units: np.ndarray,
                      rays: np.ndarray, exact_value: bool, confidence: float):
    """(stderr, low, high) (k,) float64 of pooled means (a box-filtered pixel's) with a
    measured ``se`` on ``dof`` (k,) degrees of freedom: where dof < 1 the worst case 0.5 /
    sqrt(units); the interval's rule of three over ``units`` (k,) (the pixel's covered
    positions); a zero spread's stderr the resolution 1 / ``rays`` (k,) of the values
    pooled, as a point's is; ``exact_value`` (every ray gives the same answer): 0 and
    [mean, mean]."""
    if exact_value:
        return exact(mean)
    se = np.where(dof >= 1, se, 0.5 / np.sqrt(units))  # nothing to measure: worst case
    error = error_bars(mean, se, units, dof, confidence)
    return (np.where(se > 0, se, 1.0 / np.maximum(rays, 1)),) + error[1:]


def normal_equivalent(se: np.ndarray, dof, confidence: float) -> np.ndarray:
    """se (k,) measured on ``dof`` (k,) degrees of freedom (>= 1) -> (k,) se t_dof(C) / z(C).

    The standard error whose normal interval +-z(C) at ``confidence`` C is se's Student
    interval +-t_dof(C) se: for an error reported as one number with no interval of its own
    (the bent normal's angle), so that z(C) of it covers C although se was measured on few
    degrees of freedom (with 4 replicates, dof 3: 1.62 se at C = 0.95; -> se as dof grows).
    """
    dof = np.floor(np.asarray(dof, dtype=np.float64)).clip(1.0, None)
    z = normal_quantile(confidence)
    few = dof < SERIES_DOF
    t = np.where(few, t_quantile(confidence, np.where(few, dof, 1.0)), _t_series(z, dof))
    return se * (t / z)


#: from this many degrees of freedom on, :func:`normal_equivalent` takes t from its
#: Cornish-Fisher series (within 1e-8 of the exact quantile at 100 dof, 1e-12 at 1000:
#: t_quantile's own accuracy) instead of the exact inversion, which costs ~2 ms a value
#: above ~1000 dof and a ``random`` bake's bent normals have one dof per escape count
SERIES_DOF = 100


def exact(mean: np.ndarray):
    """(stderr, low, high) of a value that is exact by construction: 0 and [mean, mean]."""
    return np.zeros_like(mean), mean.copy(), mean.copy()


def texel_stderr(variance_sum: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Standard error of a texel that averages its s sample estimates: sqrt(sum se^2) / s.

    variance_sum : (H, W) float64 mean of se^2 over the texel's samples (``splat``),
    count : (H, W) int samples per texel.  Empty texels get 0 (masked by coverage).
    """
    return np.sqrt(variance_sum / np.maximum(count, 1))


def summary(stderr: np.ndarray) -> dict:
    """Mean and 95th percentile of (n,) standard errors (np.percentile's value, found a
    block at a time by ``aobake.select``: np.percentile partitions a copy, 8 bytes a point
    of every point baked)."""
    from aobake import select

    if stderr.dtype != np.float64:  # (np.percentile works in the array's own precision)
        return {"stderr_mean": float(stderr.mean()),
                "stderr_p95": float(np.percentile(stderr, 95))}
    return {"stderr_mean": float(stderr.mean()),
            "stderr_p95": float(select.percentile(select.of_array(stderr), 95))}


# --------------------------------------------------------------------------- intervals
#
# Every ao / obscurance value comes with a two-sided interval at ``confidence``
# (``*_ci_low``, ``*_ci_high``), built to keep its coverage with few rays and at
# the extremes (docs/conventions.md, "Error bars", has the measured coverage).


def normal_quantile(confidence: float) -> float:
    """z with P(|N(0,1)| <= z) = confidence."""
    from statistics import NormalDist

    return NormalDist().inv_cdf(0.5 + confidence / 2.0)


def t_quantile(confidence: float, dof):
    """t with P(|T_dof| <= t) = confidence (Student t), for dof >= 1, scalar or array.

    Non-integer dof are rounded down (a larger, conservative t).  Hand-written rather than
    scipy.stats.t.ppf: importing scipy.stats costs 0.66 s (scipy.special 0.19 s) per
    process, measured, most of a small bake; this is the exact quantile (Newton on the
    regularized incomplete beta, tested against scipy to 1e-8) in plain Python, so
    scipy is not a dependency of the package (only of its tests).
    """
    dof = np.floor(np.asarray(dof, dtype=np.float64)).clip(1.0, None)
    if dof.ndim == 0:
        return _t_quantile(float(confidence), float(dof))
    top = float(dof.max()) if dof.size else 1.0
    if top <= _TABLE_DOF:
        # A texture's dof are small integers: index a table by them (a sort-based unique of
        # a 1024^2 image took 0.17 s; the table lookup 0.01 s, the same values).
        whole = dof.astype(np.int64)
        table = np.zeros(int(top) + 1)
        for v in np.flatnonzero(np.bincount(whole.reshape(-1), minlength=len(table))):
            table[v] = _t_quantile(float(confidence), float(v))
        return table[whole]
    levels, inverse = np.unique(dof, return_inverse=True)
    values = np.array([_t_quantile(float(confidence), float(v)) for v in levels])
    return values[inverse].reshape(dof.shape)


#: t_quantile looks dof up in a table up to this many degrees of freedom (larger: unique)
_TABLE_DOF = 1 << 20


def _betacf(a: float, b: float, x: float) -> float:
    """Continued fraction of the incomplete beta function (modified Lentz)."""
    tiny = 1e-300
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 500):
        m2 = 2 * m
        for aa in (m * (b - m) * x / ((a + m2 - 1.0) * (a + m2)),
                   -(a + m) * (a + b + m) * x / ((a + m2) * (a + m2 + 1.0))):
            d = 1.0 + aa * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + aa / c
            c = c if abs(c) > tiny else tiny
            h *= d * c
        if abs(d * c - 1.0) < 1e-15:
            break
    return h


def _t_upper(t: float, v: float) -> float:
    """P(T_v > t) for t >= 0: I_{v / (v + t^2)}(v/2, 1/2) / 2."""
    x = v / (v + t * t)
    a, b = v / 2.0, 0.5
    if x <= 0.0:
        return 0.0
    front = math.exp(math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b)
                     + a * math.log(x) + b * math.log1p(-x))
    if x < (a + 1.0) / (a + b + 2.0):
        beta = front * _betacf(a, b, x) / a
    else:
        beta = 1.0 - front * _betacf(b, a, 1.0 - x) / b
    return 0.5 * beta


@functools.lru_cache(maxsize=4096)
def _t_quantile(confidence: float, v: float) -> float:
    tail = (1.0 - confidence) / 2.0
    if v == 1.0:
        return math.tan(math.pi * (0.5 - tail))
    if v == 2.0:
        p = 1.0 - tail
        return (2.0 * p - 1.0) / math.sqrt(2.0 * p * (1.0 - p))
    log_norm = math.lgamma((v + 1.0) / 2.0) - math.lgamma(v / 2.0) - 0.5 * math.log(v * math.pi)
    z = normal_quantile(confidence)
    # Cornish-Fisher start, then Newton on the exact tail.
    t = _t_series(z, v)
    for _ in range(50):
        pdf = math.exp(log_norm - (v + 1.0) / 2.0 * math.log1p(t * t / v))
        step = (_t_upper(t, v) - tail) / pdf
        t = max(t + step, t / 2.0)
        if abs(step) <= 1e-14 * t:
            break
    return t


def _t_series(z, v):
    """The Cornish-Fisher series of t_v at the normal quantile z (Abramowitz & Stegun 26.7.5,
    four terms), scalar or array v."""
    return (z + (z**3 + z) / (4 * v) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * v**2)
            + (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / (384 * v**3))
