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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aobake.samplers import SampleSet, elevation_shifts, shifts
from aobake.warp import WEIGHTINGS, frames


@dataclass(frozen=True)
class Rays:
    """The rays of k points, point-major.

    origins : (k, 3) float32   one origin per point (already offset and rebased)
    directions : (k, R, m, 3) float32  unit directions in scene axes (C-contiguous)
    weight : (R, m) float32 | None  cos(theta) / (pi pdf) per sample (same for every
             point); None means 1 for every ray
    """

    origins: np.ndarray
    directions: np.ndarray
    weight: np.ndarray | None


class RayGenerator:
    """Warps the base set once; :meth:`rays` builds one chunk."""

    def __init__(self, samples: SampleSet, weighting: str, seed: int):
        self.samples = samples
        self.seed = seed
        base = samples.base
        u0 = (base[None, :, 0] + elevation_shifts(seed, samples.groups)[:, None]) % 1.0  # (R, m)
        u0 = np.minimum(u0, 1.0 - 2.0**-53)  # keep cos(theta) > 0
        r, z, weight = WEIGHTINGS[weighting][0](u0)
        phi = 2.0 * np.pi * base[:, 1]
        local = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)  # (R, m, 3)
        self.local = local.astype(np.float32)
        self.weight = None if weight is None else weight.astype(np.float32)

    def rays(self, origins: np.ndarray, normals: np.ndarray, point_ids: np.ndarray) -> Rays:
        """origins (k, 3) float64 (offset, rebased), normals (k, 3) float64 unit, point_ids (k,) int64."""
        groups = self.samples.groups
        azimuth = 2.0 * np.pi * shifts(self.seed, point_ids, groups)[..., 1]  # (k, R)
        tangent, bitangent = frames(normals)
        cs, ss = np.cos(azimuth)[..., None], np.sin(azimuth)[..., None]
        frame = np.empty((len(normals), groups, 3, 3), dtype=np.float32)
        # Rows of the per-(point, replicate) frame: T and B rotated about N, then N.
        frame[:, :, 0] = cs * tangent[:, None, :] + ss * bitangent[:, None, :]
        frame[:, :, 1] = cs * bitangent[:, None, :] - ss * tangent[:, None, :]
        frame[:, :, 2] = normals[:, None, :]
        directions = np.matmul(self.local[None], frame)  # (k, R, m, 3): d = x T' + y B' + z N
        return Rays(origins.astype(np.float32), directions, self.weight)
