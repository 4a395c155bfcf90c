"""``sobol`` (the default): per replicate, the first m = 2^k points of the 2-D Sobol sequence,
Owen-scrambled per
point, replicate and dimension (hash-based nested uniform scrambling, Burley 2020,
"Practical Hash-based Owen Scrambling", with the Laine-Karras permutation constants of
Vegdahl 2021).

Owen scrambling keeps the net's stratification in every elementary interval, gives each
sample an exactly uniform marginal (at 32-bit resolution: u = (x + 1/2) / 2^32), and makes
the replicates independent, so the replicate spread is an honest error; unlike a
Cranley-Patterson shift it does not make replicates agree exactly where visibility depends
on one coordinate only.
"""

from __future__ import annotations

import numpy as np

from aobake.rng import mix
from aobake.samplers.base import REPLICATES, SALTS, SampleSet, split

#: code of this sampler in aobake/_kernels.c
KERNEL = 2
_TWO_POW_M32 = 2.0**-32


def sobol_ints(m: int, start: int = 0) -> np.ndarray:
    """(m, 2) uint32: points start .. start + m - 1 of the 2-D Sobol sequence as 32-bit
    integers (Gray-code order; point / 2^32 in [0, 1)).

    Dimension 0 is the base-2 radical inverse; dimension 1 uses the direction
    numbers of the primitive polynomial x + 1: v_1 = 1/2, v_k = v_{k-1} xor (v_{k-1} / 2).
    """
    bits = 32
    v1 = np.array([1 << (bits - 1 - k) for k in range(bits)], dtype=np.uint64)
    v2 = np.empty(bits, dtype=np.uint64)
    v2[0] = 1 << (bits - 1)
    for k in range(1, bits):
        v2[k] = v2[k - 1] ^ (v2[k - 1] >> np.uint64(1))
    index = np.arange(start, start + m, dtype=np.uint64)
    i = index ^ (index >> np.uint64(1))  # Gray-code order, the standard Sobol enumeration
    x = np.zeros(m, dtype=np.uint64)
    y = np.zeros(m, dtype=np.uint64)
    for k in range(bits):
        bit = (i >> np.uint64(k)) & np.uint64(1)
        x ^= bit * v1[k]
        y ^= bit * v2[k]
    return np.stack([x, y], axis=1).astype(np.uint32)


def sobol_2d(m: int) -> np.ndarray:
    """(m, 2) float64: the first m unscrambled Sobol points in [0, 1)^2."""
    return sobol_ints(m).astype(np.float64) * _TWO_POW_M32


def reverse_bits(x: np.ndarray) -> np.ndarray:
    """uint32 array with its 32 bits reversed."""
    x = ((x >> np.uint32(1)) & np.uint32(0x55555555)) | ((x & np.uint32(0x55555555)) << np.uint32(1))
    x = ((x >> np.uint32(2)) & np.uint32(0x33333333)) | ((x & np.uint32(0x33333333)) << np.uint32(2))
    x = ((x >> np.uint32(4)) & np.uint32(0x0F0F0F0F)) | ((x & np.uint32(0x0F0F0F0F)) << np.uint32(4))
    x = ((x >> np.uint32(8)) & np.uint32(0x00FF00FF)) | ((x & np.uint32(0x00FF00FF)) << np.uint32(8))
    return (x >> np.uint32(16)) | (x << np.uint32(16))


def owen_scramble(x: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """Hash-based nested uniform (Owen) scramble of uint32 ``x`` with uint32 ``seed``
    (broadcast): reverse, Laine-Karras permutation, reverse (wrapping uint32 arithmetic)."""
    return owen_scramble_reversed(reverse_bits(x), seed)


def owen_scramble_reversed(x: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """:func:`owen_scramble` of ``reverse_bits(x)`` (the sampler stores its table reversed)."""
    with np.errstate(over="ignore"):
        x = x + seed
        x ^= x * np.uint32(0x6C50B47C)
        x ^= x * np.uint32(0xB82F1E52)
        x ^= x * np.uint32(0xC7AFE638)
        x ^= x * np.uint32(0x8D22F6E6)
    return reverse_bits(x)


def scramble_seeds(keys: np.ndarray) -> np.ndarray:
    """(k, R) uint64 replicate keys -> (k, R, 2) uint32 Owen seeds, one per dimension."""
    with np.errstate(over="ignore"):
        return np.stack([(mix(keys + SALTS[d]) >> np.uint64(32)).astype(np.uint32)
                         for d in range(2)], axis=-1)


def sample(n_rays: int, replicates: int = REPLICATES) -> SampleSet:
    """R replicates (default 8) of m = 2^k points, the smallest power of two with R m >= n_rays: a
    full (0, k, 2)-net per replicate (a prefix of other length loses most of the gain:
    104 rays as 8 x 13 are about as accurate as 64, benchmarks/study_intervals.py)."""
    groups, m = split(n_rays, replicates)
    m = 1 << (m - 1).bit_length()
    piece = SampleSet("sobol", groups, m, False, None).piece  # a power of two, <= m
    # Stored reversed (owen_scramble reverses first), only the first piece: the Sobol
    # points are a linear (xor) function of the Gray code of their index, and for j0 a
    # multiple of the power of two P > t, gray(j0 + t) = gray(j0) ^ gray(t); so points
    # j0 .. j0 + P - 1 are the first P xor point j0 (``shift``), and a streamed point needs
    # no table larger than one piece.
    table = reverse_bits(sobol_ints(piece))

    def shift(j0):
        return reverse_bits(sobol_ints(1, start=j0))[0]

    def values(keys, j0, count):
        seeds = scramble_seeds(keys)  # (k, R, 2)
        constants = samples.table_for(j0, count)
        x = owen_scramble_reversed(constants[None, None, :, :], seeds[:, :, None, :])
        # The centre of the 2^-32 cell: exactly uniform mean, and u0 < 1 (cos theta > 0).
        return (x.astype(np.float64) + 0.5) * _TWO_POW_M32  # (k, R, count, 2)

    samples = SampleSet("sobol", groups, m, False, values, kernel=KERNEL, table=table,
                        shift=shift)
    return samples
