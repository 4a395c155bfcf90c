"""Exact order statistics (median, percentile) of float64 values read a block at a time.

``np.median`` and ``np.percentile`` partition a copy of their input: 8 bytes a value while
they run.  The report takes them over every baked point (the median ray offset, the 95th
percentile of each quantity's stderr); for a set of N instances that is 8 bytes a point of
every instance, a temporary that grows with N.  Here the same numbers, bit for bit, come
from passes over the values a block at a time (the caller's ``blocks()`` yields them again
on each call, in any order and any cut: an order statistic depends on the multiset alone):

1. a histogram of each value's top HISTOGRAM_BITS of its sortable key (the float's bits,
   ordered as the floats are) finds the bin holding the wanted rank;
2. where that bin holds at most ``limit`` values they are gathered and partitioned (the
   rank's exact value); else the next HISTOGRAM_BITS of the key in that bin are
   histogrammed, and so on (64 bits at most: 4 passes).

Memory: the histograms (2^16 int64, 0.5 MiB) and at most ``limit`` gathered values,
whatever the count.  Then ``np.median``'s and ``np.percentile``'s own arithmetic on the
order statistics found (:func:`median`, :func:`percentile`), so the value is theirs.
"""

from __future__ import annotations

from typing import Callable, Iterable

import numpy as np

#: bits of the key each histogram pass resolves (2^16 bins)
HISTOGRAM_BITS = 16
#: the most values a pass gathers to partition (8 MiB of float64)
GATHER_LIMIT = 1 << 20
_SIGN = np.uint64(1 << 63)


def sortable_keys(values: np.ndarray) -> np.ndarray:
    """(n,) uint64 keys ordered as the float64 ``values`` (n,) are: the bits of a value >= +0
    with the sign bit set, those of a negative one inverted (-0.0 sorts just below +0.0;
    the partitions below compare the floats themselves, where they are equal)."""
    bits = np.ascontiguousarray(values, dtype=np.float64).view(np.uint64)
    negative = (bits & _SIGN) != 0
    return np.where(negative, ~bits, bits | _SIGN)


class TopCounts:
    """The first pass of :func:`order_statistics`, fed a block at a time (``add``): the
    histogram of the values' top HISTOGRAM_BITS of key, their count, whether any is NaN.
    A caller that makes the values anyway (the tracer, its ray offsets) counts them as it
    goes, and the selection then reads the values again only for the bins it needs."""

    def __init__(self):
        self.hist = np.zeros(1 << HISTOGRAM_BITS, dtype=np.int64)
        self.n, self.nan = 0, False

    def add(self, values: np.ndarray) -> None:
        """Count (k,) float64 ``values``."""
        if not len(values):
            return
        self.n += len(values)
        self.nan = self.nan or bool(np.isnan(values).any())
        top = (sortable_keys(values) >> np.uint64(64 - HISTOGRAM_BITS)).astype(np.int64)
        self.hist += np.bincount(top, minlength=len(self.hist))


def order_statistics(blocks: Callable[[], Iterable[np.ndarray]], ranks_of,
                     limit: int | None = None, first: TopCounts | None = None
                     ) -> tuple[list, int]:
    """([the k-th smallest value for each k of ``ranks_of(n)``], n the count of values),
    exact.

    blocks : a function returning an iterable of (k,) float64 arrays, the same values on
    each call (every pass reads them again); ranks_of : n -> 0-based ranks, each < n
    (called once the first pass has counted them); limit : the most values gathered at once
    (default GATHER_LIMIT); first : the first pass, already counted (:class:`TopCounts`),
    or None.  NaN anywhere: every statistic is NaN (as np.median / np.percentile give).
    Returns ([], 0) when there are no values.

    A bin whose values all have one key (ties: a constant array, offsets that are all one
    power of two) is resolved by the pass that finds its keys' min equal to their max."""
    limit = GATHER_LIMIT if limit is None else limit
    if first is None:
        first = TopCounts()
        for values in blocks():
            first.add(values)
    n = first.n
    if n == 0:
        return [], 0
    ranks = [int(r) for r in ranks_of(n)]
    if first.nan:
        return [float("nan")] * len(ranks), n
    if any(r < 0 or r >= n for r in ranks):
        raise ValueError(f"ranks {ranks} outside 0..{n - 1}")
    # each rank: (prefix of the key, bits resolved, rank within the prefix, values there)
    state = [_narrow(first.hist, 0, 0, r) for r in ranks]
    found: dict = {}
    while len(found) < len(ranks):
        # gather where the bin is small enough; else histogram its next bits
        gather = {i: s for i, s in enumerate(state) if i not in found and
                  (s[3] <= limit or s[1] >= 64)}
        refine = {i: s for i, s in enumerate(state) if i not in found and i not in gather}
        # one pass serves every rank in the same bin
        gathered = {(s[0], s[1]): [] for s in gather.values()}
        hists = {(s[0], s[1]): [np.zeros(1 << HISTOGRAM_BITS, dtype=np.int64),
                                np.uint64(2**64 - 1), np.uint64(0)] for s in refine.values()}
        for values in blocks():
            if not len(values):
                continue
            keys = sortable_keys(values)
            for (prefix, bits), out in gathered.items():
                out.append(values[_in_bin(keys, prefix, bits)])
            for (prefix, bits), bin_ in hists.items():
                inside = keys[_in_bin(keys, prefix, bits)]
                if not len(inside):
                    continue
                low = 64 - bits - HISTOGRAM_BITS
                bin_[0] += np.bincount(((inside >> np.uint64(low)) &
                                        np.uint64((1 << HISTOGRAM_BITS) - 1)).astype(np.int64),
                                       minlength=len(bin_[0]))
                bin_[1], bin_[2] = min(bin_[1], inside.min()), max(bin_[2], inside.max())
        for key, pieces in gathered.items():  # one partition for the ranks of a bin
            values = np.concatenate(pieces)
            mine = {i: s[2] for i, s in gather.items() if (s[0], s[1]) == key}
            values.partition(sorted(set(mine.values())))
            found.update({i: float(values[rank]) for i, rank in mine.items()})
        for i, (prefix, bits, rank, _) in refine.items():
            hist, lowest, highest = hists[(prefix, bits)]
            if lowest == highest:  # every value of the bin has one key: it is the value
                found[i] = float(_value_of(lowest))
            else:
                state[i] = _narrow(hist, prefix, bits, rank)
    return [found[i] for i in range(len(ranks))], n


def _value_of(key: np.uint64) -> np.float64:
    """The float64 whose :func:`sortable_keys` key is ``key``."""
    bits = np.uint64(key)
    bits = bits & ~_SIGN if bits & _SIGN else ~bits
    return np.array([bits], dtype=np.uint64).view(np.float64)[0]


def _narrow(hist: np.ndarray, prefix: int, bits: int, rank: int) -> tuple:
    """The bin of ``hist`` (the next HISTOGRAM_BITS of the keys with ``prefix`` on their top
    ``bits``) holding rank ``rank``: (its prefix, its bits, the rank within it, its count)."""
    below = np.cumsum(hist)
    b = int(np.searchsorted(below, rank, side="right"))
    start = int(below[b - 1]) if b else 0
    return (prefix << HISTOGRAM_BITS) | b, bits + HISTOGRAM_BITS, rank - start, int(hist[b])


def _in_bin(keys: np.ndarray, prefix: int, bits: int) -> np.ndarray:
    """(n,) bool the keys whose top ``bits`` are ``prefix``."""
    if bits >= 64:
        return keys == np.uint64(prefix)
    return (keys >> np.uint64(64 - bits)) == np.uint64(prefix)


def median(blocks: Callable[[], Iterable[np.ndarray]]) -> float | None:
    """``float(np.median(values))`` of all the blocks' values, the same bits; None without
    values.  np.median takes the middle value, or the mean of the two middle ones: that
    mean is np.mean's of the pair (np.median's own), so the bits are its."""
    values, n = order_statistics(blocks, lambda n: [n // 2] if n % 2 else [n // 2 - 1, n // 2])
    if n == 0:
        return None
    return float(np.median(np.array(values, dtype=np.float64)))


def percentile(blocks: Callable[[], Iterable[np.ndarray]], q: float) -> float | None:
    """``float(np.percentile(values, q))`` (its default, linear, method) of all the blocks'
    values, the same bits; None without values.

    np.percentile's steps for n values: q / 100, the virtual index (n - 1) q (its linear
    method's), its floor and the next index
    (both the last where the virtual index reaches n - 1, the first below 0), the weight
    their difference, and ``_lerp``: a + (b - a) t, or b - (b - a)(1 - t) where t >= 0.5."""
    q = np.true_divide(q, 100)
    where = {}

    def ranks_of(n):
        virtual = (n - 1) * q
        previous = np.floor(virtual)
        if virtual >= n - 1:
            lo = hi = n - 1
        elif virtual < 0:
            lo = hi = 0
        else:
            lo, hi = int(previous), int(previous) + 1
        where["t"] = float(virtual - previous)
        return [lo, hi]

    values, n = order_statistics(blocks, ranks_of)
    if n == 0:
        return None
    a, b = values
    if np.isnan(a):
        return float("nan")
    t = where["t"]
    a, b = np.float64(a), np.float64(b)
    diff = b - a
    return float(b - diff * (1 - t) if t >= 0.5 else a + diff * t)


def of_array(values: np.ndarray, mask: np.ndarray | None = None,
             block: int = 1 << 16) -> Callable[[], Iterable[np.ndarray]]:
    """``blocks`` for :func:`median` / :func:`percentile` of (n,) ``values`` (where ``mask``
    (n,) bool, if given): views of a block of rows at a time, no copy of the whole."""
    def blocks():
        for start in range(0, len(values), block):
            rows = values[start:start + block]
            yield rows if mask is None else rows[mask[start:start + block]]
    return blocks
