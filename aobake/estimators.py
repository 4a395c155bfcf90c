"""Per-point estimates from traced rays: AO, Zhukov obscurance, bent normal.

Every estimate carries its standard error and the rays used (no bare means).
Contributions per ray, with w = cos(theta) / (pi pdf) from ``warp`` (1 for the
cosine weighting):

* AO          f = w * [ray escapes]            A = (1/pi) int V cos dw;  1 = open, 0 = occluded
* obscurance  f = w * rho(L), rho = 1 - exp(-tau L) for a hit at distance L,
              rho = 1 for a miss (nothing within the max distance);  1 = open, 0 = occluded
* bent normal normalise(sum of the escaping sample directions); the surface
              normal when no ray escapes.  Unit vector, no error bar.

Standard error: the spread of i.i.d. per-ray contributions (``random``) or of
the replicate means (randomised QMC samplers), see ``samplers``.  With a single
ray or a single replicate there is no spread to measure; the error reported
then is the worst case for a contribution in [0, w_max]: w_max / (2 sqrt(n)).
A point with no rays (no defined normal) gets the no-information answer: the
midpoint w_max / 2 with error w_max / 2.
"""

from __future__ import annotations

import numpy as np

try:  # built by setup.py; optional
    from aobake import _kernels
except ImportError:  # pragma: no cover
    _kernels = None


def mean_and_stderr(f: np.ndarray, iid: bool, max_weight: float):
    """f (k, R, m) per-ray contributions -> (mean (k,), stderr (k,)) float64."""
    k, groups, m = f.shape
    n = groups * m
    if iid:
        flat = f.reshape(k, n).astype(np.float64)
        mean = flat.sum(axis=1) / n
        if n < 2:
            return mean, np.full(k, max_weight / (2.0 * np.sqrt(n)))
        var = np.square(flat - mean[:, None]).sum(axis=1) / (n - 1)
        return mean, np.sqrt(var / n)
    group_means = f.astype(np.float64).sum(axis=2) / m  # (k, R)
    mean = group_means.sum(axis=1) / groups
    if groups < 2:
        return mean, np.full(k, max_weight / (2.0 * np.sqrt(n)))
    var = np.square(group_means - mean[:, None]).sum(axis=1) / (groups - 1)
    return mean, np.sqrt(var / groups)


def _escape_counts(occluded: np.ndarray) -> np.ndarray:
    """(k, R, m) bool occluded -> (k, R) float64 number of rays that escaped."""
    k, groups, m = occluded.shape
    if _kernels is None:  # pragma: no cover - only without the compiled kernel
        return (m - np.count_nonzero(occluded, axis=2)).astype(np.float64)
    # count_nonzero over a short last axis costs as much as generating the rays.
    blocked = np.empty(k * groups, dtype=np.int32)
    _kernels.row_counts(np.ascontiguousarray(occluded), k * groups, m, blocked)
    return (m - blocked).reshape(k, groups).astype(np.float64)


def _binary_mean_and_stderr(occluded: np.ndarray, iid: bool, max_weight: float):
    """mean_and_stderr for 0/1 contributions (1 = escaped) from (k, R, m) bool ``occluded``,
    from exact counts."""
    k, groups, m = occluded.shape
    n = groups * m
    counts = _escape_counts(occluded)  # (k, R)
    if iid:
        # i.i.d. 0/1 samples: sample variance = n/(n-1) p (1 - p).
        mean = counts.sum(axis=1) / n
        if n < 2:
            return mean, np.full(k, max_weight / (2.0 * np.sqrt(n)))
        return mean, np.sqrt(mean * (1.0 - mean) / (n - 1))
    group_means = counts / m
    mean = group_means.sum(axis=1) / groups
    if groups < 2:
        return mean, np.full(k, max_weight / (2.0 * np.sqrt(n)))
    var = np.square(group_means - mean[:, None]).sum(axis=1) / (groups - 1)
    return mean, np.sqrt(var / groups)


def rho(distance: np.ndarray, tau: float) -> np.ndarray:
    """Zhukov obscurance rho(L) = 1 - exp(-tau L) in [0, 1]; 1 for a miss (L = inf).

    distance : float32 array, inf on a miss.  Written to avoid 0 * inf at the
    extremes: tau = 0 gives 0 for every hit, tau = inf gives 1 for every hit at L > 0.
    """
    miss = ~np.isfinite(distance)
    hit_l = np.where(miss, 0.0, distance).astype(np.float32)
    if np.isinf(tau):
        value = (hit_l > 0).astype(np.float32)
    else:
        value = -np.expm1(np.float32(-tau) * hit_l)
    return np.where(miss, np.float32(1.0), value)


def estimate(quantities, directions, weight, occluded, distance, samples, tau, max_weight, normals):
    """Estimates for k points.

    directions : (k, R, m, 3) float32, weight : (k, R, m) float32 | None,
    occluded : (k, R, m) bool, distance : (k, R, m) float32 (inf on miss) | None,
    normals : (k, 3) float64.  Returns a dict of (k,) / (k, 3) float64 arrays for
    the quantities asked ("ao", "obscurance", "bent-normal").
    """
    out = {}
    if "ao" in quantities:
        if weight is None:
            # Contributions are 0/1: escape counts are exact and cheaper than float sums.
            out["ao"], out["ao_stderr"] = _binary_mean_and_stderr(occluded, samples.iid, max_weight)
        else:
            out["ao"], out["ao_stderr"] = mean_and_stderr(~occluded * weight, samples.iid, max_weight)
    if "obscurance" in quantities:
        f = rho(distance, tau)
        if weight is not None:
            f *= weight
        out["obscurance"], out["obscurance_stderr"] = mean_and_stderr(f, samples.iid, max_weight)
    if "bent-normal" in quantities:
        k = len(directions)
        total = (directions * ~occluded[..., None]).reshape(k, -1, 3).sum(axis=1, dtype=np.float64)
        length = np.linalg.norm(total, axis=1, keepdims=True)
        out["bent_normal"] = np.where(length > 0, total / np.where(length > 0, length, 1.0), normals)
    return out


def no_information(quantities, normals: np.ndarray, max_weight: float) -> dict:
    """Estimates for points that cast no rays: midpoint value, worst-case error."""
    k = len(normals)
    out = {}
    for name in ("ao", "obscurance"):
        if name in quantities:
            out[name] = np.full(k, max_weight / 2.0)
            out[name + "_stderr"] = np.full(k, max_weight / 2.0)
    if "bent-normal" in quantities:
        out["bent_normal"] = normals.copy()
    return out
