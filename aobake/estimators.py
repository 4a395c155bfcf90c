"""Per-point estimates from traced rays: AO, Zhukov obscurance, bent normal.

Every estimate carries its standard error and the rays used (no bare means).
Directions are drawn from the weighting's own measure (``warp``: cosine, or
uniform over the hemisphere), so contributions per ray are plain:

* AO          f = [ray escapes]          A = (1/pi) int V cos dw (cosine) or
                                         (1/2pi) int V dw (uniform); 1 = open, 0 = occluded
* obscurance  f = rho(L), rho = 1 - exp(-tau L) for a hit at distance L,
              rho = 1 for a miss (nothing within the max distance);  1 = open, 0 = occluded
* bent normal normalise(sum of the escaping sample directions); the surface
              normal when no ray escapes.  Unit vector; its error is an angle
              in radians (see ``bent_normal_and_stderr``).

Standard error: the spread of i.i.d. per-ray contributions (``random``) or of
the replicate means (randomised QMC samplers), see ``samplers``.  With a single
ray or a single replicate there is no spread to measure; the error reported
then is the worst case for a contribution in [0, 1]: 1 / (2 sqrt(n)).  A point
with no rays (no defined normal) gets the no-information answer: the midpoint
1/2 with error 1/2.
"""

from __future__ import annotations

import numpy as np

try:  # built by setup.py; optional
    from aobake import _kernels
except ImportError:  # pragma: no cover
    _kernels = None


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
    group_means = f.astype(np.float64).sum(axis=2) / m  # (k, R)
    mean = group_means.sum(axis=1) / groups
    if groups < 2:
        return mean, np.full(k, 1.0 / (2.0 * np.sqrt(n)))
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


def _binary_mean_and_stderr(occluded: np.ndarray, iid: bool):
    """mean_and_stderr for 0/1 contributions (1 = escaped) from (k, R, m) bool ``occluded``,
    from exact counts."""
    k, groups, m = occluded.shape
    n = groups * m
    counts = _escape_counts(occluded)  # (k, R)
    if iid:
        # i.i.d. 0/1 samples: sample variance = n/(n-1) p (1 - p).
        mean = counts.sum(axis=1) / n
        if n < 2:
            return mean, np.full(k, 1.0 / (2.0 * np.sqrt(n)))
        return mean, np.sqrt(mean * (1.0 - mean) / (n - 1))
    group_means = counts / m
    mean = group_means.sum(axis=1) / groups
    if groups < 2:
        return mean, np.full(k, 1.0 / (2.0 * np.sqrt(n)))
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


def estimate(quantities, directions, occluded, distance, samples, tau, normals):
    """Estimates for k points.

    directions : (k, R, m, 3) float32,
    occluded : (k, R, m) bool, distance : (k, R, m) float32 (inf on miss) | None,
    normals : (k, 3) float64.  Returns a dict of (k,) / (k, 3) float64 arrays for
    the quantities asked ("ao", "obscurance", "bent-normal").
    """
    out = {}
    if "ao" in quantities:
        # Contributions are 0/1: escape counts are exact and cheaper than float sums.
        out["ao"], out["ao_stderr"] = _binary_mean_and_stderr(occluded, samples.iid)
    if "obscurance" in quantities:
        out["obscurance"], out["obscurance_stderr"] = mean_and_stderr(rho(distance, tau), samples.iid)
    if "bent-normal" in quantities:
        out["bent_normal"], out["bent_normal_stderr"] = bent_normal_and_stderr(
            directions, occluded, samples.iid, normals)
    return out


#: Angular standard error (radians) reported when there is nothing to measure it
#: from (no escaping ray, a single ray or replicate, no rays): the bent normal is
#: then only known to lie in the hemisphere, up to pi/2 from the normal.
NO_INFORMATION_ANGLE = np.pi / 2


def bent_normal_and_stderr(directions, occluded, iid: bool, normals):
    """Bent normal and its angular standard error for k points.

    directions : (k, R, m, 3) float32 unit, occluded : (k, R, m) bool, normals : (k, 3) float64.
    Returns (bent (k, 3) float64 unit, stderr (k,) float64 radians).

    The bent normal is b / |b| with b the mean of f = d [ray escapes] over all rays.
    Its error is the delta method for normalising: the component of b's error
    perpendicular to b, over |b|: stderr^2 = tr(P Cov(b) P) / |b|^2 with
    P = I - b b^T / |b|^2 (the expected squared angle to the true bent normal).
    Cov(b) comes from the same source as the AO error: i.i.d. per-ray
    contributions (``random``) or the spread of the R replicate means.  Capped at
    pi/2, which is also the value when no ray escapes or there is no spread.
    """
    k, groups, m, _ = directions.shape
    n = groups * m
    f = directions * ~occluded[..., None]  # (k, R, m, 3) float32
    if iid:
        per = f.reshape(k, n, 3).astype(np.float64)
        count = n
    else:
        per = f.sum(axis=2, dtype=np.float64) / m  # replicate means (k, R, 3)
        count = groups
    b = per.sum(axis=1) / count  # (k, 3)
    length = np.linalg.norm(b, axis=1)
    ok = length > 0
    unit = b / np.where(ok, length, 1.0)[:, None]
    bent = np.where(ok[:, None], unit, normals)
    stderr = np.full(k, NO_INFORMATION_ANGLE)
    if count >= 2:
        dev = per - b[:, None, :]
        along = np.einsum("kjc,kc->kj", dev, unit)
        perp2 = (np.square(dev).sum(axis=2) - np.square(along)).sum(axis=1)  # sum |dev_perp|^2
        var = np.maximum(perp2, 0.0) / (count * (count - 1))
        with np.errstate(divide="ignore", invalid="ignore"):
            angle = np.sqrt(var) / length
        stderr = np.where(ok, np.minimum(angle, NO_INFORMATION_ANGLE), NO_INFORMATION_ANGLE)
    return bent, stderr


def no_information(quantities, normals: np.ndarray) -> dict:
    """Estimates for points that cast no rays: midpoint value, worst-case error."""
    k = len(normals)
    out = {}
    for name in ("ao", "obscurance"):
        if name in quantities:
            out[name] = np.full(k, 0.5)
            out[name + "_stderr"] = np.full(k, 0.5)
    if "bent-normal" in quantities:
        out["bent_normal"] = normals.copy()
        out["bent_normal_stderr"] = np.full(k, NO_INFORMATION_ANGLE)
    return out
