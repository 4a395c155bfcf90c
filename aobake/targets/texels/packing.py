"""Packing for fresh UV atlases: xatlas's charts laid out densely, with exact padding.

Every chart (``aobake.targets.texels.charts``: each at one texel density) is marked at a
trial scale in its own frame (``_chart_masks``: the texels its triangles touch, grown by
``padding`` rings), and the grown masks are laid into the image without overlap
(``_Packer``: a skyline drop with quarter turns, holes above the skyline, an exhaustive
search), so two charts' texels end at least ``2 * padding`` empty texels apart.  The scale
is searched for the largest one whose layout fits (``_layout``; ``better_layout`` also
tries the charts' mirror images), or, at a fixed texel density, the smallest square that
holds the charts (``layout_at_density``).  The marks and each pack run in aobake/_pack.c
when it was built (``packing_kernels``), step for step as the numpy code here, the
reference (tests/test_pack_kernel.py: the same bits).
"""

from __future__ import annotations

import logging
import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from aobake import _native
from aobake.errors import InputError
from aobake.targets.texels.charts import uv_face_areas, vertex_charts
from aobake.vectors import distinct

log = logging.getLogger(__name__)

#: largest image side accepted (a layout at a texel density grows to at most this; the
#: lightmap target refuses larger images: ``atlas.check_texture_budget``)
MAX_RESOLUTION = 16384
#: A chart's lowest u and v sit this far (texels) into its first column and row.
CHART_OFFSET = 1.0 / 64.0
#: Hole search: free squares up to HOLE_CAP texels and free runs up to HOLE_RUN are
#: tracked; at most HOLE_ROWS rows with room are tried per chart.
HOLE_CAP = 32
HOLE_RUN = 128
HOLE_ROWS = 64
#: A chart that finds no room there is looked for everywhere, at most this often per pack
#: (a layout that needs more is at a scale too large anyway).
MAX_SEARCHES = 16
#: Packing efficiency (padded chart texels / image) assumed for the first try.
FIRST_EFFICIENCY = 0.66
#: A layout that fills this share of the strip's rows is kept without trying more.
ACCEPT_ROWS = 0.985
#: Scale search: stop when the next scale is within SCALE_TOLERANCE of the best that fits.
SCALE_TOLERANCE = 0.01
MAX_PACKS = 4
#: ... and up to WIDE_PACKS more while the largest fit and the smallest failure are still
#: more than WIDE_BRACKET apart (the ogre at 1024^2 P8: [1.380, 1.480] after 4 packs)
WIDE_PACKS, WIDE_BRACKET = 2, 0.03
#: ... with at most FEW_CHARTS charts, where a pack costs milliseconds and a few large
#: charts make the fit jump with the scale (a box's six faces at 128^2: 55.7% covered
#: after 4 packs, 58.6% after 9, as xatlas's own pack)
FEW_TOLERANCE, FEW_PACKS = 0.002, 12


def _chart_masks(uv, faces, face_chart, n_charts, scale, padding, kernels=None):
    """Each chart's texels at ``scale``, in its own frame.

    Returns (origin (k, 2) float64: the chart's UV that goes to its frame's (0, 0),
    covered: list of k (h, w) bool, the texels its triangles touch, with ``padding`` empty
    rings around them; padded: the same grown by ``padding`` rings (8-neighbour)).
    A texel is marked when a triangle's closed area meets it, with a relative margin, so the
    marks hold every texel the rasteriser can cover (it needs an open overlap) after the
    chart is moved by whole texels and turned by quarter turns.
    ``kernels``: the compiled module (``aobake._native.kernels()``): the per-texel tests and
    the growing run in ``chart_marks`` (aobake/_pack.c), the same marks; None: numpy.
    """
    t = uv * scale
    vertex_chart = vertex_charts(len(t), faces, face_chart)
    order = np.argsort(vertex_chart, kind="stable")
    starts = np.searchsorted(vertex_chart[order], np.arange(n_charts))
    has = np.bincount(vertex_chart, minlength=n_charts) > 0
    lo = np.zeros((n_charts, 2))
    lo[has] = np.minimum.reduceat(t[order], starts[has], axis=0)
    origin = (lo - (CHART_OFFSET + padding)) / scale  # in UV units
    # frame coordinates: texel units, x to the right, y down the rows, P + offset from 0
    xy = (t - lo[vertex_chart]) + (CHART_OFFSET + padding)
    hi = np.zeros((n_charts, 2))
    hi[has] = np.maximum.reduceat(xy[order], starts[has], axis=0)
    size = np.floor(hi).astype(np.int64) + 1 + padding  # (k, 2) columns, rows
    size = np.maximum(size, 2 * padding + 1)
    mask_offset = np.concatenate([[0], np.cumsum(size[:, 0] * size[:, 1])])
    if kernels is not None:  # the same steps from here on, per triangle in C
        covered_flat = np.empty(int(mask_offset[-1]), np.uint8)
        padded_flat = np.empty(int(mask_offset[-1]), np.uint8)
        kernels.chart_marks(np.ascontiguousarray(xy, np.float64),
                            np.ascontiguousarray(faces, np.int64),
                            np.ascontiguousarray(face_chart, np.int64),
                            mask_offset.astype(np.int64), np.ascontiguousarray(size, np.int64),
                            int(padding), covered_flat, padded_flat)
        return origin, _split_masks(covered_flat, mask_offset, size), \
            _split_masks(padded_flat, mask_offset, size)
    tri = xy[faces]  # (f, 3, 2)
    flat = np.zeros(int(mask_offset[-1]), bool)

    d = np.roll(tri, -1, axis=1) - tri  # (f, 3, 2) edges p0->p1, p1->p2, p2->p0
    twice_area = d[:, 0, 0] * d[:, 2, 1] - d[:, 0, 1] * d[:, 2, 0]
    # zero-area triangles are marked too (along their segment): the rasteriser skips them,
    # but one that rounding gives an area after the move must stay inside the marks
    usable = np.isfinite(twice_area)
    sign = np.where(twice_area > 0, -1.0, 1.0)[:, None]  # d2 = -(p2 - p0): flip
    # Each edge function (positive inside) as a x + b y + c, c raised by its largest gain
    # over a texel square, (|dx| + |dy|) / 2, with a relative margin of 1e-7: >= 0 at a
    # texel centre <=> the closed triangle side meets the texel.
    ea, eb = -sign * d[..., 1], sign * d[..., 0]
    ec = sign * (d[..., 1] * tri[..., 0] - d[..., 0] * tri[..., 1])
    ec += 0.5 * (np.abs(d[..., 0]) + np.abs(d[..., 1])) * (1.0 + 1e-7)
    c0 = np.floor(tri[..., 0].min(axis=1)).astype(np.int64)
    c1 = np.floor(tri[..., 0].max(axis=1)).astype(np.int64)
    r0 = np.floor(tri[..., 1].min(axis=1)).astype(np.int64)
    r1 = np.floor(tri[..., 1].max(axis=1)).astype(np.int64)
    bw, bh = c1 - c0 + 1, r1 - r0 + 1
    ids = np.flatnonzero(usable)
    pairs = (bw * bh)[ids]
    # batches of about 2^18 (triangle, texel) pairs bound the temporaries
    bounds = np.searchsorted(np.cumsum(pairs), np.arange(1, int(pairs.sum()) // (1 << 18) + 1)
                             * (1 << 18))
    for batch in np.split(ids, bounds):
        if not len(batch):
            continue
        n = bw[batch] * bh[batch]
        f = np.repeat(batch, n)
        j = np.arange(len(f)) - np.repeat(np.cumsum(n) - n, n)
        w = bw[f]
        col, row = c0[f] + j % w, r0[f] + j // w
        cx, cy = col + 0.5, row + 0.5
        inside = ea[f, 0] * cx + eb[f, 0] * cy + ec[f, 0] >= 0
        for k in (1, 2):
            inside &= ea[f, k] * cx + eb[f, k] * cy + ec[f, k] >= 0
        ch = face_chart[f[inside]]
        flat[mask_offset[ch] + row[inside] * size[ch, 0] + col[inside]] = True
    covered = [flat[mask_offset[c]:mask_offset[c + 1]].reshape(size[c, 1], size[c, 0])
               for c in range(n_charts)]
    padded = [_grow(m, padding) for m in covered]
    return origin, covered, padded


def _split_masks(flat, offset, size):
    """(n,) uint8 0/1 masks laid end to end -> list of k (rows, columns) bool views
    (mask c at offset[c], size[c] = (columns, rows))."""
    view = flat.view(bool)
    return [view[offset[c]:offset[c + 1]].reshape(size[c, 1], size[c, 0])
            for c in range(len(size))]


def _grow(mask: np.ndarray, rings: int) -> np.ndarray:
    """(h, w) bool grown by ``rings`` 8-neighbour rings (a square of side 2 rings + 1)."""
    if rings == 0:
        return mask.copy()
    rows = mask.copy()
    for d in range(1, rings + 1):
        rows[:, d:] |= mask[:, :-d]
        rows[:, :-d] |= mask[:, d:]
    out = rows.copy()
    for d in range(1, rings + 1):
        out[d:] |= rows[:-d]
        out[:-d] |= rows[d:]
    return out


def _profiles(mask):
    """Per column of an (h, w) mask: first and one-past-last marked row, and whether any
    is marked (unmarked columns: top = h, bottom = 0, so they constrain nothing)."""
    marked = mask.any(axis=0)
    top = np.where(marked, mask.argmax(axis=0), mask.shape[0])
    bottom = np.where(marked, mask.shape[0] - mask[::-1].argmax(axis=0), 0)
    return top, bottom, marked


class _Packer:
    """Charts' padded masks laid into a width x height strip, top row first.

    Each chart goes where the mean over its columns of its lowest texel ends highest:
    dropped onto the skyline (each column's lowest occupied row, so the chart's own
    column profile may interlock with the charts above), or into a hole above the skyline
    where its bounding box is free (found through the largest free square whose corner is
    at each texel, up to HOLE_CAP; boxes up to HOLE_RUN wide).  Masks never overlap, so two
    charts' texels, each grown by ``padding`` rings, end >= 2 padding empty texels apart.
    """

    def __init__(self, width: int, height: int):
        self.width, self.height = width, height
        self.occupied = np.zeros((height, width), bool)
        self.sky = np.zeros(width, np.int32)
        self.columns = np.arange(width, dtype=np.int32)
        # free cells from (y, x) to the right, capped at HOLE_RUN; rows past the bottom: none
        self.free_run = np.zeros((height + HOLE_CAP, width), np.int16)
        self.free_run[:height] = np.minimum(width - self.columns, HOLE_RUN)
        # side of the largest free square with its top-left corner at (y, x), capped: made
        # when the first chart small enough for a hole comes (charts come largest first)
        self.square = self.row_best = None

    def skyline(self, top, bottom, marked, w):
        """(score, y, x) of the best drop onto the skyline, or None if too wide."""
        if w > self.width:
            return None
        window = np.lib.stride_tricks.sliding_window_view(self.sky, w)
        top = top.astype(np.int32)
        if not marked.all():
            window, top, bottom = window[:, marked], top[marked], bottom[marked]
        y = np.maximum((window - top).max(axis=1), 0)
        i = int(np.argmin(y))  # the mean bottom is the same everywhere: lowest drop wins
        return float(y[i] + bottom.mean()), int(y[i]), i

    def hole(self, h, w, mean_bottom, beat: float):
        """(score, y, x) of the first free h x w box scoring below ``beat``, or None."""
        side = min(h, w)
        if side > HOLE_CAP or w > HOLE_RUN or w > self.width:
            return None
        last = self.height - h
        if math.isfinite(beat):
            last = min(int(math.ceil(beat - mean_bottom)) - 1, last)
        if last < 0:
            return None
        if self.square is None:
            self.square = np.full((self.height, self.width), HOLE_CAP, np.int16)
            self._squares(0, self.height, 0, self.width)
        rows = np.flatnonzero(self.row_best[:last + 1] >= side)[:HOLE_ROWS]
        down = np.arange(h)
        for r in range(0, len(rows), 8):  # a few rows at a time: most holes are found early
            # corners with a free square of the short side, in raster order; then the box
            ri, x = np.nonzero(self.square[rows[r:r + 8], :self.width - w + 1] >= side)
            if not len(x):
                continue
            y = rows[r:r + 8][ri]
            fits = self.free_run[y[:, None] + down, x[:, None]].min(axis=1) >= w
            j = int(np.argmax(fits))
            if fits[j]:
                return float(y[j] + mean_bottom), int(y[j]), int(x[j])
        return None

    def anywhere(self, h: int, w: int):
        """(y, x) of the first free h x w box anywhere in the strip (raster order), or None:
        the exhaustive search, for a chart that found no room on the skyline or in the
        holes tried."""
        if h > self.height or w > self.width:
            return None
        free = ~self.occupied
        run = np.minimum.accumulate(np.where(free, self.width, self.columns)[:, ::-1],
                                    axis=1)[:, ::-1] - self.columns  # exact free runs
        ok = run[:, :self.width - w + 1] >= w
        span = 1  # rows whose box rows all have the run: min over h rows by doubling
        while span < h:
            step = min(span, h - span)
            ok = ok[:-step] & ok[step:]
            span += step
        ys, xs = np.nonzero(ok[:self.height - h + 1])
        return (int(ys[0]), int(xs[0])) if len(ys) else None

    def place(self, mask, bottom, marked, y: int, x: int) -> None:
        h, w = mask.shape
        self.occupied[y:y + h, x:x + w] |= mask
        seg = self.sky[x:x + w]
        seg[marked] = np.maximum(seg[marked], y + bottom[marked])
        # runs that now stop at the new texels: up to HOLE_RUN columns to the left
        x0 = max(0, x - HOLE_RUN)
        cols = self.columns[x0:x + w]
        hit = np.zeros((h, x + w - x0), bool)
        hit[:, x - x0:] = mask
        nxt = np.minimum.accumulate(np.where(hit, cols, x + w + HOLE_RUN)[:, ::-1],
                                    axis=1)[:, ::-1]
        runs = self.free_run[y:y + h, x0:x + w]
        np.minimum(runs, np.minimum(nxt - cols, HOLE_RUN), out=runs, casting="unsafe")
        if self.square is not None:  # squares whose corner is up to HOLE_CAP above or left
            self._squares(max(0, y - HOLE_CAP), y + h, max(0, x - HOLE_CAP), x + w)

    def _squares(self, y0, y1, x0, x1):
        """Refresh the free squares with corners in [y0, y1) x [x0, x1) (they only shrink)."""
        sq = self.square[y0:y1, x0:x1]
        for dy in range(HOLE_CAP):  # side = min over rows dy of max(dy, free run there)
            np.minimum(sq, np.maximum(self.free_run[y0 + dy:y1 + dy, x0:x1], np.int16(dy)),
                       out=sq)
        if self.row_best is None:
            self.row_best = self.square.max(axis=1)
        else:
            self.row_best[y0:y1] = self.square[y0:y1].max(axis=1)


#: Packing orders (``_pack``) and whether charts stand upright: longest short side first,
#: then (tried when few charts make each pack cheap and a greedy order decides much) most
#: texels first, longest side first, and upright (a capsule's four long cylinder charts
#: at 256^2 P4: 51.4% covered flat, as a stair down the strip; side by side upright more)
ORDERS = (("short_side", False), ("texels", False), ("long_side", False),
          ("short_side", True), ("long_side", True))
#: ... at most this many charts for the other orders
FEW_CHARTS = 64


def _order(padded, how: str) -> np.ndarray:
    """(k,) int64 packing order of the masks (stable, so a function of the masks only)."""
    size = {"short_side": lambda m: min(m.shape), "texels": np.count_nonzero,
            "long_side": lambda m: max(m.shape)}[how]
    return np.argsort([-int(size(m)) for m in padded], kind="stable")


def _pack(padded, width: int, height: int, kernels=None):
    """Place every padded mask in a width x height strip: the first of ORDERS whose
    layout fits (the later ones only for at most FEW_CHARTS charts) or, when they all
    fit, the one using the fewest rows.

    Returns (place: per chart (row, column, quarter turns as np.rot90) or None when they do
    not fit, padded texels placed, strip rows used (``height`` when they did not fit)).
    ``kernels``: the compiled module or None (numpy), see ``_pack_in_order``.
    """
    best = None
    for how, upright in ORDERS if len(padded) <= FEW_CHARTS else ORDERS[:1]:
        got = _pack_in_order(padded, width, height, _order(padded, how), upright, kernels)
        if best is None or (got[0] is not None and (best[0] is None or got[2] < best[2])) \
                or (got[0] is None and best[0] is None and got[1] > best[1]):
            best = got
    return best


def _pack_in_order(padded, width: int, height: int, order, upright: bool = False,
                   kernels=None):
    """``_pack`` in one order ((k,) int64: longest short side first: large, square-ish
    charts make the skyline, slivers and small charts fill in).  ``upright``: only the
    turns that stand each chart on its short side (a greedy drop lays long charts flat,
    where they may stair-step down a strip too narrow for two side by side).

    ``kernels``: the compiled module (``aobake._native.kernels()``): the whole loop below
    runs in ``pack_charts`` (aobake/_pack.c), with the same placements; None: this loop,
    the reference.
    """
    if kernels is not None:
        return _pack_compiled(kernels, padded, width, height, order, upright)
    return _pack_numpy(padded, width, height, order, upright)[0]


def _pack_numpy(padded, width: int, height: int, order, upright: bool):
    """The reference ``_pack_in_order``: (its result, the ``_Packer`` as it ended)."""
    packer = _Packer(width, height)
    place = [(0, 0, 0)] * len(padded)
    placed = searches = 0
    for c in order:
        if not padded[c].any():
            continue  # no texels: its UVs can sit anywhere (see _layout)
        best = None
        turns = [np.rot90(padded[c], k) for k in range(4)]
        shapes = [_profiles(m) for m in turns]
        allowed = [k for k in range(4) if not upright or turns[k].shape[0] >= turns[k].shape[1]]
        boxes = [k for k in (0, 1) if k in allowed or k + 2 in allowed]  # same box as k + 2
        for k in allowed:
            top, bottom, marked = shapes[k]
            found = packer.skyline(top, bottom, marked, turns[k].shape[1])
            if found is not None and found[1] + turns[k].shape[0] <= height and (
                    best is None or found[0] < best[0]):
                best = (*found, k)
        for k in boxes:
            h, w = turns[k].shape
            found = packer.hole(h, w, shapes[k][1][shapes[k][2]].mean(),
                                best[0] if best else math.inf)
            if found is not None and (best is None or found[0] < best[0]):
                best = (*found, k)
        if best is None:  # no room on the skyline or in the holes tried
            searches += 1
            for k in boxes if searches <= MAX_SEARCHES else ():
                found = packer.anywhere(*turns[k].shape)
                if found is not None:
                    score = found[0] + shapes[k][1][shapes[k][2]].mean()
                    if best is None or score < best[0]:
                        best = (score, *found, k)
            if best is None:
                return (None, placed, height), packer
        _, y, x, k = best
        packer.place(turns[k], shapes[k][1], shapes[k][2], y, x)
        place[c] = (y, x, k)
        placed += int(padded[c].sum())
    return (place, placed, int(packer.sky.max())), packer


def _pack_compiled(kernels, padded, width: int, height: int, order, upright: bool,
                   state=None):
    """``_pack_in_order`` in aobake._kernels.pack_charts: the masks laid end to end as
    uint8 with their offsets and (rows, columns), the packer's constants passed along.
    ``state`` (for tests): None, or arrays (occupied, sky, free_run, square, row_best)
    shaped and typed as ``_Packer``'s, which receive the packer's final state (square and
    row_best -1 while not made)."""
    shapes = np.array([m.shape for m in padded], np.int64).reshape(-1, 2)
    offsets = np.concatenate([[0], np.cumsum(shapes[:, 0] * shapes[:, 1])]).astype(np.int64)
    masks = np.concatenate([np.ascontiguousarray(m, bool).ravel() for m in padded]) \
        if len(padded) else np.zeros(0, bool)
    out = np.zeros((len(padded), 3), np.int64)
    fits, placed, used = kernels.pack_charts(
        masks.view(np.uint8), offsets, shapes, np.ascontiguousarray(order, np.int64),
        int(width), int(height), bool(upright), HOLE_CAP, HOLE_RUN, HOLE_ROWS, MAX_SEARCHES,
        out, state)
    if not fits:
        return None, placed, height
    return [tuple(int(v) for v in p) for p in out], placed, used


def _layout(uv, faces, face_chart, R: int, P: int, chart_image: bool, kernels=None):
    """Scale search and packing: the largest scale whose charts fit in R x R.

    Returns (uv in texels of the R x R square, xatlas orientation (y down), scale, info).
    ``kernels``: the compiled module (marks and packs in aobake/_pack.c) or None (numpy);
    the layout is the same bits either way.
    """
    n_charts = int(face_chart.max()) + 1
    strip = R + 2 * P  # padding may overhang the image edges (as xatlas removes it there)
    area = float(uv_face_areas(uv, faces).sum())
    # boundary length of the charts (edges used by one face) for the first guess
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    keys, count = np.unique(edges[:, 0] * len(uv) + edges[:, 1], return_counts=True)
    once = keys[count == 1]
    perimeter = float(np.linalg.norm(uv[once // len(uv)] - uv[once % len(uv)], axis=1).sum())

    def model(s):  # padded texels: area + a band of P + 1/2 along the boundary + corners
        return area * s * s + perimeter * s * (P + 0.5) + n_charts * (2 * P + 1) ** 2

    def solve(target):  # the s with model(s) = target (model increases with s)
        lo_s, hi_s = 0.0, 1.0
        while model(hi_s) < target:
            hi_s *= 2.0
        for _ in range(60):
            mid = 0.5 * (lo_s + hi_s)
            lo_s, hi_s = (mid, hi_s) if model(mid) < target else (lo_s, mid)
        return lo_s

    if n_charts * (2 * P + 1) ** 2 > strip * strip:
        raise InputError(f"the {n_charts} charts cannot fit in one {R}x{R} atlas with {P} "
                         "texels of padding: raise --resolution or lower --padding")
    # A scale of 0 "fits" any number of charts by shrinking them to points (no texel, UVs
    # NaN: the ogre's 826 charts at 256^2 with P = 4 did); the search stays at or above
    # the scale at which the largest chart is one texel across.
    used = distinct(faces, len(uv))  # vertices of no face belong to no chart
    vertex_chart = vertex_charts(len(uv), faces, face_chart)[used]
    high = np.full((n_charts, 2), -np.inf)
    np.maximum.at(high, vertex_chart, uv[used])
    low = np.full((n_charts, 2), np.inf)
    np.minimum.at(low, vertex_chart, uv[used])
    span = high - low
    widest = float(np.max(span[np.isfinite(span)], initial=0.0))
    floor = 1.0 / widest if widest > 0 else 1.0
    scale = max(solve(FIRST_EFFICIENCY * strip * strip), floor)
    best, tried, fails = None, [], []
    few = n_charts <= FEW_CHARTS
    max_packs, tolerance = (FEW_PACKS, FEW_TOLERANCE) if few else (MAX_PACKS, SCALE_TOLERANCE)
    for _ in range(max_packs + WIDE_PACKS + 12):  # the last 12 only while nothing fits yet
        if len(tried) >= max_packs and best is not None:
            above = [f for f in fails if f > best[0]]
            wide = bool(above) and min(above) > best[0] * (1 + WIDE_BRACKET)
            if not wide or len(tried) >= max_packs + WIDE_PACKS:
                break
        origin, covered, padded = _chart_masks(uv, faces, face_chart, n_charts, scale, P,
                                               kernels)
        texels = max(1, sum(int(np.count_nonzero(m)) for m in padded))
        place, placed, used = (None, 0, strip) if texels > strip * strip else _pack(
            padded, strip, strip, kernels)
        tried.append((round(scale, 4), used, place is not None))
        if place is not None:
            if best is None or scale > best[0]:
                best = (scale, origin, covered, padded, place, used)
            if used >= ACCEPT_ROWS * strip:
                break  # it fills the strip
            efficiency = texels / (strip * used)
        else:
            fails.append(scale)
            # the padded texels placed before a chart found no room: that much fits (when a
            # large chart found none early on, the share says little: shrink by <= 15%)
            efficiency = max(placed / (strip * strip), 0.72 * texels / (strip * strip))
        # the scale whose padded texels fill the strip at the efficiency just seen (the
        # model corrected by the texels just counted)
        target = efficiency * strip * strip * (1 - tolerance)
        new = solve(target * model(scale) / texels)
        if place is None:
            if scale <= floor:
                break  # not even one-texel charts fit
            new = max(min(new, 0.97 * scale), floor)
        if best is not None:
            above = [f for f in fails if f > best[0]]
            if above:  # bracketed by a fit and a failure: bisect
                top = min(above)
                if top <= best[0] * (1 + tolerance):
                    break
                new = math.sqrt(best[0] * top)
            elif new <= best[0] * (1 + tolerance):
                break  # no room to grow
        scale = new
    if best is None:
        raise InputError(f"could not pack the {n_charts} charts into one {R}x{R} atlas with {P} "
                         "texels of padding: raise --resolution or lower --padding")
    log.debug("packing: %d tries %s, %d charts, %d of %d rows", len(tried), tried, n_charts,
              best[5], strip)
    return _placed(uv, faces, face_chart, best, R, P, chart_image, len(tried))


def better_layout(uv, faces, face_chart, R: int, P: int, chart_image: bool, kernels=None):
    """``_layout`` of the charts as given and of their mirror images (u and v swapped), on
    two threads: the one that covers more texels (the first on a tie; either if the other
    does not fit).

    The packer moves charts by whole texels and quarter turns, so a mirror image is a shape
    it cannot make, and which of the two it starts from moves the coverage by a few points
    either way (the scale search stops at another layout): over the bunny and the ogre at
    256^2-1024^2 and paddings 1-8, -2.5 to +2.0 points between the two, none better
    everywhere.  The better of both is at least either, for about one layout's wall time
    (the packs run compiled, without the GIL).
    """
    def attempt(start):
        try:
            return _layout(start, faces, face_chart, R, P, chart_image, kernels), None
        except InputError as exc:
            return None, exc

    mirrored = np.ascontiguousarray(uv[:, ::-1])
    with ThreadPoolExecutor(max_workers=2, thread_name_prefix="aobake-layout") as pool:
        results = list(pool.map(attempt, (uv, mirrored)))
    fitted = [layout for layout, _ in results if layout is not None]
    if not fitted:
        raise results[0][1]
    return max(fitted, key=lambda layout: layout[3]["coverage"])  # max keeps the first tie


def _placed(uv, faces, face_chart, best, R: int, P: int, chart_image: bool, packs: int):
    """The packed layout ``best`` = (scale, origin, covered, padded, place, used) as UVs.

    Returns (uv (m, 2) float64 in texels of the R x R square, xatlas orientation (y down),
    scale, chart image (R, R, 3) uint8 or None, info).
    """
    n_charts = len(best[2])
    strip = R + 2 * P
    scale, origin, covered, padded, place, used = best
    # each chart: its frame (origin, scale), quarter turns as np.rot90, then its place
    vertex_chart = vertex_charts(len(uv), faces, face_chart)
    local = (uv - origin[vertex_chart]) * scale
    turns = np.array([p[2] for p in place])[vertex_chart]
    w = np.array([m.shape[1] for m in covered], np.float64)[vertex_chart]
    h = np.array([m.shape[0] for m in covered], np.float64)[vertex_chart]
    x, y = local[:, 0], local[:, 1]
    # np.rot90 (counter-clockwise as displayed, rows down): texel (row r, col c) of an
    # (h, w) mask goes to (w - 1 - c, r), so a point (x, y) goes to (y, w - x)
    rx = np.select([turns == 0, turns == 1, turns == 2], [x, y, w - x], h - y)
    ry = np.select([turns == 0, turns == 1, turns == 2], [y, w - x, h - y], x)
    py = np.array([p[0] for p in place], np.float64)[vertex_chart]
    px = np.array([p[1] for p in place], np.float64)[vertex_chart]
    out = np.stack([rx + px - P, ry + py - P], axis=1)
    empty = np.array([not m.any() for m in covered])[vertex_chart]
    out[empty] = np.clip(out[empty], 0.0, R)  # charts without texels: anywhere inside
    image = None
    if chart_image:
        image = np.zeros((strip, strip, 3), np.uint8)
        for c, (cy, cx, k) in enumerate(place):
            m = np.rot90(covered[c], k)
            colour = np.array([(c * 97) % 200 + 55, (c * 57) % 200 + 55, (c * 31) % 200 + 55],
                              np.uint8)
            image[cy:cy + m.shape[0], cx:cx + m.shape[1]][m] = colour
        image = image[P:P + R, P:P + R]
    info = {"charts": n_charts,
            "coverage": sum(int(m.sum()) for m in covered) / (R * R),
            "utilization": sum(int(m.sum()) for m in padded) / (strip * strip),
            "packs": packs}
    return out, scale, image, info


def layout_at_density(uv, faces, face_chart, scale: float, P: int, chart_image: bool,
                      kernels=None):
    """The smallest square R x R holding every chart at ``scale`` (texels per normalised
    unit, so the texel density is exactly the one asked for).

    The charts' padded texels T bound R from below (R + 2P >= sqrt(T)); strips of that
    width are packed with room below, and the width grown to the geometric mean of the
    width and the rows used until the rows fit in the width (each pack at least 1% wider,
    at most 12 packs).  Returns (uv, scale, image, info, R) as ``_layout``, plus R.
    ``kernels``: the compiled module or None (numpy), as for ``_layout``.
    """
    n_charts = int(face_chart.max()) + 1
    origin, covered, padded = _chart_masks(uv, faces, face_chart, n_charts, scale, P, kernels)
    texels = sum(int(m.sum()) for m in padded)
    side = max(2 * P + 1, int(math.ceil(math.sqrt(texels / ACCEPT_ROWS))))  # strip width
    largest = max((max(m.shape) for m in padded if m.any()), default=1)
    side = max(side, largest)
    for packs in range(1, 13):
        if side > MAX_RESOLUTION + 2 * P:
            break
        place, _, used = _pack(padded, side, 2 * side + largest, kernels)
        if place is not None and used <= side:
            R = side - 2 * P
            best = (scale, origin, covered, padded, place, used)
            log.debug("packing at a fixed density: %d packs, %dx%d", packs, R, R)
            return (*_placed(uv, faces, face_chart, best, R, P, chart_image, packs), R)
        side = max(int(math.ceil(1.01 * side)),
                   int(math.ceil(math.sqrt(side * used))) if place is not None else 0)
    raise InputError(f"the charts at this texel density need an image larger than "
                     f"{MAX_RESOLUTION}x{MAX_RESOLUTION} (about {side - 2 * P} per side): "
                     "lower --texel-density")


def packing_kernels(compiled: bool | None):
    """The compiled module for marking and packing, or None for numpy.  compiled: True
    (required), False, or None: when built and not forced off on this thread
    (``aobake._native``); a module built before the packer's kernels existed counts as not
    built."""
    kernels = _native.kernels() if compiled in (None, True) else None
    if kernels is not None and not hasattr(kernels, "pack_charts"):
        kernels = None
    if compiled and kernels is None:
        raise RuntimeError("aobake._kernels was not built with the atlas packer "
                           "(aobake/_pack.c): rebuild it (pip install -e .)")
    return kernels

