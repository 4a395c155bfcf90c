"""Seam erasure: make bilinear lookups agree on both sides of every UV seam.

A *seam edge* is a mesh edge (two welded positions) shared by two faces whose UVs differ
there, with the same shading normal on both sides (within ``SMOOTH_DEGREES`` at both
ends: across a hard edge the baked values may differ, and are left alone).  A renderer
reads the lightmap bilinearly (texel centres at u = (c + 0.5) / W, v = 1 - (r + 0.5) / H,
see ``aobake.targets.texels.raster``), so a point of a seam edge is drawn from two
different 2x2 texel neighbourhoods, one per side, some of them gutter texels.  They
disagree by the texels' noise and by a systematic part: each side reads texels up to 1.5
texels inside its chart and gutter texels that copy them.

Erasure (least squares, as in Liu, Ferguson, Jacobson 2017, "Seamless") changes the
covered texels that the seams read, x, from the baked values b, by minimising

    sum_covered (x_t - b_t)^2 / se_t^2                          (data: inverse variance)
  + KAPPA * sum_seams integral (L_A(x) - L_B(x))^2 / var_d dl    (seam, dl in texels)

``L_A``, ``L_B`` are the two sides' bilinear lookups of the *final* map; ``var_d`` the
variance the baked noise gives their difference at that point, so the seam term counts the
difference in its own standard errors: a difference of one standard error along one texel
of seam costs KAPPA times as much as moving one texel by one standard error.  A gutter
texel that a lookup reads (the first ring around a chart) holds what the first ring of
``aobake.post.dilate`` will write there, the mean of its covered 8-neighbours, so it enters
as that mean of unknowns: the gutter stays the exact dilation of the adjusted charts
(with its mip-safety, docs/conventions.md).  Letting those gutter texels move on their own
(held to that mean by a tie as stiff as a texel's data term) lowered the seam difference
left by only 5-7% (spot 0.00262 -> 0.00248, bunny 0.00101 -> 0.00094 at 64 rays) and
let them leave the range of the chart texels around them.
Along a seam edge a bilinear lookup is quadratic between the points where either side
crosses a row or column of texel centres, so 3-point Gauss-Legendre quadrature on each
such piece integrates (L_A - L_B)^2 exactly.  The normal equations (sparse, symmetric
positive definite, over the covered texels the seams read) are assembled once as a CSR
matrix (``seam_pattern``, made with the system, then ``seam_values``: each
group of points' 8 x 8 block, read through the dilation into the covered unknowns) and
solved by Jacobi-preconditioned conjugate gradients on it (``aobake.sparse.cg``), both
compiled (aobake/_seams.c, aobake/_sparse.c), or in numpy with the same operations in the
same order (``_assemble_numpy``, ``sparse.cg_numpy``: the same bits).  Bunny 1024^2 on 2 threads:
the pattern ~0.12 s (on the seam system's thread), the values ~0.16 s, 130 iterations
~0.3 s (2.6 ms each; at KAPPA 100: at 2000, with the bounded round, 533 iterations, the
erasure ~0.6 s); applying the operator as the points
every iteration (the fill, the points' differences, their sums per group, their scatter and
the fill's transpose) took ~10 ms an iteration, 1.2-1.5 s in all: four passes of random
reads against one pass over the matrix, whose row of ~15 columns reads x from a vector that
fits in the cache.  Earlier, with the points: numpy's einsum and bincount passes 1.6 s.
A block-Jacobi preconditioner over stretches of seam, both sides at once, saved a fifth
of the iterations on the bunny in an earlier variant and cost more than that to build;
a direct sparse solve (SuperLU, COLAMD order) of the bunny's 114k covered unknowns took
as long as these iterations, and a banded Cholesky after reverse Cuthill-McKee more
(bandwidth ~500: the seams form one network).

Error bars.  The seam term involves x only, never b.  In units of the texels' own errors
(y = x / se), the solution is y = (I + H)^-1 y_b with H symmetric positive semi-definite
(H = V^1/2 P^T G^T Lambda G P V^1/2: V the texels' variances, P the dilation of the
covered texels into the gutter texels read, G the lookup differences, Lambda the seam
weights), so (I + H)^-1 has its eigenvalues in (0, 1] and Cov(y) = (I + H)^-2 <= I when
the baked texels' errors are independent (they are: docs/conventions.md).  So
Var(x_t) <= se_t^2 for every adjusted texel (to the solver's tolerance): its stderr is
kept, as an upper bound (tests/test_seams.py computes the exact sd(x_t) =
sqrt(sum_j K_tj^2 se_j^2) of x = K b and checks it).  AO and obscurance are solved within
[0, 1] (``_bounded``): for a given set of texels held at 0 or 1 (constants), the free ones
are the same kind of solution with a principal submatrix of I + H, so the bound holds for
them too.  The same holds at any seam weight, so where a solve raises the weight (the
seams still above SEAM_TARGET) the bound holds given the weight it ended at; that choice
reads the map's own seam residual, which is its systematic steps far more than its noise.
Gutter texels stay the dilation's fill (docs/conventions.md), not estimates
of their own.
"""

from __future__ import annotations

import logging
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
import numpy as np

from aobake import _native
from aobake.sparse import Csr, cg
from aobake.sparse import apply as _sparse_apply
from aobake.sparse import ranks_of as _sparse_ranks
from aobake.vectors import distinct, weld

log = logging.getLogger(__name__)

#: two sides of an edge are a seam to erase when their vertex normals agree within this
#: angle at both ends; beyond it the edge is hard and the values may differ on purpose.
#: (10 degrees also takes in normals recomputed on a mesh split at its UV seams.)
SMOOTH_DEGREES = 10.0
#: UVs closer than this (a billionth of the tile, 1e-5 texel at the largest resolution)
#: are the same: a seam edge needs its sides farther apart
UV_SAME = 1e-9
#: a face whose height over its longest edge is at most this fraction of that edge has no
#: area (``degenerate_faces``): below float32's resolution of the edge (6e-8), the
#: precision the ray tracer holds the mesh in, it is a line (the ogre has 4, exactly flat)
DEGENERATE = 1e-7
#: weight of the seam term: a seam difference of one of its standard errors along one
#: texel of seam costs KAPPA times moving one texel by one standard error.  Measured at
#: 1024^2, 256 rays, 2 seeds (benchmarks/bench_seams.py, --kappa; systematic / random rms
#: of the lookup difference; iterations of the solve, its first part to TOLERANCE):
#:   kappa   ogre (xatlas)          bunny (xatlas)         spot (own UVs)
#:   100     0.0042 / 0.0019  228   0.0005 / 0.0008  182   0.0002 / 0.0010  185
#:   1000    0.0020 / 0.0007  685   0.0002 / 0.0003  493   0.0001 / 0.0003  522
#:   2000    0.0017 / 0.0005  926   0.0002 / 0.0002  685   0.0001 / 0.0002  703
#:   5000    0.0012 / 0.0004  894   0.0001 / 0.0001  731   0.0001 / 0.0001  710
#: (off: 0.097, 0.022, 0.0094 systematic).  The residual is a fixed fraction of the step
#: the erasure removes (the seam term counts it in its own standard errors), and the
#: ogre's is the largest (parts through parts: AO from 0 to 1 within a texel of its
#: seams), the more so the coarser the map: at 512^2 (its charts finer than the texels,
#: an unerased step of 0.22) 2000 left 0.0026 (867 iterations), 5000 0.00175 (1328),
#: 10000 0.00125 (1808); the bunny 0.00019 and spot 0.00011 at 5000.  5000 keeps every
#: mesh and resolution measured below 0.002, the issue-21 target (the ogre does not fit
#: 256^2 with the default padding), at 1.5 times 2000's iterations (with HOLD_TOLERANCE,
#: 1024^2: ogre 587 -> 894, bunny 533 -> 731, spot 505 -> 710; the erasure ~0.9 -> ~1.0 s
#: on the ogre).  It moves the mean of the two lookups more (ogre 1024^2 0.046 -> 0.052
#: rms; 0.037 at 100) and lowers their noise further (0.0128 -> 0.0118; 0.0155 at 100).
#: Untried: a stronger preconditioner than Jacobi, which these iterations call for.
KAPPA = 5000.0
#: what the erasure leaves across the seams at most, rms over their length in value units:
#: half a level of an 8-bit map (1/255/2 = 0.00196), a step no 8-bit export shows.  A solve
#: at KAPPA that leaves more (a map coarse for its charts: the ogre at 512^2 at KAPPA 2000,
#: a sphere through a box at 48^2 at 5000) solves again from its result with the weight
#: KAPPA_STEP times higher, up to KAPPA_RANGE times KAPPA.  The test scene at 48^2: 0.00225
#: at 5000, below the target after one more round.
SEAM_TARGET = 0.002
KAPPA_STEP = 4.0
KAPPA_RANGE = 256.0
#: a round that leaves more than this fraction of the last one's seam difference is the
#: last (measured, the sphere through a box at 48^2: each 4x of the weight left 0.45-0.64
#: of the difference, 0.00234 at 5000 -> 0.00149, 0.00089 ... 0.00018 at 256 x 5000, its
#: iterations 595 -> 1518, 3054 ... 8494)
PLATEAU = 0.8
#: the conjugate gradients stop when the Jacobi-scaled residual is below this in every
#: unknown (value units); the solution is then within about 1e-5 of the exact one (bunny:
#: 9.9e-6 at most, 1.6e-7 rms against a direct solve of the same matrix), far below the
#: seam differences left (~1e-3 rms) and the texels' noise (~0.02)
TOLERANCE = 1e-6
#: the solve's threads have at least this many unknowns each (a barrier per pass costs
#: microseconds; an iteration over 10k unknowns takes about half a millisecond)
THREAD_UNKNOWNS = 10000
#: conjugate-gradient iterations at most (a warning is logged when the tolerance is not met)
MAX_ITERATIONS = 2000
#: active-set rounds of the bounded solve (``_bounded``), each a warm-started conjugate-
#: gradient solve.  Measured on the ogre (1024^2, 64 rays): the first round takes the seam
#: difference from 0.0098 to 0.0073 rms (over all its seam points, 0.0048 over those the
#: solve keeps); seven more settle the set (8332 texels held, then 3457, 1739, ... changed)
#: and move it by less than 1e-5, each costing about as much as the first.
MAX_ROUNDS = 1
#: the unbounded solve that picks the held texels of a bounded one stops at this tolerance
#: (the bounded solve then meets TOLERANCE): at 1024^2, 256 rays, the iterations fall from
#: 926 to 610 (ogre), 685 to 533 (bunny), 703 to 505 (spot), the lookups' differences the
#: same to 1e-5 (1e-4: 715, 543)
HOLD_TOLERANCE = 1e-3
#: stderr floor in the weights (value units): a texel exact by construction (stderr 0)
#: gets a weight of 1e14, i.e. it does not move
SE_FLOOR = 1e-7
#: 3-point Gauss-Legendre nodes and weights on [-1, 1]: exact for degree 5 (d^2 is quartic)
_GAUSS_X = np.array([-math.sqrt(0.6), 0.0, math.sqrt(0.6)])
_GAUSS_W = np.array([5.0, 8.0, 5.0]) / 9.0

# The 8 neighbours of a texel (row, col), in the order of aobake.post.dilate.
_NEIGHBOURS = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)]


@dataclass(frozen=True)
class SeamMesh:
    """What the erasure needs of the baked mesh.

    positions : (v, 3) float64, normals : (v, 3) float64 (unit, zero = undefined),
    faces : (f, 3) int64 into positions, uv : (t, 2) float64 the UVs baked into (OBJ
    convention), faces_uv : (f, 3) int64 into uv, wrap : "clamp" | "repeat" how the map
    is sampled (``Atlas.wrap``).
    """

    positions: np.ndarray
    normals: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    faces_uv: np.ndarray
    wrap: str = "clamp"


@dataclass(frozen=True)
class SeamPoints:
    """Quadrature points of the seam edges, as the UV of each side.

    uv_a, uv_b : (p, 2) float64 the same surface point in the two charts, weight : (p,)
    float64 the length of seam (in texels: the mean of the two sides' lengths) the point
    stands for, edge : (p,) int64 its seam edge, n_edges : int number of seam edges.
    """

    uv_a: np.ndarray
    uv_b: np.ndarray
    weight: np.ndarray
    edge: np.ndarray
    n_edges: int


@dataclass(frozen=True)
class SeamSystem:
    """The seam term over the texels the seams read.

    texels : (n,) int64 linear texel index ``r * W + c`` of each unknown, gutter : (n,) bool
    (not covered).  The seam points come in groups that read the same 8 texels (the points
    of one piece of an edge: the lookups' cells change only where a piece ends):
    slots : (s, 8) int64 the unknowns a group reads (side A's 2x2, then side B's), group :
    (m,) int64 each point's group (non-decreasing: points are stored in group order),
    coef : (m, 8) float64 its bilinear weights (side B's negated: coef . x[slots[group]] =
    L_A(x) - L_B(x)), weight : (m,) float64 quadrature weights.  fill_to, fill_from,
    fill_weight : (e,) the dilation's first ring as COO entries: gutter texel ``fill_to``
    is the sum of fill_weight (1 / its covered neighbours) times texel ``fill_from``.
    dropped : int seam points left out (their lookup reads a texel that is neither covered
    nor next to a covered one: a texel the first ring does not fill).
    """

    texels: np.ndarray
    gutter: np.ndarray
    slots: np.ndarray
    group: np.ndarray
    coef: np.ndarray
    weight: np.ndarray
    fill_to: np.ndarray
    fill_from: np.ndarray
    fill_weight: np.ndarray
    dropped: int

    @property
    def n_rows(self) -> int:
        return len(self.weight)

    def fill(self, x: np.ndarray) -> np.ndarray:
        """(n,) the texels with the gutter ones as the dilation makes them from the covered
        ones (P x; the gutter entries of x are ignored)."""
        out = np.where(self.gutter, 0.0, x)
        return out + np.bincount(self.fill_to, weights=self.fill_weight * x[self.fill_from],
                                 minlength=len(out))

    def differences(self, x: np.ndarray) -> np.ndarray:
        """(m,) L_A - L_B at the seam points of the map whose covered texels are x (n,)."""
        # each group's 8 texels read once, then repeated per point (contiguous rows): the
        # same numbers as indexing with slots[group], without an (m, 8) index array
        return np.einsum("pk,pk->p", self.coef, self.fill(x)[self.slots][self.group])


# --- seam edges and points -------------------------------------------------------------


def seam_edges(mesh: SeamMesh) -> tuple[np.ndarray, np.ndarray]:
    """The seam edges of ``mesh``: (uv_a (e, 2, 2), uv_b (e, 2, 2)) float64, the UVs of each
    edge's two ends (axis 1, the same 3-D end on both sides) in its two faces.

    Positions are welded (exactly equal coordinates are one vertex), so a mesh split at its
    UV seams has them too.  An edge of k >= 3 faces pairs the first with each other.
    Edges whose sides differ by whole tiles under ``wrap="repeat"`` read the same texels
    and are no seams.  A face of no area (``degenerate_faces``: never drawn, and xatlas
    gives it one UV for its three corners, outside every chart) is no side of a seam: its
    long edge's other face meets the faces on its two short edges, in pieces
    (``_across_degenerate``).
    """
    faces = np.asarray(mesh.faces, dtype=np.int64)
    faces_uv = np.asarray(mesh.faces_uv, dtype=np.int64)
    uv = np.asarray(mesh.uv, dtype=np.float64)
    normals = np.asarray(mesh.normals, dtype=np.float64)
    empty = np.zeros((0, 2, 2))
    if not len(faces):
        return empty, empty
    positions = np.asarray(mesh.positions, dtype=np.float64)
    welded = weld(positions)
    # Half-edges (face, corner k -> k + 1), each stored from its lower welded end; a
    # degenerate face's are replaced by the pieces of its neighbour's edge.
    degenerate = degenerate_faces(positions, faces)
    a_corner = faces[~degenerate].reshape(-1)
    b_corner = np.roll(faces[~degenerate], -1, axis=1).reshape(-1)
    a_uv = faces_uv[~degenerate].reshape(-1)
    b_uv = np.roll(faces_uv[~degenerate], -1, axis=1).reshape(-1)
    if degenerate.any():
        pieces = _across_degenerate(positions, welded, faces, faces_uv, uv, degenerate,
                                    a_corner, b_corner, a_uv, b_uv)
        (a_corner, b_corner, a_uv, b_uv), uv = pieces
    pa, pb = welded[a_corner], welded[b_corner]
    keep = pa != pb
    swap = pa > pb
    lo_v = np.where(swap, b_corner, a_corner)[keep]
    hi_v = np.where(swap, a_corner, b_corner)[keep]
    lo_t = np.where(swap, b_uv, a_uv)[keep]
    hi_t = np.where(swap, a_uv, b_uv)[keep]
    key_lo, key_hi = np.minimum(pa, pb)[keep], np.maximum(pa, pb)[keep]
    order = np.lexsort((key_hi, key_lo))
    key_lo, key_hi = key_lo[order], key_hi[order]
    lo_v, hi_v, lo_t, hi_t = lo_v[order], hi_v[order], lo_t[order], hi_t[order]
    if not len(order):
        return empty, empty
    start = np.r_[True, (key_lo[1:] != key_lo[:-1]) | (key_hi[1:] != key_hi[:-1])]
    first = np.maximum.accumulate(np.where(start, np.arange(len(start)), 0))
    other = np.nonzero(~start)[0]  # pairs (first of the group, other)
    one = first[other]
    uv_a = np.stack([uv[lo_t[one]], uv[hi_t[one]]], axis=1)
    uv_b = np.stack([uv[lo_t[other]], uv[hi_t[other]]], axis=1)
    shift = uv_a - uv_b
    if mesh.wrap == "repeat":  # whole tiles apart at both ends read the same texels
        tiles = np.round(shift[:, :1])
        shift = np.where(np.all(np.abs(shift - tiles) <= UV_SAME, axis=(1, 2))[:, None, None],
                         0.0, shift)
    differ = np.any(np.abs(shift) > UV_SAME, axis=(1, 2))
    smooth_cos = math.cos(math.radians(SMOOTH_DEGREES))
    smooth = ((np.einsum("ij,ij->i", normals[lo_v[one]], normals[lo_v[other]]) >= smooth_cos)
              & (np.einsum("ij,ij->i", normals[hi_v[one]], normals[hi_v[other]]) >= smooth_cos))
    seam = differ & smooth
    return uv_a[seam], uv_b[seam]


def degenerate_faces(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(f,) bool the faces of no area: their height over their longest edge is at most
    DEGENERATE times that edge (collinear corners, two corners at one point, or all three).
    positions : (v, 3) float64, faces : (f, 3) int64."""
    p = np.asarray(positions, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]
    twice_area = np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    longest = np.linalg.norm(p - np.roll(p, -1, axis=1), axis=2).max(axis=1)
    # twice the area is the longest edge times the height over it
    return twice_area <= DEGENERATE * longest ** 2


def _across_degenerate(positions, welded, faces, faces_uv, uv, degenerate, a_corner,
                       b_corner, a_uv, b_uv):
    """The half-edges (a_corner, b_corner, a_uv, b_uv) of the drawn faces, with two more
    for each degenerate face D = (a, b, c), c on its longest edge ab at t = |ac| / |ab|:
    a -> c and c -> b in the UVs of F, the drawn face on the other side of ab (its UVs at
    a and b, and at c their mix at t, appended to ``uv``), which then pair with the drawn
    faces on D's edges ac and cb.  So the seam that D hides (F against those faces, a
    T-junction) is found, and none against D's collapsed UVs.  Only where ab has exactly
    one drawn face besides D (a chain of degenerate faces, or a border, gets no pieces).
    Returns ((a_corner, b_corner, a_uv, b_uv), uv (t + 2 d, 2))."""
    d_faces = faces[degenerate]
    p = positions[d_faces]
    k = np.argmax(np.linalg.norm(p - np.roll(p, -1, axis=1), axis=2), axis=1)  # ab = k -> k+1
    rows = np.arange(len(d_faces))
    va, vb, vc = (d_faces[rows, (k + j) % 3] for j in range(3))
    ab = positions[vb] - positions[va]
    t = np.clip(np.einsum("ij,ij->i", positions[vc] - positions[va], ab)
                / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0.0, 1.0)
    # F's half-edge on ab: the drawn half-edges keyed by their welded ends, sorted
    wa, wb = welded[a_corner], welded[b_corner]
    key = np.minimum(wa, wb) * (len(welded) + 1) + np.maximum(wa, wb)
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    want = np.minimum(welded[va], welded[vb]) * (len(welded) + 1) + np.maximum(welded[va],
                                                                                welded[vb])
    left = np.searchsorted(sorted_key, want, side="left")
    right = np.searchsorted(sorted_key, want, side="right")
    one = right - left == 1
    if not one.any():
        return (a_corner, b_corner, a_uv, b_uv), uv
    h = order[left[one]]  # F's half-edge, in either direction
    va, vb, vc, t = va[one], vb[one], vc[one], t[one]
    forward = welded[a_corner[h]] == welded[va]
    fa = np.where(forward, a_corner[h], b_corner[h])  # F's corners and UVs at a and b
    fb = np.where(forward, b_corner[h], a_corner[h])
    ta = np.where(forward, a_uv[h], b_uv[h])
    tb = np.where(forward, b_uv[h], a_uv[h])
    tc = len(uv) + np.arange(len(h))
    uv = np.concatenate([uv, (1.0 - t)[:, None] * uv[ta] + t[:, None] * uv[tb]])
    return (np.concatenate([a_corner, fa, vc]), np.concatenate([b_corner, vc, fb]),
            np.concatenate([a_uv, ta, tc]), np.concatenate([b_uv, tc, tb])), uv


def _texel_coords(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """(..., 2) UV -> (..., 2) coordinates in texel-centre units: texel (r, c)'s centre is
    at (c, r), so a bilinear lookup interpolates between integer coordinates."""
    return np.stack([uv[..., 0] * width - 0.5, (1.0 - uv[..., 1]) * height - 0.5], axis=-1)


def seam_points(mesh: SeamMesh, width: int, height: int) -> SeamPoints:
    """Gauss-Legendre points (3 per piece) of every seam edge, where a piece runs between
    consecutive crossings of a row or column of texel centres by either side (the lookups
    are quadratic on it), so sums over the points integrate (L_A - L_B)^2 exactly."""
    uv_a, uv_b = seam_edges(mesh)
    n_edges = len(uv_a)
    if not n_edges:
        z = np.zeros((0, 2))
        return SeamPoints(z, z, np.zeros(0), np.zeros(0, np.int64), 0)
    # Four linear functions of t per edge: the x and y texel coordinates of each side.
    ends = np.concatenate([_texel_coords(uv_a, width, height),
                           _texel_coords(uv_b, width, height)], axis=2)  # (e, 2, 4)
    f0, f1 = ends[:, 0, :].reshape(-1), ends[:, 1, :].reshape(-1)
    lo, hi = np.minimum(f0, f1), np.maximum(f0, f1)
    first = np.floor(lo) + 1.0  # the integers strictly inside (lo, hi)
    count = np.where(hi > lo, np.maximum(np.ceil(hi) - first, 0), 0).astype(np.int64)
    which = np.repeat(np.arange(count.size), count)
    within = np.arange(len(which)) - np.repeat(np.cumsum(count) - count, count)
    t_cross = np.clip((first[which] + within - f0[which]) / (f1 - f0)[which], 0.0, 1.0)
    edge = np.concatenate([np.arange(n_edges), np.arange(n_edges), which // 4])
    t = np.concatenate([np.zeros(n_edges), np.ones(n_edges), t_cross])
    order = np.lexsort((t, edge))
    edge, t = edge[order], t[order]
    same = edge[1:] == edge[:-1]
    t0, t1, edge = t[:-1][same], t[1:][same], edge[:-1][same]
    live = t1 > t0
    t0, t1, edge = t0[live], t1[live], edge[live]
    length = 0.5 * (np.linalg.norm(ends[:, 1, :2] - ends[:, 0, :2], axis=1)
                    + np.linalg.norm(ends[:, 1, 2:] - ends[:, 0, 2:], axis=1))
    half = 0.5 * (t1 - t0)
    tq = (0.5 * (t0 + t1))[:, None] + half[:, None] * _GAUSS_X  # (pieces, 3)
    weight = (half * length[edge])[:, None] * _GAUSS_W
    edge = np.repeat(edge, 3)
    w = tq.reshape(-1, 1)
    pa = (1.0 - w) * uv_a[edge, 0] + w * uv_a[edge, 1]
    pb = (1.0 - w) * uv_b[edge, 0] + w * uv_b[edge, 1]
    return SeamPoints(pa, pb, weight.reshape(-1), edge, n_edges)


# --- bilinear lookups ------------------------------------------------------------------


def bilinear_stencil(uv, width: int, height: int, wrap: str = "clamp"
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The texels and weights of a bilinear lookup at ``uv`` (p, 2).

    Returns (texel (p, 4) int64 linear indices ``r * W + c``, weight (p, 4) float64, rows
    summing to 1).  Texel centres are at integer texel-centre coordinates (see
    ``_texel_coords``); outside the image the index is clamped (``wrap="clamp"``, GL's
    CLAMP_TO_EDGE) or taken modulo the size (``"repeat"``).
    """
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    xy = _texel_coords(uv, width, height)
    c0, r0 = np.floor(xy[:, 0]), np.floor(xy[:, 1])
    fx, fy = xy[:, 0] - c0, xy[:, 1] - r0
    c0, r0 = c0.astype(np.int64), r0.astype(np.int64)
    cols = np.stack([c0, c0 + 1, c0, c0 + 1], axis=1)
    rows = np.stack([r0, r0, r0 + 1, r0 + 1], axis=1)
    if wrap == "repeat":
        cols, rows = np.mod(cols, width), np.mod(rows, height)
    else:
        cols, rows = np.clip(cols, 0, width - 1), np.clip(rows, 0, height - 1)
    weight = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], axis=1)
    return rows * width + cols, weight


def bilinear(image, uv, wrap: str = "clamp") -> np.ndarray:
    """Bilinear lookups of ``image`` (H, W) or (H, W, c) at ``uv`` (p, 2): (p,) or (p, c)
    float64, as a renderer's linear filter reads the map (no mip level)."""
    image = np.asarray(image, dtype=np.float64)
    height, width = image.shape[:2]
    texel, weight = bilinear_stencil(uv, width, height, wrap)
    flat = image.reshape(height * width, -1)
    out = np.einsum("pk,pkc->pc", weight, flat[texel])
    return out[:, 0] if image.ndim == 2 else out


# --- the system ------------------------------------------------------------------------


def seam_system(points: SeamPoints, covered, wrap: str = "clamp") -> SeamSystem:
    """The lookup differences at ``points`` over the texels they read.

    covered : (H, W) bool.  A gutter texel a lookup reads enters as the mean of its covered
    8-neighbours (the first ring of the dilation); a point whose lookup reads one without
    any is left out (``dropped``).  Those neighbours are unknowns too.
    """
    covered = np.asarray(covered, dtype=bool)
    height, width = covered.shape
    flat = covered.reshape(-1)
    # Points reading the same 8 texels form a group, kept contiguous in the order a lexsort
    # of the 8 texel indices gives; the points are put in that order before their weights
    # are computed (so no (m, 8) array is gathered), by one stable sort of a key that
    # orders like that lexsort: a side's 4 texels follow from its first texel and whether
    # its second and third lie above it (clamped or wrapped at the image's edges).
    if height * width > 1 << 28:  # a side's key must fit in 30 bits (MAX_RESOLUTION^2 does)
        raise ValueError(f"seam erasure supports at most 2^28 texels, got {width}x{height}")
    # (The stencils are made once and put in order: a row's stencil depends on its own
    # UV only, so this is the stencil of the ordered UVs, bit for bit.)
    ta, wa = bilinear_stencil(points.uv_a, width, height, wrap)
    tb, wb = bilinear_stencil(points.uv_b, width, height, wrap)
    order = np.argsort(_stencil_key(ta) << np.int64(30) | _stencil_key(tb), kind="stable")
    texel = np.concatenate([ta[order], tb[order]], axis=1)  # (m, 8), in group order
    coef = np.concatenate([wa[order], -wb[order]], axis=1)
    del ta, wa, tb, wb
    point_weight = points.weight[order]
    # Gutter texels read, and their covered 8-neighbours (the first dilation ring's mean).
    gutter_read = distinct(texel[~flat[texel]], height * width)
    r, c = np.divmod(gutter_read, width)
    nb = np.full((len(gutter_read), 8), -1, dtype=np.int64)
    for i, (dr, dc) in enumerate(_NEIGHBOURS):
        rr, cc = r + dr, c + dc
        ok = (rr >= 0) & (rr < height) & (cc >= 0) & (cc < width)
        idx = np.where(ok, rr * width + cc, 0)
        nb[:, i] = np.where(ok & flat[idx], idx, -1)
    count = (nb >= 0).sum(axis=1)
    orphan = np.zeros(height * width, dtype=bool)
    orphan[gutter_read[count == 0]] = True
    keep = ~orphan[texel].any(axis=1)
    if not keep.any():  # no seam, or none the map's gutters let the lookups read
        i0, f0 = np.zeros(0, dtype=np.int64), np.zeros(0)
        return SeamSystem(i0, np.zeros(0, dtype=bool), np.zeros((0, 8), dtype=np.int64), i0,
                          np.zeros((0, 8)), f0, i0, i0, f0, int(np.count_nonzero(~keep)))
    if keep.all():  # the usual case: no copies
        weight = point_weight
    else:
        texel, coef, weight = texel[keep], coef[keep], point_weight[keep]
    gutter, nb, count = gutter_read[count > 0], nb[count > 0], count[count > 0]
    read = np.zeros(height * width, dtype=bool)
    read[texel.reshape(-1)] = True
    gutter_used = read[gutter]
    gutter, nb, count = gutter[gutter_used], nb[gutter_used], count[gutter_used]
    texels = distinct(np.concatenate([texel.reshape(-1), nb[nb >= 0]]), height * width)
    index = _indexer(texels, height * width)
    new_group = np.r_[True, np.any(texel[1:] != texel[:-1], axis=1)]
    group = np.cumsum(new_group) - 1
    first_point = np.nonzero(new_group)[0]  # the first point of each group
    slots = index(texels, texel[first_point])
    # The first dilation ring: gutter texel g = sum over its covered neighbours j of x_j / count.
    has = nb >= 0
    fill_to = np.repeat(index(texels, gutter), 8).reshape(-1, 8)[has]
    fill_from = index(texels, nb[has])
    fill_weight = (1.0 / count)[:, None].repeat(8, axis=1)[has]
    return SeamSystem(texels, ~flat[texels], slots, group, coef, weight, fill_to, fill_from,
                      fill_weight, int(np.count_nonzero(~keep)))


def _side_key(uv, width: int, height: int, wrap: str) -> np.ndarray:
    """(p,) int64 ordering points as a lexsort of their bilinear stencil's 4 texels:
    first texel * 4 + (second > first) * 2 + (third > first).  For a given first texel the
    second is one of two (the next column, or the same one clamped; with ``repeat``, the
    next or the row's first), and so is the third (rows); the fourth follows from them."""
    return _stencil_key(bilinear_stencil(uv, width, height, wrap)[0])


def _stencil_key(texel: np.ndarray) -> np.ndarray:
    """``_side_key`` of the stencils' texels (p, 4) int64."""
    return (texel[:, 0] * 4 + (texel[:, 1] > texel[:, 0]) * 2 + (texel[:, 2] > texel[:, 0]))


def _indexer(texels: np.ndarray, size: int):
    """index(texels, values) -> positions of values (any shape) in the sorted distinct
    ``texels`` (k,): np.searchsorted, or (for images up to 2^24 texels) a lookup table,
    which gives the same positions without a binary search per value."""
    if size > 1 << 24:
        return np.searchsorted
    rank = np.zeros(size, dtype=np.int32)
    rank[texels] = np.arange(len(texels), dtype=np.int32)
    return lambda _, values: rank[values].astype(np.int64)


def solve(values: np.ndarray, stderr: np.ndarray, system: SeamSystem,
          kappa: float | None = None, tolerance: float | None = None,
          max_iterations: int | None = None, compiled: bool | None = None,
          threads: int = 1, pattern: tuple | None = None,
          bounds: tuple | None = None) -> tuple[np.ndarray, dict]:
    """Minimise the erasure energy (module docstring) over the covered ``system.texels``.

    values : (n, c) float64 baked values of ``system.texels`` (c channels sharing the
    weights, e.g. a bent normal's components; gutter rows ignored), stderr : (n,) float64
    their stderr (gutter rows ignored).  compiled : the conjugate gradients in the compiled
    kernel (default: when it was built and not forced off, see ``aobake._native``) or in
    numpy; the bits are the same.  threads : the kernel's threads (the same bits for any
    number; numpy's runs on one).  pattern : ``system_pattern(system)``, if made already.
    bounds : (lower, upper) the values' possible range (AO's [0, 1]): the energy is then
    minimised over values in it (``_bounded``), not clipped after; None: unbounded (x is
    then linear in the values).
    Returns (x (n, c) float64: the adjusted covered values, gutter rows the dilation of
    them; info: iterations, converged, kappa (the highest seam weight solved at: KAPPA, or
    more where a channel's seams stayed above SEAM_TARGET), and rms_before / rms_after,
    max_before / max_after of the lookup difference over the seam points (rms weighted by
    seam length)).
    """
    kappa = KAPPA if kappa is None else kappa  # module constants read at call time
    tolerance = TOLERANCE if tolerance is None else tolerance
    max_iterations = MAX_ITERATIONS if max_iterations is None else max_iterations
    kernels = _native.kernels() if compiled in (None, True) else None
    if compiled and kernels is None:
        raise RuntimeError("aobake._kernels was not built")
    s = system
    values = np.array(values, dtype=np.float64)
    covered = ~s.gutter
    se = np.maximum(np.where(covered, np.asarray(stderr, dtype=np.float64), 0.0), SE_FLOOR)
    w = np.where(covered, 1.0 / se ** 2, 0.0)
    # The noise the baked errors give each point's difference (P V P^T read through the
    # stencil, neighbours of a gutter texel counted as if it were independent: a weight),
    # and its seam weight.
    se_read = np.sqrt(s.fill(np.where(covered, se ** 2, 0.0)))
    var_d = np.maximum(np.einsum("pk,pk->p", s.coef ** 2, se_read[s.slots[s.group]] ** 2),
                       SE_FLOOR ** 2)
    if kernels is not None and pattern is None:
        pattern = system_pattern(s, kernels, threads)
    systems: dict = {}

    def normal_matrix(weight):
        """The normal matrix over the covered unknowns at seam weight ``weight`` and its
        diagonal (the Jacobi preconditioner), assembled once per weight
        (``_assemble_numpy``); its pattern depends on the system only (``pattern``, made
        with the system by ``prepare``)."""
        if weight not in systems:
            lam = weight * s.weight / var_d
            # Points are stored in group order: group g is points starts[g] .. starts[g + 1] - 1.
            parts = (np.ascontiguousarray(s.coef, dtype=np.float64), lam, _starts(s),
                     np.ascontiguousarray(s.slots, dtype=np.int64),
                     np.ascontiguousarray(s.gutter), s.fill_to, s.fill_from, s.fill_weight, w)
            if kernels is not None:
                data = kernels.seam_values(*parts, *pattern, int(threads))
                matrix = Csr(*pattern, np.frombuffer(data, np.float64))
            else:
                matrix = _assemble_numpy(*parts)
            systems[weight] = (matrix, matrix.diagonal())
        return systems[weight]

    info = {"iterations": 0, "converged": True, "kappa": kappa}
    total = max(float(s.weight.sum()), 1e-300)
    before, after = [], []
    out = np.empty_like(values)
    for ch in range(values.shape[1]):
        b = np.where(covered, values[:, ch], 0.0)
        before.append(s.differences(b))
        bc = np.ascontiguousarray(b[covered])
        rhs = w[covered] * bc  # the data term's: the same at every seam weight
        xc, weight, it, last = bc, kappa, 0, math.inf
        while True:
            matrix, diag = normal_matrix(weight)
            # a stiffer seam term needs more iterations (about as its square root)
            limit = int(max_iterations * math.sqrt(weight / kappa))
            # bounded: the unbounded minimum only tells which texels to hold, to a looser
            # tolerance (``_bounded`` then solves to the full one)
            xc, more, left = cg(matrix, diag, rhs, xc, tolerance * (
                1.0 if bounds is None else HOLD_TOLERANCE / TOLERANCE), limit, kernels, threads)
            it += more
            if bounds is not None:
                xc, more, left, held = _bounded(matrix, diag, rhs, xc, left, bounds, tolerance,
                                                limit, kernels, threads)
                it += more
                info["bound_texels"] = max(info.get("bound_texels", 0), held)
            x = np.zeros_like(b)
            x[covered] = xc
            d = s.differences(x)
            # the residual is a fraction of the step removed: where the steps are steep (a
            # map coarse for its charts) the weight rises until the seams meet SEAM_TARGET,
            # from where this solve left them; not where a round no longer helps (lookups
            # that no values make agree: each 4x has about halved it where they can)
            rms = np.sqrt(np.sum(s.weight * d ** 2) / total)
            if (rms <= SEAM_TARGET or weight >= kappa * KAPPA_RANGE
                    or rms > PLATEAU * last):
                break
            weight, last = weight * KAPPA_STEP, rms
        info["kappa"] = max(info["kappa"], weight)
        info["iterations"] = max(info["iterations"], it)
        info["converged"] &= bool(left <= tolerance)
        after.append(d)
        out[:, ch] = s.fill(x)
    for name, d in (("before", np.concatenate(before)), ("after", np.concatenate(after))):
        wt = np.tile(s.weight, values.shape[1])
        info[f"rms_{name}"] = float(np.sqrt(np.sum(wt * d ** 2) / (total * values.shape[1])))
        info[f"max_{name}"] = float(np.max(np.abs(d))) if len(d) else 0.0
    if not info["converged"]:
        log.warning("seam erasure stopped after %d iterations short of its tolerance",
                    info["iterations"])
    return out, info


def _bounded(matrix: Csr, diag, rhs, x, left, bounds, tolerance, max_iterations, kernels,
             threads) -> tuple[np.ndarray, int, float, int]:
    """The minimum of 1/2 x.A x - rhs.x with lower <= x <= upper, from the unbounded one x.

    Clipping the unbounded minimum afterwards undoes the erasure wherever the baked values
    sit at a bound (open or buried texels, AO exactly 1 or 0, next to partly occluded ones:
    27% of the ogre's texels at 1024^2): the seam term pulls a texel past the bound to meet
    the other side, the clip takes it back, and the step comes back.  So texels beyond a
    bound are held at it and the free ones solved again with the held ones as known values
    (their rows and columns replaced by the identity: the matrix stays symmetric positive
    definite and the conjugate gradients leave the held values' bits alone), from where
    they were (x is the unbounded minimum to HOLD_TOLERANCE; the first round always
    solves, to the full tolerance).  These are rounds of a primal-dual active set method
    (Hintermüller, Ito, Kunisch 2002): a held texel whose gradient points inside (A x - rhs
    < 0 at the lower bound, > 0 at the upper, by more than the tolerance in the stopping
    test's Jacobi-scaled units) is let go, until the set repeats or after MAX_ROUNDS; a
    free texel still out of range is then clipped.  Every step is element-wise or a
    fixed-order sum: the same bits for any number of threads.  Returns (x, iterations, the
    last max |r / diag|, texels held).
    """
    lower, upper = bounds
    n = len(x)
    ranks = _sparse_ranks(matrix)
    rows = np.repeat(np.arange(n), np.diff(matrix.indptr))
    cols = matrix.indices.astype(np.int64)
    on_diag = rows == cols
    held = np.zeros(n, dtype=np.int8)  # -1 at the lower bound, +1 at the upper, 0 free
    iterations = 0
    for round_ in range(max(MAX_ROUNDS, 1)):
        if held.any():  # the gradient, Jacobi-scaled, tells which held texels to let go
            scaled = (_sparse_apply(matrix, x, ranks) - rhs) / diag
            go = ((held < 0) & (scaled < -tolerance)) | ((held > 0) & (scaled > tolerance))
        else:
            go = held != 0
        new = np.where(held == 0, np.where(x < lower, -1, np.where(x > upper, 1, 0)),
                       np.where(go, 0, held)).astype(np.int8)
        if round_ > 0 and np.array_equal(new, held):
            break
        held = new
        free = held == 0
        x = np.where(held < 0, lower, np.where(held > 0, upper, x))
        data = np.where(free[rows] & free[cols], matrix.data, 0.0)
        data[on_diag & ~free[rows]] = 1.0
        coupled = _sparse_apply(matrix, np.where(free, 0.0, x), ranks)  # A x_held
        x, it, left = cg(Csr(matrix.indptr, matrix.indices, data), np.where(free, diag, 1.0),
                         np.where(free, rhs - coupled, x), x, tolerance, max_iterations,
                         kernels, threads)
        iterations += it
    return np.clip(x, lower, upper), iterations, left, int(np.count_nonzero(held))


def _starts(system: SeamSystem) -> np.ndarray:
    """(G + 1,) int64 the first point of each group (points are stored in group order)."""
    g = system.group
    return np.r_[np.nonzero(np.r_[True, g[1:] != g[:-1]])[0], len(g)].astype(np.int64)


def system_pattern(system: SeamSystem, kernels, threads: int = 1) -> tuple:
    """The compiled solve's matrix pattern (``seam_pattern``): (indptr (n + 1,) int64,
    indices (nnz,) int32), a function of the system alone, made before the values are
    known."""
    indptr, indices = kernels.seam_pattern(
        _starts(system), np.ascontiguousarray(system.slots, np.int64),
        np.ascontiguousarray(system.gutter), system.fill_to, system.fill_from, int(threads))
    return np.frombuffer(indptr, np.int64), np.frombuffer(indices, np.int32)


# The assembly is written so that the compiled kernel can repeat it operation for
# operation: element-wise steps, and every sum in a fixed order (bincount adds in index
# order from 0.0), never einsum or BLAS, whose order of summation depends on the CPU.


def _assemble_numpy(coef, lam, starts, slots, gutter, fill_to, fill_from, fill_weight, w
                    ) -> Csr:
    """The solve's normal matrix A = W + P^T S P over the covered unknowns (numbered in
    texel order, gutter ones skipped) as ``Csr``, every diagonal stored: the arithmetic of
    ``seam_pattern`` and ``seam_values`` (aobake/_seams.c).

    S P: each group g's 8 x 8 block, the sum over its points p in order of (lam_p c_pk) c_pl,
    read through the map of each slot's texel t (t itself with weight 1 when covered, else
    its fill entries' texels and weights, in entry order).  A_ab sums, from 0.0 in the order
    (g, k, a's entry, l, b's entry), the terms (block_gkl w_a) w_b, then 0.0 (every
    diagonal is stored); the diagonal then adds w_a.
    """
    n, groups = len(gutter), len(slots)
    covered = ~np.asarray(gutter, dtype=bool)
    nc = int(covered.sum())
    cidx = np.full(n, -1, dtype=np.int64)
    cidx[covered] = np.arange(nc)
    group = np.repeat(np.arange(groups, dtype=np.int64), np.diff(starts))
    outer = (lam[:, None] * coef)[:, :, None] * coef[:, None, :]  # (m, 8, 8)
    bins = (group[:, None] * 64 + np.arange(64)).reshape(-1)
    block = np.bincount(bins, weights=outer.reshape(-1), minlength=64 * groups)
    # each texel's map: (unknown, weight) entries, covered texels one, gutter ones their fill
    fills = np.bincount(fill_to, minlength=n)  # entries per gutter texel
    length = np.where(covered, 1, fills)
    first = np.cumsum(length) - length
    map_col = np.empty(int(length.sum()), dtype=np.int64)
    map_w = np.empty(len(map_col))
    map_col[first[covered]] = cidx[covered]
    map_w[first[covered]] = 1.0
    order = np.argsort(fill_to, kind="stable")  # by gutter texel, each in entry order
    to = fill_to[order]
    at = first[to] + np.arange(len(order)) - (np.cumsum(fills) - fills)[to]
    map_col[at] = cidx[fill_from[order]]
    map_w[at] = fill_weight[order]

    def expand(texel):  # (entries of each texel's map, in order): (owner, entry index)
        count = length[texel]
        owner = np.repeat(np.arange(len(texel)), count)
        start = np.repeat(first[texel] - (np.cumsum(count) - count), count)
        return owner, start + np.arange(len(owner))

    flat = slots.reshape(-1)  # slot j = 8 g + k
    ja, ea = expand(flat)  # pairs (slot j, a's entry), in order of j then entry
    pair = np.repeat(np.arange(len(ja)), 8)  # each pair with l = 0..7
    jl = (ja[pair] // 8) * 8 + np.tile(np.arange(8), len(ja))
    term, eb = expand(flat[jl])
    pa, jb = pair[term], jl[term]
    g, k, l_ = ja[pa] // 8, ja[pa] % 8, jb % 8
    values = (block[g * 64 + k * 8 + l_] * map_w[ea[pa]]) * map_w[eb]
    rows, cols = map_col[ea[pa]], map_col[eb]
    diag = np.arange(nc, dtype=np.int64)  # every diagonal, its 0.0 last
    keys = np.concatenate([rows * nc + cols, diag * nc + diag])
    values = np.concatenate([values, np.zeros(nc)])
    unique, inverse = np.unique(keys, return_inverse=True)
    data = np.bincount(inverse, weights=values, minlength=len(unique))
    row, col = unique // nc, unique % nc
    on_diag = row == col
    data[on_diag] = data[on_diag] + w[covered][row[on_diag]]
    indptr = np.zeros(nc + 1, dtype=np.int64)
    np.cumsum(np.bincount(row, minlength=nc), out=indptr[1:])
    return Csr(indptr, col.astype(np.int32), data)


# --- the lightmap's channels -----------------------------------------------------------


@dataclass
class Erased:
    """What ``erase_seams`` did.

    adjusted : (H, W) bool the covered texels that are unknowns of the solve (their values
    are changed in place), info : dict seam_edges, seam_points, points_dropped,
    texels_adjusted, gutter_texels (read by the seams, filled by the dilation), iterations,
    kappa (the highest seam weight any channel was solved at), converged, bound_texels (held
    at 0 or 1 by the bounded solve), rms_before / rms_after, max_before / max_after (of the
    first value channel, AO when baked: lookup differences over the seam points).
    """

    adjusted: np.ndarray
    info: dict


@dataclass(frozen=True)
class SeamChannel:
    """One value the seams are erased in: values, the image channel names (one, or three
    components of a direction), error, the channel of its stderr (the data term's weight),
    direction (solved per component and renormalised), counted (its solve's iterations
    and convergence go into ``Erased.info``: the baked channels, not derived ones)."""

    values: tuple
    error: str
    direction: bool = False
    counted: bool = True
    #: the range an adjusted scalar is solved within (the quantity's: thickness has no top)
    bounds: tuple = (0.0, 1.0)

    @classmethod
    def of(cls, quantity) -> "SeamChannel":
        """The texel channels of a Quantity."""
        direction = quantity.texel == "direction"
        values = tuple(quantity.value.exr) if direction else (quantity.value.exr[0],)
        return cls(values, quantity.error.exr[0], direction, bounds=quantity.bounds)


@dataclass(frozen=True)
class Prepared:
    """The seam system of a map, made before its values are known (``prepare``).

    covered : (H, W) bool the covered texels it was made for, padding : int, points :
    SeamPoints or None, system : SeamSystem or None (None: nothing to erase), seconds :
    float how long making it took (on whichever thread made it), pattern : the compiled
    solve's matrix pattern (``system_pattern``) or None (no kernel, or no system).
    """

    covered: np.ndarray
    padding: int
    points: SeamPoints | None
    system: SeamSystem | None
    seconds: float
    pattern: tuple | None = None


def prepare(mesh: SeamMesh, covered, padding: int, threads: int = 1) -> Prepared:
    """The seam points and system of ``mesh`` for the covered texels (H, W) bool: all of
    the erasure that does not depend on the baked values, so it can be made while they are
    splatted into texels (``Pending``, ``aobake.targets.texels.gather.channels``).
    ``threads``: the matrix pattern's (the same pattern for any number)."""
    clock = time.perf_counter()
    covered = np.asarray(covered, dtype=bool)
    height, width = covered.shape
    points = system = pattern = None
    if padding >= 1 and covered.any():
        points = seam_points(mesh, width, height)
        system = seam_system(points, covered, mesh.wrap)
        if system.n_rows == 0:
            points = system = None
        elif _native.kernels() is not None:
            pattern = system_pattern(system, _native.kernels(), threads)
    return Prepared(covered, int(padding), points, system, time.perf_counter() - clock,
                    pattern)


class Pending:
    """A seam system being made on its own thread (``prepare`` of the arguments), while the
    caller splats the traced values into texels (after tracing: work beside the tracing
    would slow it by as much, and hide in its time).  ``take()`` waits for it and hands it
    over, once: nothing else keeps it, so its memory is free again for the gutters once the
    erasure is done."""

    def __init__(self, mesh: SeamMesh, covered, padding: int, threads: int = 1):
        pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="aobake-seams")
        try:
            self._future = pool.submit(_native.carried(prepare), mesh, covered, padding,
                                       threads)
        finally:
            pool.shutdown(wait=False)

    def take(self) -> Prepared | None:
        """The system, or None if making it failed on its thread (a MemoryError, say):
        ``erase_seams`` then makes it on the caller's thread, where a real failure is
        raised."""
        future, self._future = self._future, None
        try:
            return future.result()
        except Exception as exc:  # noqa: BLE001 - made again by the caller
            log.debug("seam system made on its thread failed (%s): made again", exc)
            return None


def erase_seams(images: dict, channels, mesh: SeamMesh, covered, padding: int,
                directions: bool = True, compiled: bool | None = None,
                prepared: Prepared | None = None, threads: int = 1) -> Erased | None:
    """Erase the seams of the value channels of ``images`` (covered texels, in place).

    images : channel name -> (H, W) float64 texel values and stderrs (covered texels
    hold the bake; others are ignored), channels : the ``SeamChannel`` s to erase (a
    direction is solved per component, with the angle error as weight, and renormalised,
    only when ``directions``: a tangent-space bent normal's frame turns across a seam, so
    its components do not meet there),
    covered : (H, W) bool, padding : the gutter rings the map gets (0: lookups at chart
    edges read the push-pull fill, and nothing is erased), compiled : as in ``solve``,
    prepared : ``prepare``'s result for this mesh, used when made for the same covered
    texels and padding (else the system is made here), threads : the solve's (at most one
    per THREAD_UNKNOWNS unknowns; the same bits for any number).
    Adjusted scalars are solved within their quantity's range (``solve``'s bounds: AO and
    obscurance [0, 1], thickness [0, inf)).  Returns None when there is nothing to erase.
    """
    covered = np.asarray(covered, dtype=bool)
    height, width = covered.shape
    if prepared is None or prepared.padding != padding \
            or not np.array_equal(prepared.covered, covered):
        prepared = prepare(mesh, covered, padding)
    points, system = prepared.points, prepared.system
    if system is None:
        return None
    info = {"seam_edges": points.n_edges, "seam_points": len(points.uv_a),
            "points_dropped": system.dropped,
            "texels_adjusted": int(np.count_nonzero(~system.gutter)),
            "gutter_texels": int(np.count_nonzero(system.gutter)), "iterations": 0,
            "converged": True, "bound_texels": 0}
    rows, cols = np.divmod(system.texels[~system.gutter], width)
    for channel in channels:
        direction, names = channel.direction, channel.values
        if direction and not directions:
            continue
        b = np.zeros((len(system.texels), len(names)))
        b[~system.gutter] = np.stack([images[name][rows, cols] for name in names], axis=1)
        se = np.zeros(len(system.texels))
        se[~system.gutter] = images[channel.error][rows, cols]
        x, solved = solve(b, se, system, compiled=compiled,
                          threads=max(1, min(int(threads or 1),
                                             len(system.texels) // THREAD_UNKNOWNS)),
                          pattern=prepared.pattern, bounds=None if direction else channel.bounds)
        x = x[~system.gutter]
        if direction:  # unit directions again (a zero mean stays zero)
            length = np.linalg.norm(x, axis=1, keepdims=True)
            x = np.divide(x, length, out=np.zeros_like(x), where=length > 0)
        else:
            x = np.clip(x, *channel.bounds)
        for i, name in enumerate(names):
            images[name][rows, cols] = x[:, i]
        if not channel.counted:
            continue
        if "rms_before" not in info:
            info.update({key: solved[key] for key in ("rms_before", "rms_after", "max_before",
                                                      "max_after")})
        info["iterations"] = max(info["iterations"], solved["iterations"])
        info["kappa"] = max(info.get("kappa", 0.0), solved["kappa"])
        info["converged"] &= solved["converged"]
        info["bound_texels"] = max(info["bound_texels"], solved.get("bound_texels", 0))
    adjusted = np.zeros((height, width), dtype=bool)
    adjusted[rows, cols] = True
    return Erased(adjusted, info)
