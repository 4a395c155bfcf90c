"""Joint samples of a pixel: positions in the pixel and the directions of the AO rays cast
from their hits, drawn together (``--pixel-filter box``'s joint estimator,
``aobake.targets.view_box``).

A pixel's ``R`` replicates each hold ``m`` AO rays (the split of ``aobake.samplers``: sobol
rounds m up to a power of two, stratified to whole replicates, random is one group of
i.i.d. samples) at ``m / r`` positions: the rays of position slot q are rays q r .. q r +
r - 1.  Every value is a pure function of (replicate key, index), the keys of (seed,
pixel, replicate) from ``replicate_keys`` (the positions' and the directions' from streams
of their own), like every other random number aobake draws.  Per sampler:

* ``sobol``: *padded* Owen-scrambled Sobol nets (Burley 2020, "Practical Hash-based Owen
  Scrambling", section 4): slot q holds point sigma(q) of the 2-D Sobol net of m / r
  positions, sigma a hash-based nested-uniform shuffle of the index (a permutation), and
  ray i's direction is point i of the m-point net: sample i of ``aobake.samplers.sobol``'s
  one replicate of m on the direction key (the values the compiled ray generator draws).
  The positions are a (0, k, 2)-net, the directions another, a position's r rays an
  aligned block of r points (spread over the hemisphere), positions and blocks paired at
  random.
* ``stratified``: a jittered grid of the positions and another of the directions, its cells
  taken in the order of a random permutation pi (the same padding).
* ``random``: i.i.d. positions and directions, one ray per position (its direction sample
  0 of ``aobake.samplers.random`` on a key of its own).

Values are float64 in [0, 1) (a direction's first coordinate strictly below 1: the warps'
cos theta > 0).  Sample values of the other samplers (``aobake.samplers.sobol`` and the
rest) are not changed by this module.
"""

from __future__ import annotations

import functools
import sys

import numpy as np

from aobake.rng import dim_salt, mix, to_unit
from aobake.samplers.base import sample_hashes
from aobake.samplers.sobol import reverse_bits, sobol_ints

#: uint64 salts of the four dimensions (position x, y; direction u0, u1) and of the shuffle
_SALTS = tuple(np.uint64(dim_salt(d)) for d in range(5))
_TWO_POW_M32 = 2.0**-32
_HALF_CELL = 2.0**-33
_BELOW_ONE = float(np.nextafter(1.0, 0.0))
#: the Laine-Karras permutation constants of ``aobake.samplers.sobol``
_LK = tuple(np.uint32(c) for c in (0x6C50B47C, 0xB82F1E52, 0xC7AFE638, 0x8D22F6E6))
#: the steps that reverse the bits within each byte (shift, mask)
_SWAPS = tuple((np.uint32(s), np.uint32(m)) for s, m in
               ((1, 0x55555555), (2, 0x33333333), (4, 0x0F0F0F0F)))
_LITTLE = sys.byteorder == "little"
#: nets up to this many points are kept (a replicate's net is the same for every pixel)
CACHED_NET = 1 << 16


@functools.lru_cache(maxsize=8)
def net_reversed(m: int) -> tuple:
    """The first m points of the 2-D Sobol sequence, bits reversed (what the scramble
    starts from): one (m,) uint32 array per dimension, read only."""
    table = reverse_bits(sobol_ints(m))
    columns = tuple(np.ascontiguousarray(table[:, d]) for d in range(2))
    for column in columns:
        column.setflags(write=False)
    return columns


def _coordinate_reversed(index: np.ndarray, m: int, d: int) -> np.ndarray:
    """uint32 of index's shape: dimension d of Sobol points ``index`` (each < m), bits
    reversed."""
    if m <= CACHED_NET:
        return np.take(net_reversed(m)[d], index)
    return np.ascontiguousarray(_points_reversed(index, m)[..., d])


def _points_reversed(index: np.ndarray, m: int) -> np.ndarray:
    """(..., 2) uint32: Sobol points ``index`` (any shape, each < m), bits reversed,
    computed point by point (the nets beyond ``CACHED_NET``)."""
    flat = np.asarray(index, dtype=np.int64).reshape(-1)
    out = np.empty((len(flat), 2), dtype=np.uint32)
    # sobol_ints enumerates in Gray-code order: point j is the linear map of gray(j)
    for start in range(0, len(flat), 1 << 16):
        part = flat[start:start + (1 << 16)]
        gray = (part ^ (part >> 1)).astype(np.uint64)
        x = np.zeros(len(part), dtype=np.uint64)
        y = np.zeros(len(part), dtype=np.uint64)
        v = np.uint64(1 << 31)
        for k in range(32):
            bit = (gray >> np.uint64(k)) & np.uint64(1)
            x ^= bit * np.uint64(1 << (31 - k))
            y ^= bit * v
            v = v ^ (v >> np.uint64(1))
        out[start:start + len(part)] = reverse_bits(np.stack([x, y], axis=1).astype(np.uint32))
    return out.reshape(np.shape(index) + (2,))


def _reverse(x: np.ndarray) -> np.ndarray:
    """uint32 array (C-contiguous) with its 32 bits reversed, in place (returned): the bits
    of each byte swapped in three masked steps, then the bytes (``reverse_bits``' values)."""
    if not _LITTLE:  # pragma: no cover - big-endian machines
        return reverse_bits(x)
    tmp = np.empty_like(x)
    for shift, mask in _SWAPS:
        np.right_shift(x, shift, out=tmp)
        np.bitwise_and(tmp, mask, out=tmp)
        np.bitwise_and(x, mask, out=x)
        np.left_shift(x, shift, out=x)
        np.bitwise_or(x, tmp, out=x)
    return x.byteswap(inplace=True)


def _permute(reversed_x: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """uint32 ``owen_scramble`` of the values whose reversed bits are given (broadcast
    against uint32 ``seed``), still reversed: + seed, then Laine and Karras' permutation."""
    x = np.add(reversed_x, seed, dtype=np.uint32)
    tmp = np.empty_like(x)
    for c in _LK:
        np.multiply(x, c, out=tmp)
        np.bitwise_xor(x, tmp, out=x)
    return x


def _owen(x: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """``aobake.samplers.sobol.owen_scramble`` (the same bits), with the faster reverse."""
    return _reverse(_permute(_reverse(np.array(x, dtype=np.uint32)), seed))


def _scramble(reversed_points: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """float64 in (0, 1): ``owen_scramble`` of the points whose reversed bits are given
    (broadcast against uint32 ``seed``), at the centre of its 2^-32 cell (exactly uniform)."""
    out = _reverse(_permute(reversed_points, seed)).astype(np.float64)
    out *= _TWO_POW_M32
    out += _HALF_CELL
    return out


def seeds(keys: np.ndarray) -> np.ndarray:
    """(k, R) uint64 replicate keys -> (k, R, 5) uint32: the four dimensions' scramble seeds
    and the shuffle's."""
    with np.errstate(over="ignore"):
        return np.stack([(mix(keys + salt) >> np.uint64(32)).astype(np.uint32)
                         for salt in _SALTS], axis=-1)


def shuffle(j: np.ndarray, seed: np.ndarray, m: int) -> np.ndarray:
    """A random permutation of 0..m-1 applied to ``j`` (uint32, broadcast with uint32
    ``seed``): the nested-uniform (Owen) scramble of the index's 32 bits, whose low bits
    permute 0..M-1 (M the power of two >= m; the high bits of a j < M are zero and scramble
    to a constant), walked along its cycles until it lands below m (a permutation of 0..m-1
    for any m; for m a power of two, one step)."""
    bits = max(int(m) - 1, 0).bit_length()
    mask = np.uint32((1 << bits) - 1) if bits < 32 else np.uint32(0xFFFFFFFF)
    out = _owen(j, seed)  # (broadcast to both shapes)
    out &= mask
    todo = out >= m
    if todo.any():
        seed = np.broadcast_to(seed, out.shape)
        while todo.any():
            out[todo] = _owen(out[todo], seed[todo]) & mask
            todo = out >= m
    return out


def _grid_cells(index: np.ndarray, jitter_x, jitter_y, grid: tuple) -> np.ndarray:
    nx, ny = grid
    return np.minimum(np.stack([(index % nx + jitter_x) / nx, (index // nx + jitter_y) / ny],
                               axis=-1), _BELOW_ONE)  # (cell + jitter) / n may round to 1


def positions(name: str, keys: np.ndarray, key_seeds: np.ndarray, q0: int, count: int,
              per_replicate: int, grid: tuple = (0, 0)) -> np.ndarray:
    """(k, R, count, 2) float64 in [0, 1)^2: the positions of slots q0 .. q0 + count - 1 of
    every replicate (x right, y down from the pixel's top-left corner); slot q's rays are
    rays q r .. q r + r - 1 (``directions``).

    keys : (k, R) uint64 replicate keys, key_seeds : their ``seeds`` (k, R, 5),
    per_replicate : positions per replicate, grid : (nx, ny) the stratified sampler's
    grid of them.  sobol: slot q holds point sigma(q) of the positions' net, sigma a
    random shuffle (the pairing of positions and directions)."""
    q = np.arange(q0, q0 + count)
    if name == "sobol":
        order = shuffle(q.astype(np.uint32)[None, None, :], key_seeds[:, :, None, 4],
                        per_replicate)
        out = np.empty(order.shape + (2,))
        for d in range(2):
            out[..., d] = _scramble(_coordinate_reversed(order, per_replicate, d),
                                    key_seeds[:, :, None, d])
        return out
    h = sample_hashes(keys, q0, count)
    with np.errstate(over="ignore"):
        u = [to_unit(mix(h + salt)) for salt in _SALTS[:2]]
    if name == "random":
        return np.stack(u, axis=-1)
    if name == "stratified":
        return _grid_cells(q[None, None, :], u[0], u[1], grid)
    raise ValueError(f"no joint samples for sampler {name!r}")


def hashes_at(keys: np.ndarray, index: np.ndarray) -> np.ndarray:
    """uint64 ``sample_hashes`` of single samples: keys (h,) uint64 and index (h, c) int64
    -> (h, c), the hash of (key, sample index) that ``sample_hashes(keys, j0, count)``
    gives sample j."""
    with np.errstate(over="ignore"):
        j = (index.astype(np.uint64) + np.uint64(1)) * np.uint64(0xD1B54A32D192ED03)
        return mix(keys[:, None] + j)


def directions(name: str, keys: np.ndarray, index: np.ndarray, m: int,
               grid: tuple = (0, 0)) -> np.ndarray:
    """(h, c, 2) float64 in [0, 1)^2, the first coordinate < 1: the direction samples (the
    weighting's u0, u1) of rays ``index`` (h, c) int64 (each < m, the rays per replicate)
    of the replicates whose direction keys are ``keys`` (h,) uint64.

    sobol: ray i is sample i of ``aobake.samplers.sobol``'s one replicate of m on the key
    (point i of the Owen-scrambled net: a position's r rays are an aligned block of r
    points, spread over the hemisphere), the values the ray generator's kernel draws;
    random: sample i of ``aobake.samplers.random`` on the key; stratified: cell pi(i) of an
    nx x ny jittered grid, pi a random shuffle (its cells in order would give a
    position's rays one row of the grid)."""
    if name == "random":
        h = hashes_at(keys, index)
        with np.errstate(over="ignore"):
            return np.stack([to_unit(mix(h + salt)) for salt in _SALTS[:2]], axis=-1)
    key_seeds = seeds(keys)  # (h, 5)
    if name == "sobol":
        out = np.empty(index.shape + (2,))
        for d in range(2):
            out[..., d] = _scramble(_coordinate_reversed(index, m, d), key_seeds[:, None, d])
        return out
    if name == "stratified":
        order = shuffle(index.astype(np.uint32), key_seeds[:, None, 4], m)
        h = hashes_at(keys, index)
        with np.errstate(over="ignore"):
            jitter = [to_unit(mix(h + salt)) for salt in _SALTS[2:4]]
        return _grid_cells(order.astype(np.int64), jitter[0], jitter[1], grid)
    raise ValueError(f"no joint samples for sampler {name!r}")
