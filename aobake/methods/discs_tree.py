"""The disc hierarchy of ``--method discs`` and the gathers that read it.

A balanced binary k-d tree over the elements (oriented discs: ``aobake.methods.discs``):
level 0 is the root, level ``depth`` the leaves (one element or nothing per slot).  Node
``i`` of level ``l`` holds the elements ``order[(i n) >> l : ((i + 1) n) >> l]``: every level
is a split of the one above at each segment's middle, after the segment was sorted along
its widest axis (a median split), so a node's elements are a compact piece of surface.
Its children are nodes ``2 i`` and ``2 i + 1`` of level ``l + 1``.

A node stands for its elements as one disc: summed area, area-weighted mean position,
normalised area-weighted sum of normals (zero where they cancel: such a node casts
nothing when accepted), and per pass the area-weighted mean of its elements' accessibility.
``radius`` is the distance from that position to its farthest element centre (for the
max-distance test).

A gather visits, per receiver, the root, then each node's children where the receiver is
too close for the node's disc to stand in for them (``d < kappa sqrt(A / pi)``) or where
the max-distance sphere cuts the node; every node it does not open is one disc term.
Each receiver's sum is made from its own terms alone, in a fixed order (level by level,
within a level in tree order), so any split of the receivers gives the same bits.

A gather sums several columns at once, each with its own kernel (``KINDS``): the chapter's
shadow (AO), or the disc-to-disc form factor seen from the element's front (light it
emits: indirect light) or from its back (light it blocks: the indirect light's shadow
passes).  A column's sums do not depend on the other columns gathered with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class Level:
    """One level of m nodes: position (m, 3) float64, normal (m, 3) float64 unit (zero:
    the normals cancel, or an empty leaf slot), area (m,) float64 (0 = empty slot),
    radius (m,) float64 distance from the position to the farthest element centre."""

    position: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    radius: np.ndarray

    @cached_property
    def packed(self) -> np.ndarray:
        """(m, 8) float64 rows x, y, z, nx, ny, nz, area, radius: one gather per pair."""
        return np.concatenate([self.position, self.normal, self.area[:, None],
                               self.radius[:, None]], axis=1)


@dataclass(frozen=True)
class Tree:
    """levels : coarsest first, ``depth + 1`` of them (2^l nodes at level l; the last holds
    the elements), order : (n,) int64 element of each position in tree order, slots : (2^depth,)
    int64 the element at each leaf slot or -1, area : (n,) float64 the elements' areas."""

    levels: list
    order: np.ndarray
    slots: np.ndarray
    area: np.ndarray

    @property
    def depth(self) -> int:
        return len(self.levels) - 1

    def node_values(self, values: np.ndarray) -> list:
        """Per-element values (n, c) float64 -> [(2^l, c) float64 per level]: each node's
        area-weighted mean over its elements (0 in an empty leaf slot)."""
        n = len(self.order)
        weighted = values[self.order] * self.area[self.order][:, None]
        out = []
        for level, nodes in enumerate(self.levels[:-1]):
            starts = _starts(n, level)
            sums = np.add.reduceat(weighted, starts, axis=0)
            out.append(sums / nodes.area[:, None])
        leaf = np.zeros((len(self.slots), values.shape[1]))
        full = self.slots >= 0
        leaf[full] = values[self.slots[full]]
        out.append(leaf)
        return out


def _starts(n: int, level: int) -> np.ndarray:
    """(2^level,) int64 first position of each node's segment (all non-empty below the
    leaf level: 2^level < n there)."""
    return (np.arange(1 << level, dtype=np.int64) * n) >> level


def build(position: np.ndarray, normal: np.ndarray, area: np.ndarray) -> Tree:
    """The tree of n elements: position (n, 3), normal (n, 3) unit, area (n,) > 0, float64."""
    n = len(position)
    depth = max(0, math.ceil(math.log2(n))) if n > 1 else 0
    order = np.arange(n, dtype=np.int64)
    for level in range(depth):
        starts = _starts(n, level)
        sizes = np.diff(np.append(starts, n))
        segment = np.repeat(np.arange(len(starts)), sizes)
        p = position[order]
        extent = np.maximum.reduceat(p, starts, axis=0) - np.minimum.reduceat(p, starts, axis=0)
        axis = np.argmax(extent, axis=1)  # the widest axis of each segment (first on ties)
        key = p[np.arange(n), axis[segment]]
        order = order[np.lexsort((key, segment))]  # stable: equal keys keep their order
    # Leaf slot j holds positions (j n) >> depth .. ((j + 1) n) >> depth - 1: one or none.
    slot_start = _starts(n, depth) if n else np.zeros(1, dtype=np.int64)
    slot_stop = np.append(slot_start[1:], n)
    slots = np.where(slot_stop > slot_start, order[np.minimum(slot_start, max(n - 1, 0))], -1)
    levels = []
    p, nrm, a = position[order], normal[order], area[order]
    for level in range(depth):
        starts = _starts(n, level)
        sizes = np.diff(np.append(starts, n))
        total = np.add.reduceat(a, starts)
        centre = np.add.reduceat(p * a[:, None], starts, axis=0) / total[:, None]
        summed = np.add.reduceat(nrm * a[:, None], starts, axis=0)
        offset = p - np.repeat(centre, sizes, axis=0)
        reach = np.maximum.reduceat(_dot(offset, offset), starts)
        levels.append(Level(centre, _unit(summed), total, np.sqrt(reach)))
    full = slots >= 0
    leaf_p = np.zeros((len(slots), 3))
    leaf_n = np.zeros((len(slots), 3))
    leaf_a = np.zeros(len(slots))
    leaf_p[full], leaf_n[full], leaf_a[full] = (position[slots[full]], normal[slots[full]],
                                                area[slots[full]])
    levels.append(Level(leaf_p, leaf_n, leaf_a, np.zeros(len(slots))))
    return Tree(levels, order, slots, area)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row dot products of (k, 3) arrays, summed x + y + z (the same bits for any k: no
    reduction whose order depends on the array's length or alignment)."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def _unit(vectors: np.ndarray) -> np.ndarray:
    length = np.sqrt(_dot(vectors, vectors))
    out = np.zeros_like(vectors)
    ok = length > 0
    out[ok] = vectors[ok] / length[ok, None]
    return out


def shadow_terms(dx, dy, dz, d2, area, emitter_normal, receiver_normal, k: float):
    """The chapter's element-to-receiver shadow (``occlusion.cg``'s SolidAngle):

        (1 - 1 / sqrt(A / (pi d^2) + 1)) * sat(n_E . v) * sat(k n_R . v)

    dx, dy, dz : the components of emitter position - receiver position (v = that / d:
    receiver -> emitter), d2 : their squared length, area : A, emitter_normal and
    receiver_normal : (nx, ny, nz) unit components; arrays of any broadcastable shapes,
    float64.  Returns float64 in [0, 1): 0 = casts nothing.  sat(n_E . v) > 0 when the
    receiver is behind the emitter: shadows are cast from an element's back (the chapter:
    light is emitted and reflected from the front, transmitted and shadowed from the back).
    ``1 - 1/s`` is evaluated as ``x / (s (s + 1))`` (s = sqrt(1 + x), x = A / (pi d^2)): the
    same number without the cancellation that rounds a far disc's shadow to 0.  A pair at
    d = 0 (the receiver's own element, or one at the same position) has no direction and
    casts nothing.  Every step is an elementwise IEEE operation, so a pair's value never
    depends on the other pairs computed with it.
    """
    safe = np.where(d2 > 0, d2, 1.0)
    x = area / (math.pi * safe)
    s = np.sqrt(1.0 + x)
    solid = x / (s * (s + 1.0))
    d = np.sqrt(safe)
    ex, ey, ez = emitter_normal
    rx, ry, rz = receiver_normal
    cos_e = (ex * dx + ey * dy + ez * dz) / d
    cos_r = (rx * dx + ry * dy + rz * dz) / d
    value = solid * np.clip(cos_e, 0.0, 1.0) * np.clip(k * cos_r, 0.0, 1.0)
    return np.where(d2 > 0, value, 0.0)


#: the kernels a gathered column may use: ``shadow`` (the chapter's shadow of an element's
#: back, ``shadow_terms``), ``light`` (the form factor of its front: the light it emits),
#: ``blocked`` (the form factor of its back: the light it blocks)
KINDS = ("shadow", "light", "blocked")


def form_factor_terms(dx, dy, dz, d2, area, emitter_normal, receiver_normal, side: str):
    """The disc-to-disc form factor of the chapter (section 14.4), in AO's normalisation:

        A sat(cos_E) sat(n_R . v) / (pi d^2 + A)

    arguments as :func:`shadow_terms` (v = (dx, dy, dz) / d, unit, receiver -> element).
    ``side = "light"``: cos_E = n_E . (-v), positive when the element's **front** faces the
    receiver (light is emitted and reflected from the front); ``side = "blocked"``: cos_E =
    n_E . v, positive when the receiver sees the element's **back** (shadows are cast from
    the back: the same sign as :func:`shadow_terms`).  No gain k on the receiver's cosine.

    On axis (both cosines 1) it is A / (pi d^2 + A) = sin^2(alpha), alpha = atan(r / d) the
    half-angle of a disc of radius r = sqrt(A / pi): exactly (1/pi) int cos dw over the disc,
    the cosine-weighted fraction of the hemisphere it covers, so a disc of uniform radiance
    L gives the receiver L sin^2(alpha) in the units of ``-q indirect``.  Far away it falls as
    A cos_E cos_R / (pi d^2), the point-to-point form factor.  Returns float64 in [0, 1);
    a pair at d = 0 gives 0.
    """
    safe = np.where(d2 > 0, d2, 1.0)
    d = np.sqrt(safe)
    ex, ey, ez = emitter_normal
    rx, ry, rz = receiver_normal
    cos_e = (ex * dx + ey * dy + ez * dz) / d
    if side == "light":
        cos_e = -cos_e
    cos_r = (rx * dx + ry * dy + rz * dz) / d
    value = area / (math.pi * safe + area) * np.clip(cos_e, 0.0, 1.0) * np.clip(cos_r, 0.0, 1.0)
    return np.where(d2 > 0, value, 0.0)


def _kernel(kind: str, dx, dy, dz, d2, area, emitter_normal, receiver_normal, k: float):
    if kind == "shadow":
        return shadow_terms(dx, dy, dz, d2, area, emitter_normal, receiver_normal, k)
    return form_factor_terms(dx, dy, dz, d2, area, emitter_normal, receiver_normal, kind)


def _groups(kinds, columns: int) -> list:
    """[(kind, [column, ...])] in KINDS order; ``kinds`` None: every column a shadow."""
    kinds = ("shadow",) * columns if kinds is None else tuple(kinds)
    if len(kinds) != columns:
        raise ValueError(f"{columns} weight columns but {len(kinds)} kinds")
    unknown = set(kinds) - set(KINDS)
    if unknown:
        raise ValueError(f"kinds must be some of {KINDS}, got {sorted(unknown)}")
    return [(kind, [j for j in range(columns) if kinds[j] == kind])
            for kind in KINDS if kind in kinds]


def gather_tree(tree: Tree, weights: list, receivers: np.ndarray, normals: np.ndarray,
                k: float, kappa: float, max_distance: float, budget: int, kinds=None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Shadow sums at c receivers through the hierarchy.

    weights : per level (2^l, w) float64, each column one weighting of the emitters' shadows
    (1, or an earlier pass's accessibility), receivers : (c, 3), normals : (c, 3) unit,
    kappa : open a node where d^2 < kappa^2 A / pi, max_distance : elements whose centre is
    farther contribute nothing (inf: no limit), budget : the most (receiver, node) pairs held
    at once (a front over it is cut between receivers, which changes no bit), kinds : (w,)
    each column's kernel (``KINDS``; None: every column a shadow).
    Returns (sums (c, w) float64, terms (c,) int64 disc terms evaluated per receiver).
    """
    c = len(receivers)
    columns = weights[0].shape[1]
    groups = _groups(kinds, columns)
    sums = np.zeros((c, columns))
    terms = np.zeros(c, dtype=np.int64)
    open_factor = kappa * kappa / math.pi
    limited = math.isfinite(max_distance)
    # One gather per pair of each side: receiver (x, y, z, nx, ny, nz).
    here = np.concatenate([receivers, normals], axis=1)
    stack = [(0, np.arange(c, dtype=np.int64), np.zeros(c, dtype=np.int64))]
    while stack:
        level, rec, node = stack.pop()
        if len(rec) == 0:
            continue
        nodes = tree.levels[level]
        leaf = level == tree.depth
        g = nodes.packed[node]  # (k, 8): x, y, z, nx, ny, nz, area, radius
        h = here[rec]
        dx, dy, dz = g[:, 0] - h[:, 0], g[:, 1] - h[:, 1], g[:, 2] - h[:, 2]
        d2 = dx * dx + dy * dy + dz * dz
        area = g[:, 6]
        if leaf:
            accept = area > 0
            if limited:
                accept &= d2 <= max_distance * max_distance
            opened = None
        else:
            opened = d2 < open_factor * area
            accept = ~opened
            if limited:
                d = np.sqrt(d2)
                reach = g[:, 7]
                inside = d + reach <= max_distance  # every element within the limit
                outside = d - reach > max_distance  # every element beyond it
                opened |= ~inside & ~outside  # the limit cuts the node: look closer
                accept = ~opened & inside
        if accept.any():
            # Every pair is evaluated and the unaccepted ones add 0 (x + 0.0 == x): cheaper
            # than compressing eight arrays, and each receiver's sum sees the same terms in
            # the same order.
            low = int(rec[0])
            span = int(rec[-1]) - low + 1  # rec is sorted: this piece's receivers
            local = rec - low
            w = weights[level]
            for kind, cols in groups:
                value = _kernel(kind, dx, dy, dz, d2, area, (g[:, 3], g[:, 4], g[:, 5]),
                                (h[:, 3], h[:, 4], h[:, 5]), k)
                value = np.where(accept, value, 0.0)
                for j in cols:
                    sums[low:low + span, j] += np.bincount(local, value * w[node, j],
                                                           minlength=span)
            terms[low:low + span] += np.bincount(local, accept, minlength=span).astype(np.int64)
        if opened is None or not opened.any():
            continue
        parents_r, parents = rec[opened], node[opened]
        child_r = np.repeat(parents_r, 2)
        child = (2 * parents[:, None] + np.arange(2)).ravel()
        if level + 1 == tree.depth:  # drop empty leaf slots
            keep = tree.levels[-1].area[child] > 0
            child_r, child = child_r[keep], child[keep]
        for piece in _cut(child_r, budget):
            stack.append((level + 1, child_r[piece], child[piece]))
    return sums, terms


def _cut(receiver: np.ndarray, budget: int) -> list:
    """Slices of a receiver-sorted front of at most ``budget`` pairs each, cut only between
    receivers (one receiver's pairs always stay together); pushed in reverse so the first
    piece is taken first."""
    n = len(receiver)
    if n <= budget:
        return [slice(0, n)]
    pieces, start = [], 0
    while start < n:
        stop = min(n, start + budget)
        if stop < n:
            # back to the start of the receiver at `stop`, unless that empties the piece
            boundary = int(np.searchsorted(receiver, receiver[stop], side="left"))
            if boundary > start:
                stop = boundary
            else:  # one receiver over the budget: its whole front, past the budget
                stop = int(np.searchsorted(receiver, receiver[start], side="right"))
        pieces.append(slice(start, stop))
        start = stop
    return pieces[::-1]


def gather_brute(position: np.ndarray, normal: np.ndarray, area: np.ndarray,
                 weights: np.ndarray, receivers: np.ndarray, normals: np.ndarray, k: float,
                 max_distance: float, budget: int, kinds=None) -> tuple[np.ndarray, np.ndarray]:
    """Shadow sums at c receivers from every one of n elements (O(c n)).

    position, normal (n, 3), area (n,), weights (n, w) float64; the rest as
    :func:`gather_tree`.  Each receiver's row of terms is summed along one contiguous row
    (numpy's pairwise sum of that row alone), so any split gives the same bits.
    """
    c, n = len(receivers), len(position)
    groups = _groups(kinds, weights.shape[1])
    sums = np.zeros((c, weights.shape[1]))
    rows = max(1, budget // max(n, 1))
    limited = math.isfinite(max_distance)
    emitter = (normal[None, :, 0], normal[None, :, 1], normal[None, :, 2])
    for start in range(0, c, rows):
        stop = min(c, start + rows)
        here, nr = receivers[start:stop], normals[start:stop]
        dx = position[None, :, 0] - here[:, None, 0]  # (r, n)
        dy = position[None, :, 1] - here[:, None, 1]
        dz = position[None, :, 2] - here[:, None, 2]
        d2 = dx * dx + dy * dy + dz * dz
        for kind, cols in groups:
            value = _kernel(kind, dx, dy, dz, d2, area[None, :], emitter,
                            (nr[:, None, 0], nr[:, None, 1], nr[:, None, 2]), k)
            if limited:
                value = np.where(d2 <= max_distance * max_distance, value, 0.0)
            for j in cols:
                sums[start:stop, j] = np.ascontiguousarray(value * weights[None, :, j]).sum(axis=1)
    return sums, np.full(c, n, dtype=np.int64)
