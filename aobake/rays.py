"""Build the rays of a chunk of points: origins and cosine/uniform hemisphere directions.

The cheap-by-design part of the hot path.  Sample j of replicate g of point p
has u = sampler(key_pg, j) (``aobake.samplers``: a pure function of (seed, point
id, replicate, j), independent between points), warped to a local direction
(r cos phi, r sin phi, z) by the weighting (``aobake.warp``: r, z from u0,
phi = 2 pi u1) and turned into scene axes by the point's frame (T, B, N):
d = (x T + y B) + z N in float64, rounded once to float32.  Rays are laid out
point-major (all rays of one point together) because Embree traces coherent rays
about twice as fast as shuffled ones.

The per-ray work runs in the compiled ``aobake._kernels`` when it was built and
the sampler has a kernel case, otherwise in numpy.  Both do the same IEEE
operations in the same order and precision (cos/sin from one + and * polynomial,
``warp.cos_sin_2pi``), so they give bit-identical rays; ``RayGenerator.compiled``
says which one runs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aobake import _native
from aobake.samplers import SampleSet, point_key, replicate_keys
from aobake.warp import WEIGHTINGS, cos_sin_2pi, frames

#: weighting name -> its code in aobake/_kernels.c
_WEIGHTING_CODES = {"cosine": 0, "uniform": 1}


@dataclass(frozen=True)
class Rays:
    """The rays of k points, point-major.

    origins : (k * R * m, 3) float32  the origin of every ray (its point's, offset and rebased)
    directions : (k, R, m, 3) float32  unit directions in scene axes (C-contiguous)
    """

    origins: np.ndarray
    directions: np.ndarray


class RayGenerator:
    """Makes the rays of chunks of points for one sampler, weighting and seed."""

    def __init__(self, samples: SampleSet, weighting: str, seed: int, compiled: bool | None = None,
                 stage: int = 0, key: int | None = None):
        """``compiled``: use the compiled kernel (default: when built, not forced off and the
        sampler and weighting have a kernel case); ``stage``: the key stream
        (``samplers.point_key``); ``key``: another stream's key instead (the inward rays')."""
        has_case = samples.kernel is not None and weighting in _WEIGHTING_CODES
        self._kernels = _native.kernels() if compiled in (None, True) and has_case else None
        if compiled and self._kernels is None:
            raise RuntimeError("aobake._kernels was not built, or has no case for this sampler")
        #: True when the compiled kernel builds the rays (recorded in reports)
        self.compiled = self._kernels is not None
        self.samples, self.weighting, self.seed = samples, weighting, seed
        self._key = point_key(seed, stage) if key is None else key

    def rays(self, origins: np.ndarray, normals: np.ndarray, point_ids: np.ndarray,
             j0: int = 0, count: int | None = None) -> Rays:
        """origins (k, 3) float64 (offset, rebased), normals (k, 3) float64 unit, point_ids (k,)
        int64; samples j0 .. j0 + count - 1 of every replicate (default all m: a streamed
        point traces one piece of them at a time).  directions: (k, R, count, 3)."""
        samples = self.samples
        groups, m = samples.groups, samples.m
        count = m - j0 if count is None else count
        k = len(normals)
        origins32 = np.ascontiguousarray(origins, dtype=np.float32)
        keys = replicate_keys(self._key, point_ids, groups)  # (k, R) uint64
        if self.compiled:
            flat_origins = np.empty((k * groups * count, 3), dtype=np.float32)
            directions = np.empty((k, groups, count, 3), dtype=np.float32)
            nx, ny = samples.grid
            self._kernels.fill_rays(origins32, np.ascontiguousarray(normals, dtype=np.float64),
                                    np.ascontiguousarray(keys), samples.table_for(j0, count),
                                    samples.kernel, _WEIGHTING_CODES[self.weighting], nx, ny,
                                    k, groups, m, j0, count, flat_origins, directions)
            return Rays(flat_origins, directions)
        # Reference formulation (and the fallback), operation for operation as the kernel.
        u = samples.values(keys, j0, count)  # (k, R, count, 2)
        r, z = WEIGHTINGS[self.weighting](u[..., 0])
        c, s = cos_sin_2pi(u[..., 1])
        x, y = r * c, r * s
        tangent, bitangent = frames(normals)
        axes = [a[:, None, None, :] for a in (tangent, bitangent, normals)]
        directions = (x[..., None] * axes[0] + y[..., None] * axes[1]) + z[..., None] * axes[2]
        return Rays(np.repeat(origins32, groups * count, axis=0), directions.astype(np.float32))
