"""``stratified``: a jittered grid per replicate (R independent replicates give the error)."""

from __future__ import annotations

import numpy as np

from aobake.rng import hash_uniform
from aobake.samplers.base import STREAM_BASE, SampleSet, split


def sample(n_rays: int, seed: int) -> SampleSet:
    groups, m = split(n_rays)
    # Grid nx * ny = m with nx the largest divisor <= sqrt(m): square when m is.
    nx = max(d for d in range(1, int(np.sqrt(m)) + 1) if m % d == 0)
    ny = m // nx
    j = np.arange(m)
    jitter = np.stack([hash_uniform(seed, STREAM_BASE, j, 0),
                       hash_uniform(seed, STREAM_BASE, j, 1)], axis=1)
    base = np.stack([(j % nx + jitter[:, 0]) / nx, (j // nx + jitter[:, 1]) / ny], axis=1)
    return SampleSet(np.minimum(base, np.nextafter(1.0, 0.0)), groups, False)
