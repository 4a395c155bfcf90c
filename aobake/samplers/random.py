"""``random``: i.i.d. uniform base points; the per-ray sample variance is the honest error."""

from __future__ import annotations

import numpy as np

from aobake.rng import hash_uniform
from aobake.samplers.base import STREAM_BASE, SampleSet


def sample(n_rays: int, seed: int) -> SampleSet:
    ids = np.arange(n_rays)
    base = np.stack([hash_uniform(seed, STREAM_BASE, ids, 0),
                     hash_uniform(seed, STREAM_BASE, ids, 1)], axis=1)
    return SampleSet(base, 1, True)
