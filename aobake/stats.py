"""Standard errors of Monte-Carlo means, and their aggregation over texel samples.

Two kinds of sample sets (``SampleSet.iid``):

* i.i.d. rays (``random``): the per-ray sample variance is honest,
  stderr = sqrt(s^2 / n).
* randomised QMC (``stratified``, ``sobol``): the rays of one replicate are not
  independent, the R replicates are; stderr = sqrt(var(replicate means) / R).

With a single ray or a single replicate there is no spread to measure; the error
reported then is the worst case for a contribution in [0, 1]: 1 / (2 sqrt(n)).
"""

from __future__ import annotations

import numpy as np


def mean_and_stderr(f: np.ndarray, iid: bool):
    """f (k, R, m) per-ray contributions in [0, 1] -> (mean (k,), stderr (k,)) float64."""
    k, groups, m = f.shape
    n = groups * m
    if iid:
        flat = f.reshape(k, n).astype(np.float64)
        mean = flat.sum(axis=1) / n
        if n < 2:
            return mean, np.full(k, 1.0 / (2.0 * np.sqrt(n)))
        var = np.square(flat - mean[:, None]).sum(axis=1) / (n - 1)
        return mean, np.sqrt(var / n)
    return replicate_mean_and_stderr(f.astype(np.float64).sum(axis=2) / m, n)


def replicate_mean_and_stderr(group_means: np.ndarray, n: int):
    """group_means (k, R) float64 replicate means of n rays in all -> (mean (k,), stderr (k,))."""
    k, groups = group_means.shape
    mean = group_means.sum(axis=1) / groups
    if groups < 2:
        return mean, np.full(k, 1.0 / (2.0 * np.sqrt(n)))
    var = np.square(group_means - mean[:, None]).sum(axis=1) / (groups - 1)
    return mean, np.sqrt(var / groups)


def binary_mean_and_stderr(counts: np.ndarray, m: int, iid: bool):
    """mean_and_stderr for 0/1 contributions from exact counts.

    counts : (k, R) float64 number of 1s among the m rays of each replicate.
    """
    k, groups = counts.shape
    n = groups * m
    if iid:
        # i.i.d. 0/1 samples: sample variance = n/(n-1) p (1 - p).
        mean = counts.sum(axis=1) / n
        if n < 2:
            return mean, np.full(k, 1.0 / (2.0 * np.sqrt(n)))
        return mean, np.sqrt(mean * (1.0 - mean) / (n - 1))
    return replicate_mean_and_stderr(counts / m, n)


def texel_stderr(variance_sum: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Standard error of a texel that averages its s sample estimates: sqrt(sum se^2) / s.

    variance_sum : (H, W) float64 mean of se^2 over the texel's samples (``splat``),
    count : (H, W) int samples per texel.  Empty texels get 0 (masked by coverage).
    """
    return np.sqrt(variance_sum / np.maximum(count, 1))


def summary(stderr: np.ndarray) -> dict:
    """Mean and 95th percentile of (n,) standard errors."""
    return {"stderr_mean": float(stderr.mean()), "stderr_p95": float(np.percentile(stderr, 95))}
