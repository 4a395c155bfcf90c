"""``sobol``: the first m points of the 2-D Sobol sequence per replicate, randomly shifted."""

from __future__ import annotations

import numpy as np

from aobake.samplers.base import SampleSet, split


def sobol_2d(m: int) -> np.ndarray:
    """(m, 2) float64: the first m points of the 2-D Sobol sequence (unscrambled, Gray-code order).

    Dimension 0 is the base-2 radical inverse; dimension 1 uses the direction
    numbers of the primitive polynomial x + 1: v_1 = 1/2, v_k = v_{k-1} xor (v_{k-1} / 2).
    """
    bits = 32
    v1 = np.array([1 << (bits - 1 - k) for k in range(bits)], dtype=np.uint64)
    v2 = np.empty(bits, dtype=np.uint64)
    v2[0] = 1 << (bits - 1)
    for k in range(1, bits):
        v2[k] = v2[k - 1] ^ (v2[k - 1] >> np.uint64(1))
    index = np.arange(m, dtype=np.uint64)
    i = index ^ (index >> np.uint64(1))  # Gray-code order, the standard Sobol enumeration
    x = np.zeros(m, dtype=np.uint64)
    y = np.zeros(m, dtype=np.uint64)
    for k in range(bits):
        bit = (i >> np.uint64(k)) & np.uint64(1)
        x ^= bit * v1[k]
        y ^= bit * v2[k]
    return np.stack([x, y], axis=1).astype(np.float64) / float(1 << bits)


def sample(n_rays: int, seed: int) -> SampleSet:
    groups, m = split(n_rays)
    return SampleSet(sobol_2d(m), groups, False)
