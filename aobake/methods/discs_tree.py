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


# ---------------------------------------------------------------------------- the robust model
#
# Hoberock and Jia's fixes to the chapter (GPU Gems 3, ch. 12), as ``discs_model = "robust"``
# does them (aobake.methods.discs has the whole model):
#
# - every term is the cosine-weighted form factor (the on-axis exact disc form factor far
#   away, Lambert's exact polygon form factor of the element's own triangles near it);
# - a node is blended with its children over a band of distances instead of switched at
#   kappa (and a leaf with its triangles), so the result is continuous in the receiver's
#   position;
# - every element has a second, flipped layer, present in proportion to how open its back
#   is (``presence``): an open sheet casts from both sides, a closed surface from its back.

#: the blend between a node and its children: the node alone beyond (1 + TRANSITION) kappa r,
#: its children alone within kappa r (r = sqrt(A / pi)), smoothstep in between.  A pair in
#: the band costs three terms (the node and both children) where a switch costs one or
#: two: 0.25 doubles the terms per point (bunny: 555 against 294 with a switch) for the
#: same error (0.0142 against 0.0150 at 0.1 and 0.0119 at 1.0, four times the terms)
TRANSITION = 0.25

#: receivers this close to a triangle's plane (local units, where the elements span [-1, 1])
#: are on it: they take the one-sided limit of its form factor (below)
PLANE_TOLERANCE = 2.0 ** -20

#: the height (times the triangle's longest edge) at which that limit is evaluated: the
#: limit's error is of this order, the rounding's eps / this (about 2e-10)
LIMIT_HEIGHT = 2.0 ** -20

#: a point this close to a triangle's edge (local units) is on it: rounding only, far below
#: LIMIT_HEIGHT x any triangle's size
EDGE_TOLERANCE = 2.0 ** -40

#: |n_R . n_f| at most this: the receiver's normal lies along the triangle's plane
CONTACT_COSINE = 1e-9


@dataclass(frozen=True)
class Triangles:
    """The elements' own triangles, for the exact near field.

    corners : (f, 3, 3) float64 the triangles' corners in the local frame, normal : (f, 3)
    float64 unit face normals (the winding's), start : (e + 1,) int64 and faces : (m,) int64
    the triangles around each element (element i's are ``faces[start[i]:start[i + 1]]``,
    each of non-zero area), an element being a third of each of them.
    """

    corners: np.ndarray
    normal: np.ndarray
    start: np.ndarray
    faces: np.ndarray

    @cached_property
    def size(self) -> np.ndarray:
        """(f,) float64 each triangle's longest edge."""
        c = self.corners
        edges = [c[:, 1] - c[:, 0], c[:, 2] - c[:, 1], c[:, 0] - c[:, 2]]
        return np.sqrt(np.maximum.reduce([_dot(e, e) for e in edges]))


def flipped_levels(tree: Tree, position: np.ndarray, normal: np.ndarray, area: np.ndarray,
                   presence: np.ndarray) -> list:
    """The flipped layer's nodes, level by level as ``tree.levels``: each node's elements with
    their normals reversed and their areas times ``presence`` (e,) in [0, 1]: area = sum of
    presence A, position = their presence-area-weighted mean (the node's own where that is
    0), normal = the unit presence-area-weighted sum of the reversed normals."""
    n = len(position)
    weight = presence * area
    p, nrm, a = position[tree.order], -normal[tree.order], weight[tree.order]
    out = []
    for level, nodes in enumerate(tree.levels[:-1]):
        starts = _starts(n, level)
        total = np.add.reduceat(a, starts)
        summed = np.add.reduceat(p * a[:, None], starts, axis=0)
        centre = nodes.position.copy()
        some = total > 0
        centre[some] = summed[some] / total[some, None]
        flipped = _unit(np.add.reduceat(nrm * a[:, None], starts, axis=0))
        out.append(Level(centre, flipped, total, nodes.radius))
    leaves = tree.levels[-1]
    full = tree.slots >= 0
    leaf_n = np.zeros_like(leaves.normal)
    leaf_a = np.zeros_like(leaves.area)
    leaf_n[full] = -normal[tree.slots[full]]
    leaf_a[full] = weight[tree.slots[full]]
    out.append(Level(leaves.position, leaf_n, leaf_a, leaves.radius))
    return out


def disc_form_factors(dx, dy, dz, d2, area, emitter_normal, receiver_normal,
                      front: bool = True):
    """(back, front): the disc form factor ``A sat(cos_E) sat(n_R . v) / (pi d^2 + A)`` seen
    from the element's back (cos_E = n_E . v: the receiver is behind it) and from its front
    (cos_E = -n_E . v); arguments as :func:`shadow_terms`.  One of the two is 0.  On axis it
    is sin^2(alpha), the cosine-weighted fraction of the hemisphere a disc covers (exact for
    a real disc); far away A cos cos / (pi d^2).  A pair at d = 0 gives 0.  front=False:
    (back, None)."""
    safe = np.where(d2 > 0, d2, 1.0)
    d = np.sqrt(safe)
    ex, ey, ez = emitter_normal
    rx, ry, rz = receiver_normal
    cos_e = (ex * dx + ey * dy + ez * dz) / d
    cos_r = (rx * dx + ry * dy + rz * dz) / d
    common = np.where(d2 > 0, area / (math.pi * safe + area) * np.clip(cos_r, 0.0, 1.0), 0.0)
    back = common * np.clip(cos_e, 0.0, 1.0)
    return back, (common * np.clip(-cos_e, 0.0, 1.0) if front else None)


def _edge(ax, ay, az, bx, by, bz, nx, ny, nz):
    """theta(a, b) n . unit(a x b) per row (0 where a x b = 0: an edge through the receiver or
    pointing at it adds nothing)."""
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    length = np.sqrt(cx * cx + cy * cy + cz * cz)
    theta = np.arctan2(length, ax * bx + ay * by + az * bz)
    safe = np.where(length > 0, length, 1.0)
    return np.where(length > 0, theta * (nx * cx + ny * cy + nz * cz) / safe, 0.0)


def triangle_form_factors(points: np.ndarray, normals: np.ndarray, corners: np.ndarray,
                          face_normal: np.ndarray, size: np.ndarray, contact: bool = True):
    """(back, front, enclosed, edge_on) (m,): the cosine-weighted form factor of triangle i at
    receiver i (Lambert's polygon formula, ``(1/2 pi) |sum over edges theta_e n_R . unit(a x
    b)|``, of the triangle clipped to the receiver's hemisphere), float64, as ``back`` where
    the receiver is behind the triangle (n_f . (p - x) < 0), else as ``front``; and two bool
    contacts.  points, normals (m, 3), corners (m, 3, 3), face_normal (m, 3) unit, size (m,)
    longest edges.

    A receiver on the triangle's plane (within ``PLANE_TOLERANCE``) sees it edge-on.  It takes
    the limit from the side its normal points to, the value a ray cast just off it would
    see: 0 for its own triangle on a flat or convex surface, 0 beside the triangle.  Lying
    on the triangle (within its edges) it touches it: facing its back (n_R . n_f < 0) it
    faces into what the triangle bounds (``enclosed``: a closed surface's inside, where
    nothing reaches it); facing along its plane (|n_R . n_f| <= ``CONTACT_COSINE``: a wall's
    foot on a floor) it is ``edge_on``: which side it is on is undefined, and the ray tracer,
    whose rays all start on the triangle, finds every one blocked (a hit at t = 0).  Both
    give back = front = 0; the caller decides what they block.
    """
    m = len(points)
    fx, fy, fz = face_normal[:, 0], face_normal[:, 1], face_normal[:, 2]
    px, py, pz = points[:, 0], points[:, 1], points[:, 2]
    side = fx * (corners[:, 0, 0] - px) + fy * (corners[:, 0, 1] - py) \
        + fz * (corners[:, 0, 2] - pz)  # n_f . (x - p): > 0 behind the triangle
    on = np.abs(side) <= PLANE_TOLERANCE
    nx, ny, nz = normals[:, 0], normals[:, 1], normals[:, 2]
    facing = nx * fx + ny * fy + nz * fz
    behind = np.where(on, facing < 0, side > 0)
    enclosed = np.zeros(m, dtype=bool)
    edge_on = np.zeros(m, dtype=bool)
    touched = np.flatnonzero(on)
    if len(touched):
        t = touched
        # onto the plane, then LIMIT_HEIGHT x the triangle's size off it, on the chosen side
        lift = side[t] + np.where(behind[t], -1.0, 1.0) * LIMIT_HEIGHT * size[t]
        px, py, pz = px.copy(), py.copy(), pz.copy()
        px[t] += lift * fx[t]
        py[t] += lift * fy[t]
        pz[t] += lift * fz[t]
        # facing the front of a triangle in its plane (a flat surface's own neighbours)
        # is no contact: only a normal along the plane or into its back can be
        t = touched[facing[touched] <= CONTACT_COSINE] if contact else touched[:0]
        if len(t):
            # on the triangle after the ray tracer's step off the surface along the normal
            # (its part along the plane: a point on an edge, stepping out, is beside it)
            along = normals[t] - facing[t, None] * face_normal[t]
            length = np.sqrt(_dot(along, along))
            step = LIMIT_HEIGHT * size[t] / np.where(length > 0, length, 1.0)
            touching = _within(points[t] + step[:, None] * along, corners[t], face_normal[t])
            edge_on[t] = touching & (np.abs(facing[t]) <= CONTACT_COSINE)
            enclosed[t] = touching & ~edge_on[t] & (facing[t] < 0)
    # only triangles with a corner above the receiver's horizon can add anything
    above = np.zeros(m, dtype=bool)
    for i in range(3):
        above |= (nx * (corners[:, i, 0] - px) + ny * (corners[:, i, 1] - py)
                  + nz * (corners[:, i, 2] - pz)) >= 0
    seen = np.flatnonzero(above & ~edge_on & ~enclosed)
    value = np.zeros(m)
    value[seen] = _clipped_lambert(px[seen], py[seen], pz[seen], nx[seen], ny[seen], nz[seen],
                                   corners[seen])
    return np.where(behind, value, 0.0), np.where(behind, 0.0, value), enclosed, edge_on


def _within(points, corners, face_normal) -> np.ndarray:
    """(m,) bool: point i, on triangle i's plane, lies inside it or on an edge (within
    ``EDGE_TOLERANCE``: rounding)."""
    inside = np.ones(len(points), dtype=bool)
    for i in range(3):
        a, b = corners[:, i], corners[:, (i + 1) % 3]
        e, q = b - a, points - a
        cross = np.stack([e[:, 1] * q[:, 2] - e[:, 2] * q[:, 1],
                          e[:, 2] * q[:, 0] - e[:, 0] * q[:, 2],
                          e[:, 0] * q[:, 1] - e[:, 1] * q[:, 0]], axis=1)
        # n_f . (e x q) is |e| times the point's distance inside edge i
        inside &= _dot(face_normal, cross) >= -EDGE_TOLERANCE * np.sqrt(_dot(e, e))
    return inside


def _clipped_lambert(px, py, pz, nx, ny, nz, corners) -> np.ndarray:
    """(m,) float64 Lambert's form factor of triangle i, clipped to the hemisphere of normal
    n (nx, ny, nz) at p (px, py, pz): (1 / 2 pi) |sum over the clipped polygon's edges of
    theta_e n . unit(a x b)|."""
    r = [(corners[:, i, 0] - px, corners[:, i, 1] - py, corners[:, i, 2] - pz) for i in range(3)]
    s = [nx * x + ny * y + nz * z for x, y, z in r]  # heights above the receiver's horizon
    total = np.zeros(len(px))
    crossing = []
    for i in range(3):
        j = (i + 1) % 3
        (ax, ay, az), (bx, by, bz), sa, sb = r[i], r[j], s[i], s[j]
        up_a, up_b = sa >= 0, sb >= 0
        t = np.clip(sa / np.where(sa != sb, sa - sb, 1.0), 0.0, 1.0)
        xx, xy, xz = ax + t * (bx - ax), ay + t * (by - ay), az + t * (bz - az)
        crossing.append((xx, xy, xz, up_a & ~up_b, ~up_a & up_b))
        # the part of edge i above the horizon: from a (or the crossing) to b (or it)
        start = (np.where(up_a, ax, xx), np.where(up_a, ay, xy), np.where(up_a, az, xz))
        stop = (np.where(up_b, bx, xx), np.where(up_b, by, xy), np.where(up_b, bz, xz))
        total += np.where(up_a | up_b, _edge(*start, *stop, nx, ny, nz), 0.0)
    # the clipped polygon's edge along the horizon: from where it leaves to where it returns
    leave = [np.zeros(len(px)) for _ in range(3)]
    enter = [np.zeros(len(px)) for _ in range(3)]
    clipped = np.zeros(len(px), dtype=bool)
    for xx, xy, xz, out, back in crossing:
        for k, value in enumerate((xx, xy, xz)):
            leave[k] = np.where(out, value, leave[k])
            enter[k] = np.where(back, value, enter[k])
        clipped |= out
    cut = np.flatnonzero(clipped)
    if len(cut):
        total[cut] += _edge(*(x[cut] for x in leave), *(x[cut] for x in enter), nx[cut],
                            ny[cut], nz[cut])
    return np.abs(total) / (2.0 * math.pi)


def _smooth_far(q2: np.ndarray, band: float) -> np.ndarray:
    """The weight of a node's own disc at (d / (kappa r))^2 = q2: 0 where q2 < 1 (its children
    instead), 1 from q = 1 + band on, smoothstep in between; band 0: the chapter's switch."""
    if band <= 0:
        return (q2 >= 1.0).astype(np.float64)
    x = np.clip((np.sqrt(q2) - 1.0) / band, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def gather_robust(tree: Tree, flipped: list, triangles: Triangles | None, presence: np.ndarray,
                  weights: list, receivers: np.ndarray, normals: np.ndarray, kappa: float,
                  max_distance: float, budget: int, kinds=None, brute: bool = False,
                  band: float | None = None, contact: bool = True
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Sums at c receivers under the robust model, through the hierarchy.

    tree and flipped (:func:`flipped_levels`) : the two layers, triangles : the exact near
    field (None: discs at every distance), presence : (e,) the flipped layer's weight per
    element, weights, receivers, normals, kappa, max_distance, budget : as
    :func:`gather_tree`; brute : open every node above the leaves (each element its own
    term: O(n) per receiver), band : :data:`TRANSITION`.  Column kinds (``KINDS``):
    ``shadow`` = F_back w + F_flipped (the flipped layer's presence is in its area),
    ``light`` = F_front w, ``blocked`` = F_back w, F the form factors of
    :func:`disc_form_factors` (of a leaf opened: of its triangles, a third each).

    Every (receiver, node) pair carries a weight: 1 at the root; a node at q = d / (kappa r)
    adds its disc times the pair's weight times _smooth_far(q), and hands the rest on to its
    children (a leaf: to its triangles), so the blend is continuous.  Each receiver's sums
    are made from its own terms alone in a fixed order (level by level; in a level, discs
    then triangles), so any split of the receivers gives the same bits.
    Returns (sums (c, w) float64, terms (c,) int64: discs and triangles evaluated).
    """
    band = TRANSITION if band is None else band
    c = len(receivers)
    columns = weights[0].shape[1]
    groups = _groups(kinds, columns)
    need_front = any(kind == "light" for kind, _ in groups)
    sums = np.zeros((c, columns))
    terms = np.zeros(c, dtype=np.int64)
    open_factor = kappa * kappa / math.pi
    limited = math.isfinite(max_distance)
    here = np.concatenate([receivers, normals], axis=1)
    stack = [(0, np.arange(c, dtype=np.int64), np.zeros(c, dtype=np.int64), np.ones(c))]
    while stack:
        level, rec, node, carried = stack.pop()
        if len(rec) == 0:
            continue
        nodes, other = tree.levels[level], flipped[level]
        leaf = level == tree.depth
        g, h = nodes.packed[node], here[rec]
        dx, dy, dz = g[:, 0] - h[:, 0], g[:, 1] - h[:, 1], g[:, 2] - h[:, 2]
        d2 = dx * dx + dy * dy + dz * dz
        area = g[:, 6]
        if brute and not leaf:
            far = np.zeros(len(rec))
        elif leaf and triangles is None:
            far = np.ones(len(rec))
        else:
            far = _smooth_far(d2 / (open_factor * area), band)
        keep = np.ones(len(rec), dtype=bool)
        if limited:
            if leaf:
                keep = d2 <= max_distance * max_distance
            else:
                d = np.sqrt(d2)
                reach = g[:, 7]
                inside = d + reach <= max_distance
                keep = d - reach <= max_distance  # a node wholly beyond it: nothing
                far = np.where(inside, far, 0.0)  # one the limit cuts: look closer
        accept = carried * np.where(keep, far, 0.0)
        onward = carried * np.where(keep, 1.0 - far, 0.0)
        low = int(rec[0])
        span = int(rec[-1]) - low + 1
        local = rec - low
        w = weights[level]
        taken = np.flatnonzero(accept > 0)
        if len(taken):
            # only the pairs that add something (a blended or far node): the rest are opened
            i, a = taken, accept[taken]
            hn = (h[i, 3], h[i, 4], h[i, 5])
            back, front = disc_form_factors(dx[i], dy[i], dz[i], d2[i], area[i],
                                            (g[i, 3], g[i, 4], g[i, 5]), hn, need_front)
            flipped_part = np.zeros(len(i))
            present = np.flatnonzero(other.area[node[i]] > 0)  # closed surfaces: none
            if len(present):
                f, j = other.packed[node[i[present]]], i[present]
                fx, fy, fz = f[:, 0] - h[j, 0], f[:, 1] - h[j, 1], f[:, 2] - h[j, 2]
                flipped_part[present], _ = disc_form_factors(
                    fx, fy, fz, fx * fx + fy * fy + fz * fz, f[:, 6], (f[:, 3], f[:, 4], f[:, 5]),
                    (h[j, 3], h[j, 4], h[j, 5]), False)
            _add(sums, groups, w[node[i]], back * a, None if front is None else front * a,
                 flipped_part * a, local[i], low, span)
            terms[low:low + span] += np.bincount(local[i], minlength=span).astype(np.int64)
        near = onward > 0
        if not near.any():
            continue
        if leaf:
            pair = np.flatnonzero(near)
            element = tree.slots[node[pair]]
            count = triangles.start[element + 1] - triangles.start[element]
            which = np.repeat(np.arange(len(pair)), count)
            first = np.repeat(triangles.start[element] - np.cumsum(count) + count, count)
            face = triangles.faces[first + np.arange(len(which))]
            # A triangle near a receiver is near all three of its corners' elements: its
            # form factor is a function of (receiver, triangle) alone, computed once.
            key = rec[pair[which]] * np.int64(len(triangles.normal)) + face
            key, row, inverse = np.unique(key, return_index=True, return_inverse=True)
            at, face_u = rec[pair[which[row]]], face[row]
            back, front, enclosed, edge_on = (x[inverse.reshape(-1)] for x in triangle_form_factors(
                receivers[at], normals[at], triangles.corners[face_u], triangles.normal[face_u],
                triangles.size[face_u], contact))
            scale = onward[pair] / 3.0  # an element is a third of each of its triangles
            back = np.bincount(which, back, minlength=len(pair)) * scale
            front = np.bincount(which, front, minlength=len(pair)) * scale
            # contact blocks for certain: not weighted by any pass (a closed surface's
            # inside by how closed it is, 1 - presence)
            certain = (np.bincount(which, enclosed, minlength=len(pair))
                       * (1.0 - presence[element])
                       + np.bincount(which, edge_on, minlength=len(pair))) * scale
            _add(sums, groups, w[node[pair]], back, front, front * presence[element] + certain,
                 local[pair], low, span)
            terms[low:low + span] += np.bincount(local[pair], count,
                                                  minlength=span).astype(np.int64)
            continue
        parents_r, parents, share = rec[near], node[near], onward[near]
        child_r = np.repeat(parents_r, 2)
        child = (2 * parents[:, None] + np.arange(2)).ravel()
        child_w = np.repeat(share, 2)
        if level + 1 == tree.depth:  # drop empty leaf slots
            full = tree.levels[-1].area[child] > 0
            child_r, child, child_w = child_r[full], child[full], child_w[full]
        for piece in _cut(child_r, budget):
            stack.append((level + 1, child_r[piece], child[piece], child_w[piece]))
    return sums, terms


def _add(sums, groups, w, back, front, flipped, local, low, span):
    """Adds one level's terms to the receivers' sums, per column kind (``gather_robust``)."""
    for kind, cols in groups:
        for j in cols:
            if kind == "shadow":
                value = back * w[:, j] + flipped
            elif kind == "light":
                value = front * w[:, j]
            else:
                value = back * w[:, j]
            sums[low:low + span, j] += np.bincount(local, value, minlength=span)
