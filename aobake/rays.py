"""Build the rays of a chunk of points: origins and cosine/uniform hemisphere directions.

The cheap-by-design part of the hot path.  Sample j of replicate g of point p
uses u = (frac(b0_j + e_g), frac(b1_j + s_pg)) where b is the sampler's base
set, e_g a random elevation shift per replicate (shared by all points) and
s_pg a random azimuth shift per point and replicate (see ``samplers``).  Each
u is exactly uniform on [0,1)^2, so every point's estimate is unbiased, its
replicates are independent, and i.i.d. base points stay i.i.d.

Because the elevation part does not depend on the point, the local directions
``D[g, j]`` (R x m of them) are warped once per bake; a point only needs its
frame (T, B, N) rotated about N by 2 pi s_pg, and its rays are one small
matrix product ``D[g] @ frame[p, g]``: 9 multiply-adds per ray, no square root
or trigonometry per ray.  Rays are laid out point-major (all rays of one point
together) because Embree traces coherent rays about twice as fast as shuffled.

The per-point and per-ray work (azimuth hash, cos/sin, frame, the 3x3 product
and repeating each origin for its rays) runs in the compiled ``aobake._kernels``
when it was built, otherwise in numpy.  Both do the same IEEE operations in the
same order and precision (cos/sin from the C library in both), so they give
bit-identical rays; ``RayGenerator.compiled`` says which one runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aobake import _native
from aobake.rng import dim_salt
from aobake.samplers import SampleSet, elevation_shifts, shift_key, shifts
from aobake.warp import WEIGHTINGS, frames


@dataclass(frozen=True)
class Rays:
    """The rays of k points, point-major.

    origins : (k * R * m, 3) float32  the origin of every ray (its point's, offset and rebased)
    directions : (k, R, m, 3) float32  unit directions in scene axes (C-contiguous)
    """

    origins: np.ndarray
    directions: np.ndarray


class RayGenerator:
    """Warps the base set once; :meth:`rays` builds one chunk."""

    def __init__(self, samples: SampleSet, weighting: str, seed: int, compiled: bool | None = None):
        """``compiled``: use the compiled kernel (default: when built and not forced off)."""
        self._kernels = _native.kernels() if compiled in (None, True) else None
        if compiled and self._kernels is None:
            raise RuntimeError("aobake._kernels was not built")
        #: True when the compiled kernel builds the rays (recorded in reports)
        self.compiled = self._kernels is not None
        self.samples = samples
        self.seed = seed
        self._shift_key, self._azimuth_salt = shift_key(seed), dim_salt(1)  # for the kernel
        base = samples.base
        u0 = (base[None, :, 0] + elevation_shifts(seed, samples.groups)[:, None]) % 1.0  # (R, m)
        u0 = np.minimum(u0, 1.0 - 2.0**-53)  # keep cos(theta) > 0
        r, z = WEIGHTINGS[weighting](u0)
        phi = 2.0 * np.pi * base[:, 1]
        local = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)  # (R, m, 3)
        self.local = local.astype(np.float32)

    def rays(self, origins: np.ndarray, normals: np.ndarray, point_ids: np.ndarray) -> Rays:
        """origins (k, 3) float64 (offset, rebased), normals (k, 3) float64 unit, point_ids (k,) int64."""
        groups, m = self.samples.groups, self.local.shape[1]
        k = len(normals)
        origins32 = np.ascontiguousarray(origins, dtype=np.float32)
        if self.compiled:
            flat_origins = np.empty((k * groups * m, 3), dtype=np.float32)
            directions = np.empty((k, groups, m, 3), dtype=np.float32)
            self._kernels.fill_rays(origins32, np.ascontiguousarray(normals, dtype=np.float64),
                               np.ascontiguousarray(point_ids, dtype=np.int64),
                               self._shift_key, self._azimuth_salt, self.local,
                               k, groups, m, flat_origins, directions)
            return Rays(flat_origins, directions)
        # Reference formulation (and the fallback).  cos/sin through math, i.e. the C
        # library the kernel calls: numpy's own float64 cos may use other code (SVML).
        azimuth = 2.0 * np.pi * shifts(self.seed, point_ids, groups)[..., 1]  # (k, R)
        cs = np.frompyfunc(math.cos, 1, 1)(azimuth).astype(np.float64)[..., None]
        ss = np.frompyfunc(math.sin, 1, 1)(azimuth).astype(np.float64)[..., None]
        tangent, bitangent = frames(normals)
        # Rows of the per-(point, replicate) frame: T and B rotated about N (in
        # float64, rounded once to float32), then N.
        rows = (
            (cs * tangent[:, None, :] + ss * bitangent[:, None, :]).astype(np.float32),
            (cs * bitangent[:, None, :] - ss * tangent[:, None, :]).astype(np.float32),
            np.broadcast_to(normals.astype(np.float32)[:, None, :], (k, groups, 3)),
        )
        # d = x T' + y B' + z N, summed left to right in float32: (k, R, m, 3).
        x, y, z = (self.local[None, :, :, i:i + 1] for i in range(3))
        directions = x * rows[0][:, :, None, :] + y * rows[1][:, :, None, :] + z * rows[2][:, :, None, :]
        return Rays(np.repeat(origins32, groups * m, axis=0), directions)
