"""What every sampler shares: the SampleSet record, the replicate split and the shifts.

Sample values u in [0,1)^2 are pure functions of (seed, point id, sample id).

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
STREAM_BASE = 0x5EED_0001
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


def split(n_rays: int) -> tuple[int, int]:
    """(replicates R, points per replicate m) with R*m >= n_rays, m = ceil(n_rays / R)."""
    groups = max(1, min(REPLICATES, n_rays))
    return groups, -(-n_rays // groups)
