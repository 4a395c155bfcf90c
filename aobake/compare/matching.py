"""Matching two files' copies of one mesh's vertices by position, in any order.

Positions pair up within ``position_tolerance``; vertices that coincide (a seam's or a hard
edge's copies, a double-sided surface) are told apart by ``tie_features`` (normals, the
faces around them), which depend on the geometry, not on the vertex order.
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
    extent = float(np.max(positions.max(axis=0) - positions.min(axis=0)))
    return POSITION_TOLERANCE * max(float(np.max(np.abs(positions))), extent, np.finfo(float).tiny)


def match_vertices(reference: np.ndarray, candidate: np.ndarray, tol: float,
                   features: tuple | None = None) -> tuple[np.ndarray, str, int]:
    """Match two copies of the same vertices, in any order.

    reference, candidate : (n, 3) float positions; tol : a coordinate difference allowed;
    features : (reference (n, d), candidate (n, d)) float or None: what tells coincident
      vertices apart (``tie_features``: normals, the faces around them); among coincident
      vertices each reference vertex takes the candidate nearest in features (greedily),
      ties in file order.
    Returns (order (n,) int64, how, ambiguous): ``candidate[order[i]]`` is reference vertex i;
    how is 'order' (same order already) or 'position'; ambiguous counts the reference
    vertices that coincide with another in position and features (paired in file order).
    Raises ValueError describing the mismatch.
    """
    reference = np.asarray(reference, dtype=np.float64)
    candidate = np.asarray(candidate, dtype=np.float64)
    n = len(reference)
    if len(candidate) != n:
        raise ValueError(f"{len(candidate)} vertices against {n}")
    if np.all(np.abs(reference - candidate) <= tol):
        return np.arange(n), "order", 0
    # Coincident reference vertices form one cluster (named by its smallest index); each
    # candidate vertex belongs to the cluster of the reference vertices within tol of it.
    rq, rp = _neighbours(reference, reference, tol)
    ref_cluster = np.arange(n)
    np.minimum.at(ref_cluster, rq, rp)
    cq, cp = _neighbours(candidate, reference, tol)
    cand_cluster = np.full(n, n, dtype=np.int64)
    np.minimum.at(cand_cluster, cq, cp)
    lost = np.flatnonzero(cand_cluster == n)
    if len(lost):
        x, y, z = candidate[lost[0]]
        raise ValueError(f"{len(lost)} vertices (the first, {lost[0]}, at ({x:.9g}, {y:.9g}, "
                         f"{z:.9g})) are not within {tol:.3g} of any vertex")
    if not np.array_equal(np.sort(ref_cluster), np.sort(cand_cluster)):
        raise ValueError("the vertex positions do not pair up one to one with those")
    # clusters in the same sequence on both sides; within one, file order for now
    ref_order = np.lexsort((np.arange(n), ref_cluster))
    cand_order = np.lexsort((np.arange(n), cand_cluster))
    order = np.empty(n, dtype=np.int64)
    order[ref_order] = cand_order
    size = np.bincount(ref_cluster, minlength=n)[ref_cluster[ref_order]]  # per sorted slot
    ambiguous = 0
    fr, fc = (np.zeros((n, 0)), np.zeros((n, 0))) if features is None else \
        (np.asarray(f, dtype=np.float64) for f in features)
    for k in np.unique(size[size > 1]):
        slots = np.flatnonzero(size == k)
        r, c = ref_order[slots].reshape(-1, k), cand_order[slots].reshape(-1, k)
        # features apart: |difference| per pair (clusters, k reference, k candidate)
        apart = np.abs(fr[r][:, :, None, :] - fc[c][:, None, :, :]).max(axis=3, initial=0.0)
        self_apart = np.abs(fr[r][:, :, None, :] - fr[r][:, None, :, :]).max(axis=3, initial=0.0)
        self_apart[:, np.arange(k), np.arange(k)] = np.inf
        ambiguous += int(np.count_nonzero(self_apart.min(axis=2) <= _FEATURE_TIE))
        rows = np.arange(len(r))
        for _ in range(k):  # greedy: the closest remaining pair of each cluster first
            a, b = np.divmod(apart.reshape(len(r), -1).argmin(axis=1), k)
            order[r[rows, a]] = c[rows, b]
            apart[rows, a, :] = np.inf
            apart[rows, :, b] = np.inf
    if not np.all(np.abs(reference - candidate[order]) <= tol):
        raise ValueError("the vertex positions do not pair up one to one with those")
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
        corners = np.asarray(positions, dtype=np.float64)[faces]  # (f, 3 corners, 3)
        centroid = corners.mean(axis=1)
        area = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        n, at = len(positions), faces.reshape(-1)  # each face's values go to its 3 corners
        per_face = np.repeat(np.hstack([centroid, area]), 3, axis=0)
        total = np.column_stack([np.bincount(at, per_face[:, j], n) for j in range(6)])
        count = np.bincount(at, minlength=n).astype(np.float64)
        length = np.linalg.norm(total[:, 3:], axis=1, keepdims=True)
        parts += [total[:, :3] / np.maximum(count, 1.0)[:, None] / size,
                  total[:, 3:] / np.where(length > 0, length, 1.0)]
    return np.hstack(parts) if parts else np.zeros((len(positions), 0))


def _neighbours(query: np.ndarray, points: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i, j) with every |query[i] - points[j]| coordinate <= tol: (q,) int64 and (q,)
    int64 arrays.  Sorted along a generic direction (not an axis, on which a grid's vertices
    line up), the candidates for each query are a short window."""
    direction = np.array([1.0, math.sqrt(2.0), math.sqrt(3.0)])
    direction /= direction.sum()  # a coordinate difference <= tol moves the projection <= tol
    proj_p = points @ direction
    proj_q = query @ direction
    order = np.argsort(proj_p, kind="stable")
    sorted_p = proj_p[order]
    lo = np.searchsorted(sorted_p, proj_q - tol, side="left")
    hi = np.searchsorted(sorted_p, proj_q + tol, side="right")
    width = hi - lo
    qi = np.repeat(np.arange(len(query)), width)
    start = np.repeat(np.cumsum(width) - width, width)
    pj = order[np.repeat(lo, width) + np.arange(int(width.sum())) - start]
    keep = np.all(np.abs(query[qi] - points[pj]) <= tol, axis=1)
    return qi[keep], pj[keep]

