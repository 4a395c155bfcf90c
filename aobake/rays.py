"""Build the rays of a chunk of points: origins and cosine/uniform hemisphere directions.

The cheap-by-design part of the hot path.  For point p, replicate g and base
sample j, with the Cranley-Patterson shift s = (s0, s1) of (p, g):

    u0 = frac(b0_j + s0)                      -> sin(theta), cos(theta) (one sqrt each)
    phi = 2 pi (b1_j + s1)                     -> a rotation of the frame by 2 pi s1
    d = sin(theta) (cos(2 pi b1_j) T' + sin(2 pi b1_j) B') + cos(theta) N

where T', B' are the point's tangent frame rotated by 2 pi s1 (per point and
replicate, not per ray).  So each ray costs two square roots and a few
multiply-adds in float32; the trigonometry is per base sample or per point.
Rays are laid out point-major (all rays of one point together) because Embree
traces coherent rays about twice as fast as shuffled ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aobake.samplers import SampleSet, shifts
from aobake.warp import WEIGHTINGS, frames


@dataclass(frozen=True)
class Rays:
    """The rays of k points, point-major.

    origins : (k, 3) float32   one origin per point (already offset and rebased)
    directions : (k, R, m, 3) float32  unit directions in scene axes (a strided view:
                 component-major in memory; ``reshape(-1, 3)`` keeps it a view)
    weight : (k, R, m) float32 | None  cos(theta) / (pi pdf); None means 1 for every ray
    """

    origins: np.ndarray
    directions: np.ndarray
    weight: np.ndarray | None


class RayGenerator:
    """Precomputes the per-sample part once; :meth:`rays` builds one chunk."""

    def __init__(self, samples: SampleSet, weighting: str, seed: int):
        self.samples = samples
        self.seed = seed
        self._elevation = WEIGHTINGS[weighting][0]
        base = samples.base
        self._b0 = base[:, 0].astype(np.float32)
        self._cb = np.cos(2.0 * np.pi * base[:, 1]).astype(np.float32)
        self._sb = np.sin(2.0 * np.pi * base[:, 1]).astype(np.float32)

    def rays(self, origins: np.ndarray, normals: np.ndarray, point_ids: np.ndarray) -> Rays:
        """origins (k, 3) float64 (offset, rebased), normals (k, 3) float64 unit, point_ids (k,) int64."""
        groups = self.samples.groups
        shift = shifts(self.seed, point_ids, groups)  # (k, R, 2) float64
        tangent, bitangent = frames(normals)
        angle = 2.0 * np.pi * shift[..., 1]
        cs, ss = np.cos(angle)[..., None], np.sin(angle)[..., None]
        t_rot = (cs * tangent[:, None, :] + ss * bitangent[:, None, :]).astype(np.float32)
        b_rot = (cs * bitangent[:, None, :] - ss * tangent[:, None, :]).astype(np.float32)
        n32 = normals.astype(np.float32)

        u0 = self._b0[None, None, :] + shift[..., 0, None].astype(np.float32)  # (k, R, m)
        u0 -= u0 >= 1.0  # frac(): both terms are in [0, 1)
        np.clip(u0, 0.0, np.float32(1.0 - 2.0**-24), out=u0)  # keep cos(theta) > 0
        r, z, weight = self._elevation(u0)
        k, m = len(normals), len(self._b0)
        # Component-major storage: each component is written contiguously (no
        # interleaving pass); the (k, R, m, 3) view handed on is a transpose.
        planes = np.empty((3, k, groups, m), dtype=np.float32)
        for axis in range(3):
            comp = planes[axis]
            np.multiply(self._cb, t_rot[:, :, None, axis], out=comp)
            comp += self._sb * b_rot[:, :, None, axis]
            comp *= r
            comp += z * n32[:, None, None, axis]
        return Rays(origins.astype(np.float32), np.moveaxis(planes, 0, -1), weight)
