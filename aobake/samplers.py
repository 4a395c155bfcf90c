"""Sample values u in [0,1)^2 as pure functions of (seed, point id, sample id).

Every sampler here is a *randomised* point set with Cranley-Patterson rotation:
a base set ``b_j`` (j = 0..m-1) shared by all points, shifted by a uniform random
vector: ``u = frac(b_j + (e_g, s_pg))``.  The first (elevation) shift ``e_g`` is
drawn per replicate g and shared by all points; the second (azimuth) shift
``s_pg`` per point and replicate (hashes of seed, replicate and point id).  Each
u is then exactly uniform on [0,1)^2, so every estimate is unbiased whatever
the base set; replicates are independent; and the azimuth shift is a rotation
of the point's frame, so ``rays`` warps the base set once and only rotates it
per point (that is what keeps ray generation cheap).

How the standard error is estimated depends on the sampler (``iid`` flag):

* ``random``: base points are i.i.d. uniform, so after one shift per point the
  ``n`` samples of a point are i.i.d.: the per-ray sample variance is honest.
* ``stratified`` (jittered grid) and ``sobol`` (the first m points of the 2-D
  Sobol sequence): samples of one point are not independent, so ``R``
  independent replicates (same base set, independent shifts) are traced, and the
  standard error is the spread of the R replicate means (randomised QMC).

Randomness comes from a counter-based hash (splitmix64) of integer ids, never a
shared generator, so results do not depend on threads or chunking.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aobake.rng import hash_key, hash_uniform

#: replicates for the randomised-QMC samplers' standard error.
REPLICATES = 8

# Hash streams: distinct constants so base points and shifts never share numbers.
_STREAM_BASE = 0x5EED_0001
_STREAM_SHIFT = 0x5EED_0002
_STREAM_ELEVATION = 0x5EED_0003


def shift_key(seed: int) -> int:
    """hash_key of the Cranley-Patterson shift stream (see :func:`shifts`)."""
    return hash_key(seed, _STREAM_SHIFT)


@dataclass(frozen=True)
class SampleSet:
    """The rays of one point: ``groups`` replicates of ``base`` (m points), each shifted.

    base : (m, 2) float64 in [0,1)^2
    groups : int  replicates R; rays per point = R * m
    iid : bool    True if all R*m samples of a point are i.i.d. (per-ray variance is honest)
    """

    base: np.ndarray
    groups: int
    iid: bool

    @property
    def rays(self) -> int:
        return self.groups * len(self.base)


def _random(n_rays: int, seed: int) -> SampleSet:
    ids = np.arange(n_rays)
    base = np.stack([hash_uniform(seed, _STREAM_BASE, ids, 0),
                     hash_uniform(seed, _STREAM_BASE, ids, 1)], axis=1)
    return SampleSet(base, 1, True)


def _split(n_rays: int) -> tuple[int, int]:
    """(replicates R, points per replicate m) with R*m >= n_rays, m = ceil(n_rays / R)."""
    groups = max(1, min(REPLICATES, n_rays))
    return groups, -(-n_rays // groups)


def _stratified(n_rays: int, seed: int) -> SampleSet:
    groups, m = _split(n_rays)
    # Grid nx * ny = m with nx the largest divisor <= sqrt(m): square when m is.
    nx = max(d for d in range(1, int(np.sqrt(m)) + 1) if m % d == 0)
    ny = m // nx
    j = np.arange(m)
    jitter = np.stack([hash_uniform(seed, _STREAM_BASE, j, 0),
                       hash_uniform(seed, _STREAM_BASE, j, 1)], axis=1)
    base = np.stack([(j % nx + jitter[:, 0]) / nx, (j // nx + jitter[:, 1]) / ny], axis=1)
    return SampleSet(np.minimum(base, np.nextafter(1.0, 0.0)), groups, False)


def sobol_2d(m: int) -> np.ndarray:
    """(m, 2) float64: the first m points of the 2-D Sobol sequence (unscrambled, Gray-code order).

    Dimension 0 is the base-2 radical inverse; dimension 1 uses the direction
    numbers of the primitive polynomial x + 1: v_1 = 1/2, v_k = v_{k-1} xor (v_{k-1} / 2).
    """
    bits = 32
    v1 = np.array([1 << (bits - 1 - k) for k in range(bits)], dtype=np.uint64)
    v2 = np.empty(bits, dtype=np.uint64)
    v2[0] = 1 << (bits - 1)
    for k in range(1, bits):
        v2[k] = v2[k - 1] ^ (v2[k - 1] >> np.uint64(1))
    index = np.arange(m, dtype=np.uint64)
    i = index ^ (index >> np.uint64(1))  # Gray-code order, the standard Sobol enumeration
    x = np.zeros(m, dtype=np.uint64)
    y = np.zeros(m, dtype=np.uint64)
    for k in range(bits):
        bit = (i >> np.uint64(k)) & np.uint64(1)
        x ^= bit * v1[k]
        y ^= bit * v2[k]
    return np.stack([x, y], axis=1).astype(np.float64) / float(1 << bits)


def _sobol(n_rays: int, seed: int) -> SampleSet:
    groups, m = _split(n_rays)
    return SampleSet(sobol_2d(m), groups, False)


#: sampler name -> function (n_rays, seed) -> SampleSet.  The CLI's choices come from here.
SAMPLERS = {"random": _random, "stratified": _stratified, "sobol": _sobol}


def sample_set(name: str, n_rays: int, seed: int) -> SampleSet:
    """The base set for ``n_rays`` rays per point (rays actually cast: ``.rays`` >= n_rays)."""
    if name not in SAMPLERS:
        raise ValueError(f"unknown sampler {name!r}; choose one of {sorted(SAMPLERS)}")
    if n_rays < 1:
        raise ValueError(f"rays must be >= 1, got {n_rays}")
    return SAMPLERS[name](n_rays, seed)


def elevation_shifts(seed: int, groups: int) -> np.ndarray:
    """(groups,) float64 shift of the first coordinate per replicate, shared by all points.

    Sharing it across points lets the elevation warp run once per bake (see
    ``rays``); each point's samples stay exactly uniform because its azimuth
    shift is independent.
    """
    return hash_uniform(seed, _STREAM_ELEVATION, np.arange(groups), 0)


def shifts(seed: int, point_ids: np.ndarray, groups: int) -> np.ndarray:
    """(k, groups, 2) float64 Cranley-Patterson shifts for points ``point_ids`` (k,) int64.

    A pure function of (seed, point id, replicate): the same point gets the same
    shifts in any chunk, in any thread.
    """
    ids = (np.asarray(point_ids, dtype=np.int64)[:, None] * groups + np.arange(groups)).ravel()
    out = np.stack([hash_uniform(seed, _STREAM_SHIFT, ids, 0),
                    hash_uniform(seed, _STREAM_SHIFT, ids, 1)], axis=1)
    return out.reshape(len(point_ids), groups, 2)
