"""Meshes as they come: triangles wound against their neighbours, and shells turned inside out.

Pure functions over numpy arrays; :func:`aobake.scene.make_scene` calls them
(``--fix-normals warn|fix|off``).

Rules (docs/conventions.md, Geometry):

* **Components.** Two triangles are neighbours when they share a *manifold* edge: an
  edge (pair of vertex indices) used by exactly those two triangles.  Edges used by
  one triangle (boundary) or by three or more (non-manifold) connect nothing.  A
  component is a set of triangles connected through manifold edges; it is *closed*
  when none of its triangles has a boundary or non-manifold edge.  Triangles with a
  repeated corner index have no orientation and belong to no component (-1).
* **Winding.** Neighbours are consistent when they traverse their shared edge in
  opposite directions.  Each component is made consistent by a 2-colouring of its
  triangles (a union-find that carries parities); the colour holding the smaller
  share of the component's area (ties: fewer triangles, then the colour opposite the
  component's first triangle) is "wound against its neighbours".  A non-orientable
  component (a Moebius strip) has manifold edges no colouring satisfies; they are
  counted (``conflicting_edges``) and left as they are.
* **Inward.** After that, a closed component points inward when its signed volume
  ``sum det(v0 - c, v1 - c, v2 - c) / 6`` (c: the mean of its corners) is negative
  (beyond 1e-8 of the sum of the absolute terms: a zero-volume shell, e.g. two
  coincident layers, is never called inward).  A *nearly closed* component (a body with
  a few small holes: eye sockets, a neck) is closed first: each boundary loop gets a
  fan of triangles from its vertices' mean, and it counts as nearly closed when those
  caps total at most NEARLY_CLOSED (5%) of its area; its capped volume then decides as
  for a closed one.  Any other open component has no inside: it points inward when
  the file gave vertex normals and they disagree with it, ``sum_faces (2 area n_face) .
  (n_0 + n_1 + n_2) < 0`` over its triangles' corners; without file normals it keeps
  the orientation of its majority.  A closed shell meant to face inward (a room, a
  Cornell box, a cavity) is called inward too: that is why the default mode only warns.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from aobake import _native
from aobake.rng import stable_sort
from aobake.vectors import distinct

#: --fix-normals choices: report and change nothing | repair | skip the detection
MODES = ("warn", "fix", "off")

#: a closed component's |signed volume| at most this fraction of the sum of its absolute
#: terms has no decidable inside (float64 rounding of the sum is ~1e-16 per term)
UNDECIDED_VOLUME = 1e-8
#: an open component whose boundary loops, capped by fans, total at most this fraction of
#: its area is oriented by its capped volume, like a closed one (a bowl's cap is half its
#: area, a plane's all of it: both stay open; the ogre's body, 0.6%, is nearly closed)
NEARLY_CLOSED = 0.05
#: faces per block of the per-face geometry
BLOCK = 1 << 16


@dataclass(frozen=True)
class Orientation:
    """Result of :func:`orient`.

    component : (f,) int64        component of each triangle, 0..n_components-1 numbered in
                                  order of their first triangle; -1 for a triangle with a
                                  repeated corner index
    against : (f,) bool           wound against its neighbours (the minority colour)
    flip : (f,) bool              to flip for a consistent, outward orientation:
                                  ``against`` xor ``inward[component]``
    closed : (c,) bool            component without boundary or non-manifold edges
    nearly_closed : (c,) bool     open component whose capped holes are small
                                  (NEARLY_CLOSED): oriented by volume
    inward : (c,) bool            component (once consistent) points into the surface
    conflicting_edges : int       manifold edges no consistent winding can satisfy
    """

    component: np.ndarray
    against: np.ndarray
    flip: np.ndarray
    closed: np.ndarray
    nearly_closed: np.ndarray
    inward: np.ndarray
    conflicting_edges: int

    @property
    def n_components(self) -> int:
        return int(len(self.closed))

    def counts(self) -> dict:
        """The detector's numbers (report keys)."""
        # (a mask, not np.unique: numpy 2's hashing unique took 23 ms on spot's faces)
        with_against = distinct(self.component[self.against], self.n_components)
        return {
            "components": self.n_components,
            "closed_components": int(np.count_nonzero(self.closed)),
            "nearly_closed_components": int(np.count_nonzero(self.nearly_closed)),
            "faces_against_neighbours": int(np.count_nonzero(self.against)),
            "components_with_faces_against": int(len(with_against)),
            "inward_components": int(np.count_nonzero(self.inward)),
            "conflicting_edges": self.conflicting_edges,
        }


def _proper(faces: np.ndarray) -> np.ndarray:
    """(f,) bool: the triangle's three corner indices differ (it has an orientation)."""
    return (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])


class EdgePairs(NamedTuple):
    """Result of :func:`manifold_pairs`.

    a, b : (e,) int64       triangles sharing an edge used by no other triangle
    same : (e,) bool        both traverse it in the same direction (inconsistent neighbours)
    open_start, open_end : (o,) int64  the other edges (boundary or non-manifold), as
                            their triangle traverses them
    open_owner : (o,) int64 the triangle of each
    open_face : (f,) bool   triangles with such an edge, and those left out
    """

    a: np.ndarray
    b: np.ndarray
    same: np.ndarray
    open_start: np.ndarray
    open_end: np.ndarray
    open_owner: np.ndarray
    open_face: np.ndarray


def manifold_pairs(faces: np.ndarray, n_vertices: int) -> EdgePairs:
    """Triangle pairs sharing a manifold edge, and the edges that are not.

    faces : (f, 3) int64, n_vertices : int.  Triangles with a repeated corner index are
    left out (they have no orientation).

    Memory: the edge keys and their order (16 bytes an edge, 48 a triangle) while the
    sort runs; every other per-edge value is read back through the order (edge e is
    corner e % 3 of proper triangle e // 3) where it is needed."""
    faces = np.asarray(faces, dtype=np.int64)
    proper = _proper(faces)
    index = np.flatnonzero(proper)
    tri = faces if len(index) == len(faces) else faces[index]  # every triangle: no copy
    if n_vertices >= 3_037_000_499:  # lo * n + hi would overflow int64
        raise ValueError(f"too many vertices ({n_vertices}) for the edge keys")
    start = np.ascontiguousarray(tri).reshape(-1)
    end = np.roll(tri, -1, axis=1).reshape(-1)
    forward = start < end
    key = np.minimum(start, end)
    key *= np.int64(n_vertices)
    key += np.maximum(start, end, out=end)  # the larger end in place of ``end``
    del end, start
    order, key = stable_sort(key, n_vertices * n_vertices, _native.kernels())
    new = np.ones(len(key), dtype=bool)
    np.not_equal(key[1:], key[:-1], out=new[1:])
    del key
    starts = np.flatnonzero(new)
    del new
    lengths = np.diff(np.append(starts, len(order)))
    first = starts[lengths == 2]
    other = order[np.repeat(lengths != 2, lengths)]
    del starts, lengths
    edge = order[first]
    a = index[edge // 3]
    same = forward[edge]
    edge = order[first + 1]
    b = index[edge // 3]
    same = same == forward[edge]
    del edge, order, first, forward
    t, c = other // 3, other % 3
    open_start, open_end, open_owner = tri[t, c], tri[t, (c + 1) % 3], index[t]
    open_face = ~proper
    open_face[open_owner] = True
    return EdgePairs(a, b, same, open_start, open_end, open_owner, open_face)


def _parity_union_find(n: int, a: np.ndarray, b: np.ndarray, odd: np.ndarray, kernels=None):
    """Components of the graph on 0..n-1 with edges (a, b) and a parity per node such that
    ``parity[a] ^ parity[b] == odd`` wherever the constraints allow.

    Vectorised hook-and-jump: every round each root with an edge to another tree hooks
    onto the smallest root it reaches (ties: the lexically first (root, parity)), then
    pointer jumping flattens every tree.  Roots only ever hook onto smaller roots, so
    the final root of a component is its smallest node and the result is a pure
    function of the inputs.  Returns (root (n,) int64, parity (n,) bool).
    kernels : the compiled module (``aobake._native.kernels()``) or None: its
    ``parity_union_find`` runs the same rounds (the same bits, also the parities of a
    non-orientable component; tested), ~20x faster than the numpy rounds.
    """
    if kernels is not None:
        root, parity = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.bool_)
        kernels.parity_union_find(np.ascontiguousarray(a, dtype=np.int64),
                                  np.ascontiguousarray(b, dtype=np.int64),
                                  np.ascontiguousarray(odd, dtype=np.bool_).view(np.uint8),
                                  root, parity.view(np.uint8))
        return root, parity
    parent = np.arange(n, dtype=np.int64)
    parity = np.zeros(n, dtype=bool)
    live_a, live_b, live_odd = a, b, odd
    while True:
        while True:  # pointer jumping: parity to the grandparent is the xor of the two steps
            grand = parent[parent]
            if np.array_equal(grand, parent):
                break
            parity = parity ^ parity[parent]
            parent = grand
        ra, rb = parent[live_a], parent[live_b]
        crossing = ra != rb
        if not crossing.any():
            return parent, parity
        live_a, live_b, live_odd = live_a[crossing], live_b[crossing], live_odd[crossing]
        ra, rb = ra[crossing], rb[crossing]
        # flip[ra] ^ flip[rb] implied by this edge: symmetric in the two ends
        between = parity[live_a] ^ parity[live_b] ^ live_odd
        high, low = np.maximum(ra, rb), np.minimum(ra, rb)
        order = np.lexsort((between, low, high))
        pick = np.ones(len(order), dtype=bool)
        pick[1:] = high[order][1:] != high[order][:-1]
        chosen = order[pick]
        parent[high[chosen]] = low[chosen]
        parity[high[chosen]] = between[chosen]


def orient(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> Orientation:
    """Find the triangles wound against their neighbours and the components turned inward.

    vertices : (v, 3) float64 (best re-centred and scaled: the volumes are products of
    three coordinates), faces : (f, 3) int64, normals : (v, 3) float64 | None the file's
    vertex normals (any length; zero rows = none), used only to orient open components.
    The rules are in the module docstring.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    n_faces = len(faces)
    compiled = _native.kernels()
    edges = manifold_pairs(faces, len(vertices))
    a, b, same, open_face = edges.a, edges.b, edges.same, edges.open_face
    root, parity = _parity_union_find(n_faces, a, b, same, compiled)
    conflicting = int(np.count_nonzero((parity[a] ^ parity[b]) != same))

    proper = _proper(faces)
    # np.unique(root[proper], return_inverse=True) without a sort: roots ascend, so ranks in
    # a mask over the face indices are the labels (first-face order)
    is_root = np.zeros(n_faces, dtype=bool)
    is_root[root[proper]] = True
    roots = np.flatnonzero(is_root)
    label = (np.cumsum(is_root) - 1)[root[proper]]
    component = np.full(n_faces, -1, dtype=np.int64)
    component[proper] = label
    n_comp = len(roots)
    comp, colour = component[proper], parity[proper]

    corners = faces[proper]
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
    area, mean, agree = _face_terms(vertices, corners, normals, compiled)
    area1 = np.bincount(comp, weights=area * colour, minlength=n_comp)
    area0 = np.bincount(comp, weights=area * ~colour, minlength=n_comp)
    count1 = np.bincount(comp, weights=colour, minlength=n_comp)
    count0 = np.bincount(comp, weights=~colour, minlength=n_comp)
    # The colour to flip: the minority by area, then by count; the root's colour is 0,
    # so on a full tie colour 1 (opposite the first triangle) is flipped.
    minority = np.where(area1 != area0, area1 < area0, count1 <= count0)
    against_proper = colour == minority[comp]
    sign = np.where(against_proper, -1.0, 1.0)  # +1: keeps its winding in the consistent one

    closed = np.bincount(comp, weights=open_face[proper], minlength=n_comp) == 0
    # Signed volume about each component's mean corner (smaller terms, less cancellation).
    size = np.maximum(np.bincount(comp, minlength=n_comp), 1)
    centre = np.stack([np.bincount(comp, weights=mean[k], minlength=n_comp)
                       for k in range(3)], axis=1) / size[:, None]
    del mean
    det = _face_volumes(vertices, corners, centre, comp, compiled)
    del corners
    volume = np.bincount(comp, weights=sign * det, minlength=n_comp)
    scale = np.bincount(comp, weights=np.abs(det), minlength=n_comp)
    face_sign = np.zeros(n_faces)
    face_sign[proper] = sign
    cap_volume, cap_scale, cap_area = _caps(vertices, edges, component, face_sign, centre, n_comp,
                                            compiled)
    total_area = np.bincount(comp, weights=area, minlength=n_comp)
    nearly_closed = ~closed & (cap_area <= NEARLY_CLOSED * total_area)
    volume, scale = volume + cap_volume, scale + cap_scale  # zero for closed components
    inward = (closed | nearly_closed) & (volume < -UNDECIDED_VOLUME * scale)
    if normals is not None:
        vote = np.bincount(comp, weights=sign * agree, minlength=n_comp)
        spread = np.bincount(comp, weights=np.abs(agree), minlength=n_comp)
        inward |= ~closed & ~nearly_closed & (vote < -UNDECIDED_VOLUME * spread)

    against = np.zeros(n_faces, dtype=bool)
    against[proper] = against_proper
    flip = np.zeros(n_faces, dtype=bool)
    flip[proper] = against_proper ^ inward[comp]
    return Orientation(component, against, flip, closed, nearly_closed, inward, conflicting)


def _face_terms(vertices, corners, normals, kernels=None):
    """Per-face terms of :func:`orient`: (area (m,), mean corner (3, m), agree (m,) | None).

    vertices : (v, 3) float64, corners : (m, 3) int64, normals : (v, 3) float64 | None.
    agree: the cross product dotted with the corners' summed normals (None without
    normals).  ``kernels``: aobake._kernels, whose orient_terms (aobake/_orient.c) gives
    the same bits; the numpy runs a block of faces at a time (each row's arithmetic as on
    the whole array: the same bits), so no (m, 3, 3) corner array lives for the whole mesh.
    """
    m = len(corners)
    area, mean = np.empty(m), np.empty((3, m))
    agree = None if normals is None else np.empty(m)
    empty = np.empty(0)
    if kernels is not None and kernels.orient_terms(
            np.ascontiguousarray(vertices), np.ascontiguousarray(corners),
            empty if normals is None else np.ascontiguousarray(normals), area, mean,
            empty if agree is None else agree):
        return area, mean, agree
    for lo in range(0, m, BLOCK):
        blk = slice(lo, lo + BLOCK)
        tri = vertices[corners[blk]]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        area[blk] = 0.5 * np.linalg.norm(cross, axis=1)
        for k in range(3):
            mean[k, blk] = tri[:, :, k].mean(axis=1)
        if agree is not None:
            agree[blk] = np.einsum("ij,ij->i", cross, normals[corners[blk]].sum(axis=1))
    return area, mean, agree


def _face_volumes(vertices, corners, centre, comp, kernels=None):
    """(m,) float64: each face's determinant r0 . (r1 x r2) of its corners relative to its
    component's centre (centre (c, 3) float64, comp (m,) int64), through orient_volumes
    (aobake/_orient.c, the same bits) where ``kernels`` is given, else numpy by blocks."""
    det = np.empty(len(corners))
    if kernels is not None and kernels.orient_volumes(
            *map(np.ascontiguousarray, (vertices, corners, centre, comp)), det):
        return det
    for lo in range(0, len(corners), BLOCK):
        blk = slice(lo, lo + BLOCK)
        rel = vertices[corners[blk]] - centre[comp[blk]][:, None, :]
        det[blk] = np.einsum("ij,ij->i", rel[:, 0], np.cross(rel[:, 1], rel[:, 2]))
    return det


def _caps(vertices, edges: EdgePairs, component, face_sign, centre, n_comp, kernels=None):
    """Fan caps over each component's boundary loops (its open edges, connected through
    shared vertices), traversed against the consistent winding so they close it.

    Returns per component (c,) float64: the caps' signed volume terms (det about
    ``centre``, as the faces'), their absolute sum, and the caps' area.
    """
    keep = component[edges.open_owner] >= 0
    owner = edges.open_owner[keep]
    comp = component[owner]
    # As the consistent winding traverses the edge: reversed where the face is flipped.
    forward = face_sign[owner] > 0
    start = np.where(forward, edges.open_start[keep], edges.open_end[keep])
    end = np.where(forward, edges.open_end[keep], edges.open_start[keep])
    zeros = np.zeros(n_comp)
    if not len(comp):
        return zeros, zeros, zeros
    # Loops: boundary vertices of one component joined by its open edges.
    nodes, inverse = np.unique(np.stack([np.concatenate([comp, comp]),
                                         np.concatenate([start, end])], axis=1),
                               axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    loop_root, _ = _parity_union_find(len(nodes), inverse[:len(comp)], inverse[len(comp):],
                                      np.zeros(len(comp), dtype=bool), kernels)
    loops, loop_of_node = np.unique(loop_root, return_inverse=True)
    count = np.bincount(loop_of_node, minlength=len(loops))
    mean = np.stack([np.bincount(loop_of_node, weights=vertices[nodes[:, 1], k],
                                 minlength=len(loops)) for k in range(3)], axis=1) / count[:, None]
    loop = loop_of_node[inverse[:len(comp)]]
    m, p, q = mean[loop], vertices[start], vertices[end]
    # Cap triangle (m, q, p): the edge traversed backwards closes the surface.
    rel_m, rel_p, rel_q = m - centre[comp], p - centre[comp], q - centre[comp]
    det = np.einsum("ij,ij->i", rel_m, np.cross(rel_q, rel_p))
    area = 0.5 * np.linalg.norm(np.cross(q - m, p - m), axis=1)
    return (np.bincount(comp, weights=det, minlength=n_comp),
            np.bincount(comp, weights=np.abs(det), minlength=n_comp),
            np.bincount(comp, weights=area, minlength=n_comp))


def flip_faces(faces: np.ndarray, flip: np.ndarray) -> np.ndarray:
    """(f, 3) copy of ``faces`` (or per-corner ``faces_uv``) with the rows ``flip`` (f,) bool
    reversed by swapping corners 1 and 2 (corner 0 stays, so a triangle flipped twice is
    the original, bit for bit)."""
    out = np.array(faces, copy=True)
    out[flip] = out[flip][:, [0, 2, 1]]
    return out


def warning_text(counts: dict, source: str) -> str | None:
    """The warn mode's one line, or None when nothing was found."""
    n, m, k = (counts["faces_against_neighbours"], counts["components_with_faces_against"],
               counts["inward_components"])
    if not (n or k):
        return None
    return (f"{source}: {n} faces of {m} components are wound against their neighbours; "
            f"{k} components point inward: --fix-normals fix repairs them")


def orientation_warning(fix_normals: str, counts: dict, flipped: int, source: str) -> str | None:
    """The winding check's one line for ``--fix-normals`` (fix: the faces flipped, where
    any were; warn: ``warning_text``), or None: ``aobake.scene.make_scene``'s and
    ``aobake.placed``'s (a set made an instance at a time: its counts summed)."""
    if fix_normals == "fix":
        if not flipped:
            return None
        return (f"{source}: flipped {flipped} faces ({counts['faces_against_neighbours']} "
                f"wound against their neighbours, {counts['inward_components']} components "
                "pointing inward)")
    return warning_text(counts, source) if fix_normals == "warn" else None
