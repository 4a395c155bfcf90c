"""The lightmap rasteriser: texels of a UV atlas -> sample points (triangle + barycentrics).

Conventions (used by every function here and by ``aobake.outputs.image``):

- UVs follow the OBJ convention: ``u`` runs left to right and ``v = 0`` is the
  BOTTOM of the image, ``v = 1`` the top.
- An image of ``W x H`` texels is an array ``(H, W, C)`` whose row 0 is the
  TOP of the image (``v`` near 1).
- Texel ``(row r, col c)`` has its centre at ``u = (c + 0.5) / W``,
  ``v = 1 - (r + 0.5) / H``.  Its linear index is ``r * W + c``.
- Internally the rasteriser works in texel space ``x = u * W``,
  ``y = (1 - v) * H`` (``y`` grows downwards with the row number), where
  texel ``(r, c)`` is the unit square ``[c, c + 1) x [r, r + 1)``.
- UVs are not wrapped: parts of triangles outside ``[0, 1]^2`` are not
  sampled, and ``check_uvs`` reports such faces.

Coverage rule.  A sub-position is on a triangle when all three edge functions
are positive, or zero on an edge that the triangle owns.  Ownership is a
tie-break: a point exactly on an edge belongs to the side that contains the
point nudged by an infinitesimal step in the fixed direction (-1, -delta) in
texel space ("top-left" style rule).  Each edge function is evaluated from the
edge's endpoints in a canonical order, so the two triangles sharing an edge
compute bit-identical values of opposite sign; a point on a shared edge or a
shared vertex therefore lands on exactly one triangle of a watertight chart.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from aobake import _native
from aobake.rng import GOLDEN, mix, stable_sort, to_unit

log = logging.getLogger(__name__)

#: Coverage given to a texel that received only a fallback sample (no
#: sub-position landed on the surface): half of one sub-position's share,
#: i.e. ``0.5 / K``.  It is > 0 (the texel does hold a surface sample) and
#: smaller than the coverage of any texel where a sub-position landed.
FALLBACK_COVERAGE_FRACTION = 0.5

#: Default number of (triangle, texel) candidate pairs processed at once; it does not
#: change the result.  The numpy path's memory (roughly 500 bytes per pair): 64k pairs keep
#: a batch's temporaries in cache, 1.6x faster than 512k on one thread, and enough batches
#: to share between threads.  The compiled path takes rows of about this many pairs at a
#: time; its scratch is the densest row's pairs x K x 96 bytes.
CHUNK_PAIRS = 1 << 16

# --- results ---------------------------------------------------------------


@dataclass(frozen=True)
class TexelSamples:
    """Sample points of a texel atlas, as triangle + barycentric coordinates.

    Samples are sorted by (texel, sample, face), so the arrays do not depend on
    how the rasteriser was chunked.

    texel : (s,) int64
        Linear texel index ``r * width + c`` of each sample.
    face : (s,) int64
        Triangle of each sample.
    bary : (s, 3) float64
        Barycentric coordinates in the face's corner order; each in [0, 1],
        rows sum to 1.
    sample : (s,) int64
        Sub-position number within the texel, 0..K-1 (0 for fallback samples).
        Where triangles overlap in UV, one sub-position can yield one sample per
        covering triangle.
    is_fallback : (s,) bool
        True for the single fallback sample of a texel that the surface overlaps
        but where none of the K sub-positions landed on it.
    coverage : (height, width) float32
        Fraction of the texel's K sub-positions that landed on the surface
        (0 = empty, 1 = fully covered).  Texels with only a fallback sample get
        ``FALLBACK_COVERAGE_FRACTION / K``.
    shared : (height, width) int32
        Number of triangles covering the texel centre: 0 outside the surface,
        1 inside a valid atlas, >= 2 where shells overlap.
    width, height : int
        Image size in texels.
    texel_samples : int
        K, the number of sub-positions per texel.
    """

    texel: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    sample: np.ndarray
    is_fallback: np.ndarray
    coverage: np.ndarray
    shared: np.ndarray
    width: int
    height: int
    texel_samples: int

    @property
    def n_samples(self) -> int:
        return int(self.texel.shape[0])

    def rows_cols(self) -> tuple[np.ndarray, np.ndarray]:
        """Return (row, col) of each sample's texel, both (s,) int64."""
        return np.divmod(self.texel, self.width)


# --- validation ----------------------------------------------------------


def _check_uv_faces(uv, faces, width, height) -> tuple[np.ndarray, np.ndarray]:
    uv = np.asarray(uv, dtype=np.float64)
    faces = np.asarray(faces)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise ValueError(f"uv must be (n, 2), got {uv.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"faces must be (f, 3), got {faces.shape}")
    if not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"faces must be integers, got {faces.dtype}")
    faces = faces.astype(np.int64, copy=False)
    if faces.size and (faces.min() < 0 or faces.max() >= len(uv)):
        raise ValueError(f"faces index vertices outside 0..{len(uv) - 1}")
    if int(width) != width or int(height) != height or width < 1 or height < 1:
        raise ValueError(f"width and height must be positive integers, got {width} x {height}")
    return uv, faces


# --- counter-based jitter ----------------------------------------------------

_GOLDEN = np.uint64(GOLDEN)
_SEED_SALT = np.uint64(0x243F6A8885A308D3)  # digits of pi: any fixed odd constant


def _uniform(seed: int, texel: np.ndarray, k: int, dim: int) -> np.ndarray:
    """(n,) float64 in [0, 1): a pure function of (seed, texel, k, dim)."""
    with np.errstate(over="ignore"):
        s = mix(np.array([seed & 0xFFFFFFFFFFFFFFFF], dtype=np.uint64) ^ _SEED_SALT)
        key = texel.astype(np.uint64) * np.uint64(0x100000) + np.uint64(k * 4 + dim)
        # key * odd constant is a bijection, so distinct keys stay distinct for
        # one seed; the seed enters through an independent mix (never xor-ed
        # against a value built the same way, which could cancel to zero).
        h = mix(mix(key * _GOLDEN + s) + _GOLDEN)
    return to_unit(h)


def _lattice_generator(k: int) -> int:
    """Generator g coprime with k near k / golden ratio (rank-1 lattice)."""
    g = max(1, int(round(k / 1.618033988749895)))
    while np.gcd(g, k) != 1:
        g += 1
    return g


def subsample_offsets(texel: np.ndarray, k: int, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Position of sub-sample ``k`` of ``n`` inside each texel, in [0, 1)^2.

    texel : (m,) int64 linear texel indices.  Returns (dx, dy), each (m,)
    float64, measured from the texel's corner at (col, row) in texel space
    (dy grows downwards, with the row).
    n == 1: the centre (0.5, 0.5).  n a square q*q: one jittered point in each
    cell of a q x q grid.  Otherwise: a jittered rank-1 lattice (every column
    and every row of an n x n grid holds exactly one point).
    """
    if n == 1:
        half = np.full(texel.shape, 0.5)
        return half, half
    ux = _uniform(seed, texel, k, 0)
    uy = _uniform(seed, texel, k, 1)
    q = int(round(np.sqrt(n)))
    if q * q == n:
        return (k % q + ux) / q, (k // q + uy) / q
    g = _lattice_generator(n)
    return (k + ux) / n, ((k * g) % n + uy) / n


# --- the rasteriser ------------------------------------------------------------


@dataclass(frozen=True)
class _Edges:
    """Oriented, canonically evaluated edge functions of f triangles.

    For edge e of triangle t (oriented so the triangle's area is positive),
    E(x, y) = dx[t, e] * (y - ay[t, e]) - dy[t, e] * (x - ax[t, e]).
    (ax, ay) is the canonical first endpoint and (dx, dy) the canonical
    direction times +-1, so the neighbour across the edge gets exactly -E.
    Edge e runs from oriented vertex e to e + 1, so E is the barycentric weight
    of the opposite vertex e + 2.
    """

    ax: np.ndarray  # (f, 3) float64
    ay: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    owner: np.ndarray  # (f, 3) bool: the triangle owns points exactly on the edge
    verts: np.ndarray  # (f, 3, 2) float64 oriented vertices in texel space
    corner: np.ndarray  # (f, 3) int64: face corner of each oriented vertex


def _edges(xy: np.ndarray, faces: np.ndarray) -> tuple[_Edges, np.ndarray]:
    """Build edge functions; also return (f,) bool of rasterisable triangles."""
    tri = xy[faces]  # (f, 3, 2)
    e1 = tri[:, 1] - tri[:, 0]
    e2 = tri[:, 2] - tri[:, 0]
    area2 = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    usable = np.isfinite(area2) & (area2 != 0.0)
    corner = np.where((area2 < 0)[:, None], [0, 2, 1], [0, 1, 2]).astype(np.int64)
    verts = np.take_along_axis(tri, corner[:, :, None], axis=1)
    p = verts
    q = np.roll(verts, -1, axis=1)  # edge e: p[e] -> q[e] = verts[e + 1]
    swap = (p[..., 0] > q[..., 0]) | ((p[..., 0] == q[..., 0]) & (p[..., 1] > q[..., 1]))
    start = np.where(swap[..., None], q, p)
    end = np.where(swap[..., None], p, q)
    sign = np.where(swap, -1.0, 1.0)
    d = end - start
    # Negation is exact in IEEE arithmetic, so folding the sign into the
    # direction keeps E exactly antisymmetric between the two sides.
    dx, dy = sign * d[..., 0], sign * d[..., 1]
    # Owner rule = nudge the point by (-1, -delta): E(p + eps t) > 0 iff
    # dy > 0 or (dy == 0 and dx < 0), with (dx, dy) the oriented direction.
    owner = (dy > 0) | ((dy == 0) & (dx < 0))
    return _Edges(start[..., 0], start[..., 1], dx, dy, owner, verts, corner), usable


def _bbox(verts: np.ndarray, width: int, height: int):
    """Inclusive texel ranges (c0, c1, r0, r1), each (f,) int64, clipped."""
    lo = np.floor(verts.min(axis=1))
    hi = np.floor(verts.max(axis=1))
    c0 = np.clip(lo[:, 0], 0, width).astype(np.int64)
    r0 = np.clip(lo[:, 1], 0, height).astype(np.int64)
    c1 = np.clip(hi[:, 0], -1, width - 1).astype(np.int64)
    r1 = np.clip(hi[:, 1], -1, height - 1).astype(np.int64)
    return c0, c1, r0, r1


def _bands(tri, c0, c1, r0, r1, budget):
    """Split each triangle's texel box into row bands of at most ~budget pairs.

    Returns per-band arrays (tri, c0, bw, r0, rows), all (b,) int64.
    """
    bw = c1 - c0 + 1
    bh = r1 - r0 + 1
    rows_per_band = np.maximum(1, budget // bw)
    n_bands = -(-bh // rows_per_band)
    band_tri = np.repeat(tri, n_bands)
    first = np.repeat(np.cumsum(n_bands) - n_bands, n_bands)
    j = np.arange(len(band_tri)) - first
    rpb = np.repeat(rows_per_band, n_bands)
    band_r0 = np.repeat(r0, n_bands) + j * rpb
    rows = np.minimum(rpb, np.repeat(r1, n_bands) - band_r0 + 1)
    return band_tri, np.repeat(c0, n_bands), np.repeat(bw, n_bands), band_r0, rows


def _edge_values(ed: _Edges, t: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(m, 3) float64 oriented edge functions of triangles t at points (x, y)."""
    return ed.dx[t] * (y[:, None] - ed.ay[t]) - ed.dy[t] * (x[:, None] - ed.ax[t])


@dataclass
class _PairEdges:
    """Edge coefficients gathered once per (triangle, texel) candidate pair."""

    ax: np.ndarray  # (m, 3) float64
    ay: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    owner: np.ndarray  # (m, 3) bool

    @classmethod
    def gather(cls, ed: _Edges, t: np.ndarray) -> "_PairEdges":
        return cls(ed.ax[t], ed.ay[t], ed.dx[t], ed.dy[t], ed.owner[t])

    def take(self, keep: np.ndarray) -> "_PairEdges":
        return _PairEdges(self.ax[keep], self.ay[keep], self.dx[keep], self.dy[keep], self.owner[keep])

    def values(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(m, 3) edge functions at one point (x, y) per pair; same formula as _edge_values."""
        return self.dx * (y[:, None] - self.ay) - self.dy * (x[:, None] - self.ax)

    def inside(self, e: np.ndarray) -> np.ndarray:
        """(m,) bool: the point is on the triangle under the tie-break rule."""
        return np.all((e > 0) | ((e == 0) & self.owner), axis=1)


def _bary_from_edges(corner: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Barycentrics in face-corner order from (m, 3) edge values of inside points.

    corner : (m, 3) int64 face corner of each oriented vertex.
    """
    # Edge e is opposite oriented vertex e + 2: weights (E1, E2, E0).
    w = e[:, [1, 2, 0]]
    w = w / w.sum(axis=1, keepdims=True)
    out = np.empty_like(w)
    np.put_along_axis(out, corner, w, axis=1)
    return out


def _nearest_on_triangle(ed: _Edges, t: np.ndarray, px: np.ndarray, py: np.ndarray):
    """Nearest point of triangles t to points (px, py), as barycentrics.

    Returns (bary (m, 3) float64 in face-corner order, each in [0, 1], and
    dist2 (m,) float64 in texels^2).  Points inside the triangle are their own
    nearest point.
    """
    m = len(t)
    v = ed.verts[t]  # (m, 3, 2)
    p = np.stack([px, py], axis=1)
    best_d2 = np.full(m, np.inf)
    w = np.zeros((m, 3))
    for i in range(3):
        j = (i + 1) % 3
        a = v[:, i]
        d = v[:, j] - a
        s = np.clip(np.einsum("ij,ij->i", p - a, d) / np.einsum("ij,ij->i", d, d), 0.0, 1.0)
        d2 = np.sum((a + s[:, None] * d - p) ** 2, axis=1)
        better = d2 < best_d2
        best_d2 = np.where(better, d2, best_d2)
        wi = np.zeros((m, 3))
        wi[:, i] = 1.0 - s
        wi[:, j] = s
        w[better] = wi[better]
    e = _edge_values(ed, t, px, py)
    inside = np.all(e >= 0, axis=1)
    if inside.any():
        wi = e[inside][:, [1, 2, 0]]
        w[inside] = wi / wi.sum(axis=1, keepdims=True)
        best_d2[inside] = 0.0
    out = np.empty_like(w)
    np.put_along_axis(out, ed.corner[t], w, axis=1)
    return out, best_d2


def _candidate_chunks(band_tri, band_c0, band_bw, band_r0, band_rows, budget):
    """Yield (t, row, col) int64 arrays of candidate pairs, ~budget at a time."""
    counts = band_bw * band_rows
    ends = np.cumsum(counts)
    lo = 0
    while lo < len(counts):
        base = ends[lo - 1] if lo else 0
        hi = max(lo + 1, int(np.searchsorted(ends, base + budget, side="right")))
        cnt = counts[lo:hi]
        t = np.repeat(band_tri[lo:hi], cnt)
        local = np.arange(int(cnt.sum()), dtype=np.int64) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        bw = np.repeat(band_bw[lo:hi], cnt)
        row, col = np.divmod(local, bw)
        yield t, row + np.repeat(band_r0[lo:hi], cnt), col + np.repeat(band_c0[lo:hi], cnt)
        lo = hi


class _CompiledEdges(NamedTuple):
    """_Edges as C-contiguous buffers for aobake._kernels.raster_rows."""

    ax: np.ndarray
    ay: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    owner: np.ndarray
    corner: np.ndarray
    vmax: np.ndarray

    @classmethod
    def of(cls, ed: _Edges, vmax: np.ndarray) -> "_CompiledEdges":
        c = np.ascontiguousarray
        return cls(c(ed.ax, dtype=np.float64), c(ed.ay, dtype=np.float64),
                   c(ed.dx, dtype=np.float64), c(ed.dy, dtype=np.float64),
                   c(ed.owner, dtype=bool), c(ed.corner, dtype=np.int64), c(vmax, dtype=np.float64))


def _raster_chunk(ed: _Edges, vmax, t, row, col, width: int, n_sub: int, seed: int):
    """One batch of (triangle, texel) candidate pairs -> the rasteriser's per-batch parts:
    (texel, face, bary, k) of landed sub-positions, texels whose centre a triangle covers,
    and (texel, face) fallback candidates."""
    out_texel, out_face, out_bary, out_k = [], [], [], []
    pe = _PairEdges.gather(ed, t)
    cx, cy = col + 0.5, row + 0.5
    e_centre = pe.values(cx, cy)
    # Separating axes for triangle vs texel square: the bounding boxes
    # (closed overlap is guaranteed by how candidates are made), then each
    # edge, where the largest value of a linear E over the square is
    # E(centre) + (|dx| + |dy|) / 2.  Closed overlap: a sub-position can
    # land; open overlap (positive area in common): fallback candidate.
    half = 0.5 * (np.abs(pe.dx) + np.abs(pe.dy))
    # The closed test is only a pre-filter, so it gets a relative margin
    # for rounding: dropping a pair whose sub-position does land would lose
    # a sample, keeping an extra pair costs nothing.
    touch = np.all(e_centre + half * (1.0 + 1e-9) >= 0, axis=1)
    vm = vmax[t]
    open_overlap = np.all(e_centre + half > 0, axis=1) & (vm[:, 0] > col) & (vm[:, 1] > row)
    centre_in = pe.inside(e_centre)
    centre_texels = (row * width + col)[centre_in]

    if n_sub > 1:  # with K = 1 the centre test above is all there is to do
        t, row, col, open_overlap = t[touch], row[touch], col[touch], open_overlap[touch]
        pe, e_centre = pe.take(touch), e_centre[touch]
    texel = row * width + col
    corner = ed.corner[t]
    fx, fy = col.astype(np.float64), row.astype(np.float64)
    pair_hit = np.zeros(len(t), dtype=bool)
    for k in range(n_sub):
        if n_sub == 1:
            e, ins = e_centre, centre_in
        else:
            dx, dy = subsample_offsets(texel, k, n_sub, seed)
            e = pe.values(fx + dx, fy + dy)
            ins = pe.inside(e)
        pair_hit |= ins
        out_texel.append(texel[ins])
        out_face.append(t[ins])
        out_bary.append(_bary_from_edges(corner[ins], e[ins]))
        out_k.append(np.full(int(ins.sum()), k, dtype=np.int64))
    cand = open_overlap & ~pair_hit
    return (np.concatenate(out_texel), np.concatenate(out_face), np.concatenate(out_bary),
            np.concatenate(out_k), centre_texels, texel[cand], t[cand])


def _rasterize_rows(kernels, ed: _Edges, vmax, tri_ids, c0, c1, r0, r1, width: int,
                    height: int, n_sub: int, seed: int, chunk_pairs: int, threads: int
                    ) -> TexelSamples:
    """``rasterize`` through the compiled ``raster_rows``: the same samples, bit for bit.

    Each image row's triangles (their texel boxes' rows, ascending triangle ids) are
    tested in the kernel, which writes the row's samples in their final (texel,
    sub-position, triangle) order with its fallbacks, so nothing is sorted, concatenated
    or inserted here.  It runs twice over pieces of rows of about ``chunk_pairs``
    (triangle, texel) pairs, on ``threads`` threads: first counting each row's samples,
    then writing them at the offsets the counts give.  Counting twice costs less than the
    temporaries it saves (bunny 1024^2, K = 4: 2.26M samples; the per-pair kernel with
    numpy's concatenations, sort and inserts ~1.0 s on the first call, most of it first
    touches of fresh memory).
    """
    c = np.ascontiguousarray
    ce = _CompiledEdges.of(ed, vmax)
    verts = c(ed.verts, dtype=np.float64)
    c0, c1 = c(c0, dtype=np.int64), c(c1, dtype=np.int64)
    heights = (r1 - r0 + 1)[tri_ids]
    first = np.cumsum(heights) - heights
    row_of = np.repeat(r0[tri_ids], heights) + (np.arange(int(heights.sum())) -
                                                np.repeat(first, heights))
    order, row_of = stable_sort(row_of, height, kernels)
    row_tris = c(np.repeat(tri_ids, heights)[order], dtype=np.int64)
    row_start = np.zeros(height + 1, dtype=np.int64)
    np.cumsum(np.bincount(row_of, minlength=height), out=row_start[1:])
    # pieces of rows of about chunk_pairs pairs (the result does not depend on them)
    pairs = np.cumsum(np.bincount(row_of, weights=(c1 - c0 + 1)[row_tris], minlength=height))
    cuts = np.searchsorted(pairs, np.arange(1, int(pairs[-1]) // chunk_pairs + 1) * chunk_pairs
                           if len(pairs) else [], side="right")
    edges = np.unique(np.r_[0, np.minimum(cuts + 1, height), height])
    pieces = list(zip(edges[:-1].tolist(), edges[1:].tolist()))
    q = int(round(np.sqrt(n_sub)))
    g = 0 if q * q == n_sub else _lattice_generator(n_sub)
    with np.errstate(over="ignore"):
        seed_key = int(mix(np.array([seed & 0xFFFFFFFFFFFFFFFF], dtype=np.uint64) ^ _SEED_SALT)[0])
    fixed = (*ce, verts, c0, c1, row_start, row_tris, int(width), int(n_sub), seed_key, q, g)

    def run(pieces, write, rows, outputs):
        def one(piece):
            kernels.raster_rows(*fixed, piece[0], piece[1], write, rows, *outputs)
        if threads > 1 and len(pieces) > 1:
            with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="aobake-raster") as pool:
                list(pool.map(one, pieces))
        else:
            for piece in pieces:
                one(piece)

    counts = np.zeros(height, dtype=np.int64)
    none_i, none_f = np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.float32)
    run(pieces, False, counts, (none_i, none_i, np.zeros(0), none_i, np.zeros(0, dtype=bool),
                                none_f, np.zeros(0, dtype=np.int32)))
    n = int(counts.sum())
    offsets = np.cumsum(counts) - counts
    texel, face, sub = (np.empty(n, dtype=np.int64) for _ in range(3))
    bary, is_fallback = np.empty((n, 3)), np.empty(n, dtype=bool)
    coverage = np.zeros(width * height, dtype=np.float32)
    shared = np.zeros(width * height, dtype=np.int32)
    run(pieces, True, offsets, (texel, face, bary, sub, is_fallback, coverage, shared))
    return TexelSamples(texel=texel, face=face, bary=bary, sample=sub, is_fallback=is_fallback,
                        coverage=coverage.reshape(height, width),
                        shared=shared.reshape(height, width), width=width, height=height,
                        texel_samples=n_sub)


def rasterize(
    uv,
    faces,
    width: int,
    height: int,
    texel_samples: int = 1,
    seed: int = 0,
    *,
    chunk_pairs: int = CHUNK_PAIRS,
    threads: int = 1,
    compiled: bool | None = None,
) -> TexelSamples:
    """Find the surface sample points of every texel of a width x height atlas.

    uv : (n, 2) float, OBJ convention; faces : (f, 3) int.
    texel_samples : K sub-positions per texel (see ``subsample_offsets``); each
        one that lands on a triangle (module coverage rule) becomes a sample.
    seed : jitter seed; offsets are a pure function of (seed, texel, k).
    chunk_pairs : candidate pairs per batch (numpy: bounds the memory) or per piece of
        rows (compiled); does not change the result.
    threads : batches processed at once; does not change the result.
    compiled : the compiled row kernel (``_rasterize_rows``; default: when it was built and
        not forced off, see ``aobake._native``) or numpy (the reference); the samples are
        identical.

    Texels that a triangle overlaps (open intersection with the texel square)
    but where no sub-position landed on any triangle get one fallback sample:
    the point of the overlapping triangle nearest to the texel centre (ties go
    to the lower face index).  It lies on the triangle (clamped to its edges),
    so edge texels are sampled on the surface, never extrapolated off it.
    Triangles with zero UV area or non-finite UVs get no samples.
    """
    uv, faces = _check_uv_faces(uv, faces, width, height)
    width, height, n_sub = int(width), int(height), int(texel_samples)
    if n_sub < 1:
        raise ValueError(f"texel_samples must be >= 1, got {texel_samples}")
    start_time = time.perf_counter()

    xy = np.stack([uv[:, 0] * width, (1.0 - uv[:, 1]) * height], axis=1)
    ed, usable = _edges(xy, faces)
    verts = np.where(usable[:, None, None], ed.verts, 0.0)
    c0, c1, r0, r1 = _bbox(verts, width, height)
    vmax = verts.max(axis=1)  # (f, 2) for the open bounding-box overlap test
    keep = usable & (c1 >= c0) & (r1 >= r0)
    tri_ids = np.flatnonzero(keep)
    bands = _bands(tri_ids, c0[keep], c1[keep], r0[keep], r1[keep], max(1, int(chunk_pairs)))

    kernels = _native.kernels() if compiled in (None, True) else None
    if compiled and kernels is None:
        raise RuntimeError("aobake._kernels was not built")
    if kernels is not None:
        result = _rasterize_rows(kernels, ed, vmax, tri_ids, c0, c1, r0, r1, width, height,
                                 n_sub, seed, max(1, int(chunk_pairs)), threads)
        log.debug("rasterised %d triangles into %dx%d texels, K=%d: %d samples (%d fallback) "
                  "in %.2f s", len(faces), width, height, n_sub, result.n_samples,
                  int(np.count_nonzero(result.is_fallback)), time.perf_counter() - start_time)
        return result

    def work(chunk):
        return _raster_chunk(ed, vmax, *chunk, width, n_sub, seed)

    chunks = _candidate_chunks(*bands, max(1, int(chunk_pairs)))
    if threads > 1:
        # numpy releases the GIL in the large element-wise passes; map keeps chunk order,
        # so the result is the same for any thread count.
        with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="aobake-raster") as pool:
            parts = list(pool.map(work, chunks))
    else:
        parts = [work(chunk) for chunk in chunks]
    out_texel, out_face, out_bary, out_k, centre_texels, cand_texel, cand_face = (
        [part[i] for part in parts] for i in range(7))

    def cat(parts, dtype, shape=(0,)):
        return np.concatenate(parts) if parts else np.zeros(shape, dtype=dtype)

    texel = cat(out_texel, np.int64)
    face = cat(out_face, np.int64)
    bary = cat(out_bary, np.float64, (0, 3))
    sub = cat(out_k, np.int64)
    n_texels = width * height

    # Sort by (texel, sub-position); candidates are made in increasing
    # triangle order and the sort is stable, so ties (stacked shells) end up
    # ordered by face: the result does not depend on chunking.
    key = texel * n_sub + sub
    order, key = stable_sort(key, width * height * n_sub, kernels)
    texel, sub = np.divmod(key, n_sub)  # exact: the sorted texels and sub-positions
    face, bary = face[order], bary[order]
    # Coverage counts distinct sub-positions, so stacked (overlapping) shells
    # do not push a texel above 1.
    distinct = np.ones(len(key), dtype=bool)
    distinct[1:] = key[1:] != key[:-1]
    landed = np.bincount(texel[distinct], minlength=n_texels)
    coverage = landed.astype(np.float32) / np.float32(n_sub)

    cand_texel = cat(cand_texel, np.int64)
    cand_face = cat(cand_face, np.int64)
    empty = landed[cand_texel] == 0
    cand_texel, cand_face = cand_texel[empty], cand_face[empty]
    if len(cand_texel):
        r, c = np.divmod(cand_texel, width)
        fb_bary, d2 = _nearest_on_triangle(ed, cand_face, c + 0.5, r + 0.5)
        pick_order = np.lexsort((cand_face, d2, cand_texel))  # nearest, then lowest face
        first = np.ones(len(pick_order), dtype=bool)
        first[1:] = cand_texel[pick_order][1:] != cand_texel[pick_order][:-1]
        pick = pick_order[first]  # one per texel, in increasing texel order
        fb_texel, fb_face, fb_bary = cand_texel[pick], cand_face[pick], fb_bary[pick]
        coverage[fb_texel] = FALLBACK_COVERAGE_FRACTION / n_sub
    else:
        fb_texel = fb_face = np.zeros(0, dtype=np.int64)
        fb_bary = np.zeros((0, 3))

    # Merge the fallback samples into the texel order.  Their texels (increasing) hold
    # no regular sample, so each goes exactly where a stable sort would put it.
    at = np.searchsorted(texel, fb_texel)
    is_fallback = np.insert(np.zeros(len(texel), dtype=bool), at, True)
    face = np.insert(face, at, fb_face)
    bary = np.insert(bary, at, fb_bary, axis=0)
    sub = np.insert(sub, at, 0)
    texel = np.insert(texel, at, fb_texel)

    shared = np.bincount(cat(centre_texels, np.int64), minlength=n_texels).astype(np.int32)
    result = TexelSamples(
        texel=texel,
        face=face,
        bary=bary,
        sample=sub,
        is_fallback=is_fallback,
        coverage=coverage.reshape(height, width),
        shared=shared.reshape(height, width),
        width=width,
        height=height,
        texel_samples=n_sub,
    )
    log.debug(
        "rasterised %d triangles into %dx%d texels, K=%d: %d samples (%d fallback) in %.2f s",
        len(faces), width, height, n_sub, len(texel), len(fb_texel), time.perf_counter() - start_time,
    )
    return result
