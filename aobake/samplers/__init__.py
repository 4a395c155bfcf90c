"""Samplers: name -> function (n_rays) -> SampleSet (see ``aobake.samplers.base``).

A new sampler is one module with a ``sample(n_rays, replicates)`` function whose SampleSet has a
numpy ``values`` function, plus one line in ``SAMPLERS``; the CLI's ``--sampler``
choices come from here.  (It runs on the numpy formulation until ``_kernels.c`` has a
case for it: ``SampleSet.kernel`` None.)
"""

from __future__ import annotations

from aobake.samplers import random, sobol, stratified
from aobake.samplers.base import (REPLICATES, SampleSet, point_key, replicate_keys,
                                  split)
from aobake.samplers.sobol import sobol_2d

#: sampler name -> function (n_rays, replicates) -> SampleSet
SAMPLERS = {"random": random.sample, "stratified": stratified.sample, "sobol": sobol.sample}


def sample_set(name: str, n_rays: int, replicates: int = REPLICATES) -> SampleSet:
    """How ``n_rays`` rays per point are sampled (rays actually cast: ``.rays`` >= n_rays),
    in ``replicates`` independent replicates for the randomised-QMC samplers (``random``'s
    rays are all i.i.d.: it ignores them)."""
    if name not in SAMPLERS:
        raise ValueError(f"unknown sampler {name!r}; choose one of {sorted(SAMPLERS)}")
    if n_rays < 1:
        raise ValueError(f"rays must be >= 1, got {n_rays}")
    return SAMPLERS[name](n_rays, replicates)


__all__ = ["REPLICATES", "SAMPLERS", "SampleSet", "point_key", "replicate_keys", "sample_set",
           "sobol_2d", "split"]
