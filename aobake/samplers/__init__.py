"""Samplers: name -> function (n_rays, seed) -> SampleSet (see ``aobake.samplers.base``).

A new sampler is one module with a ``sample(n_rays, seed)`` function plus one
line in ``SAMPLERS``; the CLI's ``--sampler`` choices come from here.
"""

from __future__ import annotations

from aobake.samplers import random, sobol, stratified
from aobake.samplers.base import (REPLICATES, SampleSet, elevation_shifts, shift_key, shifts,
                                  split)
from aobake.samplers.sobol import sobol_2d

#: sampler name -> function (n_rays, seed) -> SampleSet
SAMPLERS = {"random": random.sample, "stratified": stratified.sample, "sobol": sobol.sample}


def sample_set(name: str, n_rays: int, seed: int) -> SampleSet:
    """The base set for ``n_rays`` rays per point (rays actually cast: ``.rays`` >= n_rays)."""
    if name not in SAMPLERS:
        raise ValueError(f"unknown sampler {name!r}; choose one of {sorted(SAMPLERS)}")
    if n_rays < 1:
        raise ValueError(f"rays must be >= 1, got {n_rays}")
    return SAMPLERS[name](n_rays, seed)


__all__ = ["REPLICATES", "SAMPLERS", "SampleSet", "elevation_shifts", "sample_set", "shift_key",
           "shifts", "sobol_2d", "split"]
