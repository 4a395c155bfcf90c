"""``random``: i.i.d. uniform samples per point; the per-ray sample variance is the honest error."""

from __future__ import annotations

from aobake.samplers.base import SampleSet, sample_hashes, uniforms

#: code of this sampler in aobake/_kernels.c
KERNEL = 0


def values(keys, j0, count):
    """u = two 53-bit uniforms from the hash of (replicate key, j)."""
    return uniforms(sample_hashes(keys, j0, count))


def sample(n_rays: int, replicates: int = 1) -> SampleSet:
    """All n_rays i.i.d. (one group: the per-ray spread is the error; replicates unused)."""
    return SampleSet("random", 1, n_rays, True, values, kernel=KERNEL)
