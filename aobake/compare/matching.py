"""Matching two files' copies of one mesh's vertices by position, in any order.

Positions pair up within ``position_tolerance``; vertices that coincide (a seam's or a hard
edge's copies, a double-sided surface) are told apart by ``tie_features`` (normals, the
faces around them), which depend on the geometry, not on the vertex order.  The work grows
as n log n whatever the duplicates (4,000 vertices at one point cost what 4,000 apart do).
"""

from __future__ import annotations

import math

import numpy as np

#: Vertices match when every coordinate agrees within this fraction of the reference's size
#: (the larger of its largest |coordinate| and its extent): 2^-19 is 32 float32 half-ulps, so
#: float32 (GLB) and 9-digit text copies of float64 positions match, while distinct
#: vertices of any mesh that float32 can represent stay apart.
POSITION_TOLERANCE = 2.0 ** -19
#: tie features this close (normals, faces' centroids / size) cannot tell two vertices apart
_FEATURE_TIE = 1e-6


def position_tolerance(positions: np.ndarray) -> float:
    """The matching tolerance for ``positions`` (n, 3) float: ``POSITION_TOLERANCE`` times the
    larger of the largest |coordinate| (float32's spacing grows with it) and the extent."""
    positions = np.asarray(positions, dtype=np.float64)
    if not len(positions):
        return 0.0
    high, low = positions.max(axis=0), positions.min(axis=0)
    with np.errstate(over="ignore"):
        extent = float(np.max(high - low))
    largest = float(np.max(np.abs(positions)))
    if not math.isfinite(extent):  # beyond float64 (coordinates near +-1.8e308): in halves
        return 2 * POSITION_TOLERANCE * max(largest / 2, float(np.max(high / 2 - low / 2)))
    return POSITION_TOLERANCE * max(largest, extent, np.finfo(float).tiny)


def match_vertices(reference: np.ndarray, candidate: np.ndarray, tol: float,
                   features: tuple | None = None, used: np.ndarray | None = None
                   ) -> tuple[np.ndarray, str, int]:
    """Match two copies of the same vertices, in any order.

    reference : (n, 3) float positions; candidate : (m, 3) float positions, m <= n;
    tol : a coordinate difference allowed;
    features : (reference (n, d), candidate (m, d)) float or None: what tells coincident
      vertices apart (``tie_features``: normals, the faces around them); among coincident
      vertices each reference vertex takes the candidate nearest in features, ties in file
      order;
    used : (n,) bool or None: the reference vertices a face uses.  With it the candidate
      may lack reference vertices no face uses (trimesh drops them when it loads a mesh);
      without it every reference vertex needs a partner (m == n).
    Returns (order (n,) int64, how, ambiguous): ``candidate[order[i]]`` is reference vertex
    i, -1 where it has none (only unused vertices); how is 'order' (same order already) or
    'position'; ambiguous counts the reference vertices that coincide with another in
    position and features (paired in file order).
    Raises ValueError describing the mismatch.

    The work is O((n + m) log(n + m)) whatever the duplicates: positions are bucketed in a
    grid of cells of 3 tol (never compared pairwise), and coincident vertices are paired
    within each bucket by features: directly in a bucket of a few (as many comparisons as
    pairs of them, at most ``_DENSE``^2), by sorting quantised features in a larger one.
    """
    reference = np.asarray(reference, dtype=np.float64)
    candidate = np.asarray(candidate, dtype=np.float64)
    n, m = len(reference), len(candidate)
    if m > n or (m < n and used is None):
        raise ValueError(f"{m} vertices against {n}")
    for label, array in (("reference", reference), ("candidate", candidate)):
        if not np.isfinite(array).all():
            raise ValueError(f"the {label} positions are not all finite")
    if m == n and np.all(np.abs(reference - candidate) <= tol):
        return np.arange(n), "order", 0
    ref_cluster, cand_cluster = _clusters(reference, candidate, tol)
    lost = np.flatnonzero(cand_cluster < 0)
    if len(lost):
        x, y, z = candidate[lost[0]]
        raise ValueError(f"{len(lost)} vertices (the first, {lost[0]}, at ({x:.9g}, {y:.9g}, "
                         f"{z:.9g})) are not within {tol:.3g} of any reference vertex")
    if features is None:
        fr, fc = np.zeros((n, 0)), np.zeros((m, 0))
    else:
        fr, fc = (np.asarray(f, dtype=np.float64) for f in features)
    used = np.ones(n, bool) if used is None else np.asarray(used, dtype=bool)
    order, ambiguous = _pair(ref_cluster, cand_cluster, fr, fc, used)
    paired = order >= 0
    if not np.all(np.abs(reference[paired] - candidate[order[paired]]) <= tol):
        raise ValueError("the vertex positions do not pair up one to one with the reference's")
    missing = np.flatnonzero(~paired & used)
    if len(missing):
        x, y, z = reference[missing[0]]
        raise ValueError(f"lacks {len(missing)} of the vertices the reference's faces use (the "
                         f"first, {missing[0]}, at ({x:.9g}, {y:.9g}, {z:.9g}))")
    return order, "position", ambiguous


def tie_features(positions: np.ndarray, normals: np.ndarray | None, faces: np.ndarray | None,
                 size: float) -> np.ndarray:
    """What tells coincident vertices apart: (n, d) float64 of the normal (3, when given)
    and, when faces are given, the mean centroid of the faces around the vertex divided by
    ``size`` and the unit sum of their area vectors (3 + 3: a seam's or a hard edge's copies
    differ in the first, a double-sided surface's in the second; zero on no face); d = 0
    with neither.  All are properties of the geometry, not of the vertex order, so two
    files of one mesh agree on them."""
    parts = []
    if normals is not None:
        parts.append(np.asarray(normals, dtype=np.float64))
    if faces is not None:
        # in units of ``size`` (the mesh's), so areas neither overflow nor underflow
        # whatever the scene's scale; a vertex far beyond it (one that matches nothing)
        # may still overflow: its features are zeros
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            corners = (np.asarray(positions, dtype=np.float64) / size)[faces]  # (f, 3, 3)
            centroid = corners.mean(axis=1)
            area = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
            n, at = len(positions), faces.reshape(-1)  # each face's values go to its 3 corners
            per_face = np.repeat(np.hstack([centroid, area]), 3, axis=0)
            total = np.column_stack([np.bincount(at, per_face[:, j], n) for j in range(6)])
            count = np.bincount(at, minlength=n).astype(np.float64)
            length = np.sqrt(np.sum(total[:, 3:] ** 2, axis=1, keepdims=True))
            parts += [total[:, :3] / np.maximum(count, 1.0)[:, None],
                      total[:, 3:] / np.where(length > 0, length, 1.0)]
    features = np.hstack(parts) if parts else np.zeros((len(positions), 0))
    return np.where(np.isfinite(features), features, 0.0)


#: a cell's neighbours in a grid: the 13 offsets of one half of the 26 (the other half
#: is the same pairs seen from the other side)
_HALF = np.array([(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)
                  if (dx, dy, dz) > (0, 0, 0)], dtype=np.int64)
#: cell indices are kept within +-_CELLS (so three of them pack into one int64 key)
_CELLS = 1 << 18


def _clusters(reference: np.ndarray, candidate: np.ndarray, tol: float):
    """Buckets of vertices that may be copies of one another: (ref (n,) int64, cand (m,)
    int64, -1 for a candidate vertex with no reference vertex near it).

    Reference vertices fall in cells of side s = 3 tol (or more: at most 2^18 cells across
    the reference), and touching non-empty cells are joined into one bucket (two reference
    vertices within 2 tol of one candidate vertex lie in touching cells).  A candidate
    vertex's box of +-1.25 tol (a margin over tol for rounding) meets at most two cells per
    axis, all touching, so its bucket is the one of any non-empty cell among them.  Only
    cells are looked up (14 per reference cell, 8 per candidate vertex): no pair of
    vertices is ever compared here, so coincident vertices cost nothing extra.
    """
    largest = float(np.max(np.abs(reference), initial=0.0))
    side = 3.0 * max(tol, largest / _CELLS, np.finfo(float).tiny)
    width = 2 * _CELLS + 16  # indices shifted by _CELLS + 8 into [0, width)

    def index(p):
        with np.errstate(over="ignore", invalid="ignore"):
            q = np.floor(p / side)
        return np.clip(q, -_CELLS - 4, _CELLS + 4).astype(np.int64) + _CELLS + 8

    def key(q):
        return (q[..., 0] * width + q[..., 1]) * width + q[..., 2]

    cells, ref_cell = np.unique(key(index(reference)), return_inverse=True)
    ref_cell = ref_cell.reshape(-1)

    def lookup(keys):
        at = np.minimum(np.searchsorted(cells, keys), len(cells) - 1)
        return np.where(cells[at] == keys, at, -1)

    # touching non-empty cells: one bucket (connected components over the 13 half-offsets)
    steps = key(_HALF)
    found = lookup(cells[:, None] + steps[None, :])
    a, b = np.nonzero(found >= 0)
    label = _components(len(cells), a, found[a, b])
    lo, hi = index(candidate - 1.25 * tol), index(candidate + 1.25 * tol)
    cand = np.full(len(candidate), -1, dtype=np.int64)
    for corner in range(8):  # the box's corners pick lo or hi per axis
        pick = np.array([(corner >> axis) & 1 for axis in range(3)], dtype=bool)
        at = lookup(key(np.where(pick, hi, lo)))
        fill = (cand < 0) & (at >= 0)
        cand[fill] = label[at[fill]]
    return label[ref_cell], cand


def _components(count: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Connected components of ``count`` nodes joined by edges (a[k], b[k]): each node's
    smallest member (roots hooked onto smaller roots, then pointer jumping, until every
    edge joins equal labels; a few rounds)."""
    label = np.arange(count)
    while len(a):
        ra, rb = label[a], label[b]
        differ = ra != rb
        if not differ.any():
            break
        np.minimum.at(label, np.maximum(ra, rb)[differ], np.minimum(ra, rb)[differ])
        while True:
            jumped = label[label]
            if np.array_equal(jumped, label):
                break
            label = jumped
    return label


#: buckets with at most this many reference or candidate vertices are paired by comparing
#: every pair (the greedy nearest in features); larger ones by sorting
_DENSE = 16
#: features are compared in quanta of this size in large buckets (well above float32's
#: noise in them, well below the difference between a seam's or a hard edge's copies)
_QUANTUM = 1e-4
#: elements per dense comparison array (a batch of buckets at a time)
_BATCH = 1 << 21


def _pair(ref_cluster, cand_cluster, fr, fc, used):
    """Pair each candidate vertex with a reference vertex of its bucket: (order (n,) int64,
    -1 for reference vertices left without one, ambiguous count).  Used reference vertices
    are paired before unused ones.  Raises ValueError when a bucket has more candidate
    vertices than reference ones."""
    n = len(ref_cluster)
    count = int(max(ref_cluster.max(initial=-1), cand_cluster.max(initial=-1))) + 1
    nr = np.bincount(ref_cluster, minlength=count)
    nc = np.bincount(cand_cluster, minlength=count)
    if np.any(nc > nr):
        raise ValueError("the vertex positions do not pair up one to one with the reference's")
    # members of every bucket, in file order within it
    ref_sorted = np.lexsort((~used, ref_cluster))  # used ones first within a bucket
    cand_sorted = np.argsort(cand_cluster, kind="stable")
    ref_start = np.concatenate([[0], np.cumsum(nr)])
    cand_start = np.concatenate([[0], np.cumsum(nc)])
    order = np.full(n, -1, dtype=np.int64)
    ambiguous = 0
    active = np.flatnonzero(nc > 0)
    size = np.maximum(nr, nc)[active]
    dense, large = active[size <= _DENSE], active[size > _DENSE]
    shapes = nr[dense] * (_DENSE + 1) + nc[dense]
    for shape in np.unique(shapes):
        buckets = dense[shapes == shape]
        r, k = int(nr[buckets[0]]), int(nc[buckets[0]])
        rows = ref_sorted[ref_start[buckets][:, None] + np.arange(r)]
        cols = cand_sorted[cand_start[buckets][:, None] + np.arange(k)]
        if r == 1 and k == 1:
            order[rows[:, 0]] = cols[:, 0]
            continue
        step = max(1, _BATCH // (r * max(r, k) * max(fr.shape[1], 1)))
        for at in range(0, len(buckets), step):
            ambiguous += _pair_dense(rows[at:at + step], cols[at:at + step], fr, fc, used, order)
    if len(large):
        ambiguous += _pair_sorted(large, ref_sorted, cand_sorted, ref_start, cand_start, nr, nc,
                                  ref_cluster, fr, fc, used, order)
    return order, ambiguous


def _pair_dense(rows, cols, fr, fc, used, order) -> int:
    """Buckets of r reference (rows (B, r)) and k candidate (cols (B, k)) vertices: the
    closest remaining pair in features first, unused reference vertices last; ``order``
    filled.  Returns the paired reference vertices that tie with another in features."""
    b, r = rows.shape
    k = cols.shape[1]
    features = fr[rows]  # (B, r, d)
    apart = np.abs(features[:, :, None, :] - fc[cols][:, None, :, :]).max(axis=3, initial=0.0)
    spare = ~used[rows]
    if spare.any():  # unused reference vertices: beyond any used one, so taken last
        apart += spare[:, :, None] * (apart.max(initial=0.0) + 1.0)
    self_apart = np.abs(features[:, :, None, :] - features[:, None, :, :]).max(axis=3,
                                                                              initial=0.0)
    self_apart[:, np.arange(r), np.arange(r)] = np.inf
    tie = self_apart.min(axis=2) <= _FEATURE_TIE
    index, done = np.arange(b), np.zeros((b, r), bool)
    for _ in range(k):  # greedy: the closest remaining pair of each bucket first
        a, c = np.divmod(apart.reshape(b, -1).argmin(axis=1), k)
        order[rows[index, a]] = cols[index, c]
        done[index, a] = True
        apart[index, a, :] = np.inf
        apart[index, :, c] = np.inf
    return int(np.count_nonzero(tie & done))


def _pair_sorted(buckets, ref_sorted, cand_sorted, ref_start, cand_start, nr, nc, ref_cluster,
                 fr, fc, used, order) -> int:
    """Large buckets: reference and candidate vertices whose features agree to within
    ``_QUANTUM`` are paired by sorting on the quantised features, on d + 1 grids shifted by
    a (d + 1)th of a quantum (two values closer than that share a cell on at least one of
    them); the rest of a bucket in file order (used reference vertices first).  Returns
    the reference vertices paired in file order among equals (ties and the rest)."""
    def members(start, counts, sorted_):
        index = np.repeat(start[buckets], counts[buckets])
        index += np.arange(len(index)) - np.repeat(np.cumsum(counts[buckets]) - counts[buckets],
                                                   counts[buckets])
        return sorted_[index], np.repeat(buckets, counts[buckets])

    refs, ref_bucket = members(ref_start, nr, ref_sorted)
    cands, cand_bucket = members(cand_start, nc, cand_sorted)
    d = fr.shape[1]
    grids = d + 1 if d else 1
    free_r = np.ones(len(refs), bool)
    free_c = np.ones(len(cands), bool)
    ambiguous = 0
    for g in range(grids):
        shift = g / grids
        kr = np.column_stack([ref_bucket[free_r], np.floor(fr[refs[free_r]] / _QUANTUM + shift)])
        kc = np.column_stack([cand_bucket[free_c], np.floor(fc[cands[free_c]] / _QUANTUM + shift)])
        keys, group = np.unique(np.vstack([kr, kc]), axis=0, return_inverse=True)
        group = group.reshape(-1)
        gr, gc = group[:len(kr)], group[len(kr):]
        if g == 0:  # reference vertices sharing a cell with another: ties
            ambiguous_groups = np.bincount(gr, minlength=len(keys)) > 1
        ir, ic = np.flatnonzero(free_r), np.flatnonzero(free_c)
        rank_r = _rank(gr, ~used[refs[ir]])
        rank_c = _rank(gc, np.zeros(len(gc), bool))
        span = max(len(gr), len(gc)) + 1
        code_r, code_c = gr * span + rank_r, gc * span + rank_c
        sorter = np.argsort(code_r)
        at = np.minimum(np.searchsorted(code_r, code_c, sorter=sorter), len(code_r) - 1)
        hit = code_r[sorter[at]] == code_c
        pr, pc = ir[sorter[at[hit]]], ic[hit]
        order[refs[pr]] = cands[pc]
        if g == 0:
            ambiguous += int(np.count_nonzero(ambiguous_groups[gr[sorter[at[hit]]]]))
        free_r[pr], free_c[pc] = False, False
        if not free_c.any():
            break
    if free_c.any():  # the rest: in file order within the bucket, used reference vertices first
        ir, ic = np.flatnonzero(free_r), np.flatnonzero(free_c)
        rank_r = _rank(ref_bucket[ir], ~used[refs[ir]])
        rank_c = _rank(cand_bucket[ic], np.zeros(len(ic), bool))
        span = max(len(ir), len(ic)) + 1
        code_r = ref_bucket[ir] * span + rank_r
        code_c = cand_bucket[ic] * span + rank_c
        sorter = np.argsort(code_r)
        at = np.searchsorted(code_r, code_c, sorter=sorter)
        order[refs[ir[sorter[at]]]] = cands[ic]
        ambiguous += len(ic)
    return ambiguous


def _rank(group: np.ndarray, later: np.ndarray) -> np.ndarray:
    """Each item's rank within its group: ``later`` ones after the others, then the given
    (file) order."""
    sorter = np.lexsort((np.arange(len(group)), later, group))
    ranks = np.empty(len(group), dtype=np.int64)
    sorted_group = group[sorter]
    first = np.concatenate([[True], sorted_group[1:] != sorted_group[:-1]]) if len(group) else \
        np.zeros(0, bool)
    start = np.maximum.accumulate(np.where(first, np.arange(len(group)), 0)) if len(group) else \
        np.zeros(0, np.int64)
    ranks[sorter] = np.arange(len(group)) - start
    return ranks
