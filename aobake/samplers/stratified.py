"""``stratified``: per replicate, a jittered nx x ny grid (one sample per cell); R independent
replicates give the error."""

from __future__ import annotations

import numpy as np

from aobake.samplers.base import REPLICATES, SampleSet, sample_hashes, split, uniforms

#: code of this sampler in aobake/_kernels.c
KERNEL = 1
_BELOW_ONE = np.nextafter(1.0, 0.0)


def grid(m: int) -> tuple[int, int]:
    """nx * ny = m with nx the largest divisor <= sqrt(m): square when m is."""
    nx = max(d for d in range(1, int(np.sqrt(m)) + 1) if m % d == 0)
    return nx, m // nx


def sample(n_rays: int, replicates: int = REPLICATES) -> SampleSet:
    groups, m = split(n_rays, replicates)
    nx, ny = grid(m)

    def values(keys, j0, count):
        jitter = uniforms(sample_hashes(keys, j0, count))
        j = np.arange(j0, j0 + count)
        u0 = (j % nx + jitter[..., 0]) / nx
        u1 = (j // nx + jitter[..., 1]) / ny
        # (cell + jitter) / n can round up to 1.0: keep u0 < 1 (cos theta > 0).
        return np.minimum(np.stack([u0, u1], axis=-1), _BELOW_ONE)

    return SampleSet("stratified", groups, m, False, values, kernel=KERNEL, grid=(nx, ny))
