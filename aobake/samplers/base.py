"""What every sampler shares: the SampleSet record, the replicate split, the per-point keys.

Sample values u in [0,1)^2 are pure functions of (seed, point id, replicate,
sample index), and every point is randomised on its own: no random number is
shared by two points, two replicates or two texel samples.  A point's R
replicates each get a 64-bit key (:func:`replicate_keys`); a sampler turns a key
and the sample index j (0..m-1) into u, so the errors of different points are
independent and every average over points has the spread independence predicts.

How the standard error is estimated depends on the sampler (``iid`` flag):

* i.i.d. samplers (``random``): the R m samples of a point are independent:
  the per-ray spread is the error.
* randomised QMC (``stratified``, ``sobol``): the m samples of one replicate are
  not independent, the R replicates are: the spread of the R replicate means is
  the error (``aobake.stats``).

The hash is ``aobake.rng``'s splitmix64, mirrored in ``aobake/_kernels.c``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from aobake.rng import GOLDEN, dim_salt, hash_key, mix, to_unit

#: replicates for the randomised-QMC samplers' standard error (the default of
#: ``--replicates``): more replicates give a steadier stderr (R - 1 degrees of freedom),
#: fewer a more accurate mean for the rays (one net of R m points beats R nets of m:
#: bunny, sobol, 128 rays: RMSE 0.0143 at R = 8, 0.0125 at 4, 0.0107 at 2)
REPLICATES = 4
#: the fewest replicates (a stderr needs at least two) and the most
MIN_REPLICATES, MAX_REPLICATES = 2, 1024

#: rays of one point traced at once: a point with more streams them in pieces of
#: PIECE_RAYS // R samples per replicate (a power of two), so memory is bounded whatever
#: the ray count.  A constant, never derived from the chunk size or the thread count: the
#: pieces fix the order in which a point's statistics are summed, hence its bits.
PIECE_RAYS = 1 << 16

#: hash stream of the per-point keys (distinct from every other stream of aobake)
STREAM_POINT = 0x5EED_0004
#: hash stream of the final stage of a --tolerance bake (independent of its pilot's rays)
STREAM_FINAL = 0x5EED_0005
#: hash stream of the inward rays (``-q thickness``), one per stage (STAGE_STRIDE apart)
STREAM_INWARD = 0x5EED_0007
#: uint64 salts of the two sample dimensions (u0: elevation, u1: azimuth)
#: the distance between the streams of successive --tolerance stages
STAGE_STRIDE = 0x1_0000
SALTS = (np.uint64(dim_salt(0)), np.uint64(dim_salt(1)))


@dataclass(frozen=True)
class SampleSet:
    """How the R m sample values of every point are made.

    name : the sampler, groups : R replicates, m : samples per replicate
    (rays per point = R m), iid : True when all R m samples of a point are i.i.d.,
    values : (keys (k, R) uint64, j0, count) -> u (k, R, count, 2) float64 in [0, 1)^2
    of samples j0 .. j0 + count - 1 of every replicate, with u0 < 1 strictly (the numpy
    formulation; the compiled kernel mirrors it bit for bit),
    kernel : the compiled kernel's code for this sampler, or None (numpy only),
    table : (min(m, piece), 2) uint32 per-sampler constants handed to the kernel
    (bit-reversed Sobol points; empty for the others),
    grid : (nx, ny) of a stratified sampler, (0, 0) otherwise,
    shift : j0 -> (2,) uint32 that turns ``table`` into the constants of samples
    j0 .. j0 + len(table) - 1 by xor (Sobol: the net's digital shift), or None.
    """

    name: str
    groups: int
    m: int
    iid: bool
    values: Callable
    kernel: int | None = None
    table: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.uint32))
    grid: tuple = (0, 0)
    shift: Callable | None = None

    @property
    def rays(self) -> int:
        return self.groups * self.m

    @property
    def piece(self) -> int:
        """Samples per replicate traced at once for one point: all m when the point's rays fit
        in PIECE_RAYS, else the largest power of two <= PIECE_RAYS // R (the point streams
        in ceil(m / piece) pieces; a power of two, so that a Sobol piece is the first one
        xor a digital shift whatever R is)."""
        if self.rays <= PIECE_RAYS:
            return self.m
        return 1 << (max(1, PIECE_RAYS // self.groups).bit_length() - 1)

    def table_for(self, j0: int, count: int) -> np.ndarray:
        """(count, 2) uint32 kernel constants of samples j0 .. j0 + count - 1 (j0 a multiple
        of the piece size); empty for samplers without a table."""
        if len(self.table) == 0 or j0 + count <= len(self.table):
            return np.ascontiguousarray(self.table[j0:j0 + count])
        return np.ascontiguousarray(self.table[:count] ^ self.shift(j0)[None, :])


def point_key(seed: int, stage: int = 0) -> int:
    """The bake's uint64 key of the per-point stream (stage 1: a --tolerance bake's final
    rays, independent of its pilot's; stage s >= 2: its further stages)."""
    if stage == 0:
        return hash_key(seed, STREAM_POINT)
    # stage 1 is the final stage; 2, 3, ... the further stages of points it left wider
    # than the tolerance, each from a stream of its own
    return hash_key(seed, STREAM_FINAL + STAGE_STRIDE * (stage - 1))


def inward_key(seed: int, stage: int = 0) -> int:
    """The bake's uint64 key of the per-point stream of inward rays (``-q thickness``) at
    ``stage`` (as :func:`point_key`'s): independent of the outward rays'."""
    return hash_key(seed, STREAM_INWARD + STAGE_STRIDE * stage)


def replicate_keys(key: int, point_ids: np.ndarray, groups: int) -> np.ndarray:
    """(k, R) uint64 keys of the R replicates of points ``point_ids`` (k,) int64.

    A pure function of (seed, point id, replicate): the same point gets the same keys in
    any chunk, in any thread; distinct (point, replicate) pairs get distinct keys (mix is a
    bijection; the replicate enters through an odd multiple of the golden ratio).
    """
    with np.errstate(over="ignore"):
        per_point = mix(np.uint64(key) ^ np.asarray(point_ids, dtype=np.int64).astype(np.uint64))
        g = (np.arange(groups, dtype=np.uint64) + np.uint64(1)) * np.uint64(GOLDEN)
        return mix(per_point[:, None] + g[None, :])


def sample_hashes(keys: np.ndarray, j0: int, count: int) -> np.ndarray:
    """(k, R, count) uint64: one hash per sample j0 .. j0 + count - 1 of every replicate
    (i.i.d. and jitter samplers)."""
    with np.errstate(over="ignore"):
        j = (np.arange(j0, j0 + count, dtype=np.uint64) + np.uint64(1)) \
            * np.uint64(0xD1B54A32D192ED03)
        return mix(keys[:, :, None] + j[None, None, :])


def uniforms(hashes: np.ndarray) -> np.ndarray:
    """(...,) uint64 sample hashes -> (..., 2) float64 uniform in [0, 1) (53 bits each)."""
    with np.errstate(over="ignore"):
        return np.stack([to_unit(mix(hashes + SALTS[0])), to_unit(mix(hashes + SALTS[1]))],
                        axis=-1)


def split(n_rays: int, replicates: int = REPLICATES) -> tuple[int, int]:
    """(replicates R, points per replicate m) with R*m >= n_rays, m = ceil(n_rays / R)
    (R = min(replicates, n_rays))."""
    groups = max(1, min(int(replicates), n_rays))
    return groups, -(-n_rays // groups)
