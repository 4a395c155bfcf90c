"""Fresh UV atlases, for meshes whose own UVs cannot be baked: xatlas charts, aobake packs.

xatlas cuts the mesh into charts and flattens them; the charts are then scaled to
one texel density and packed here (``_layout``), densely and with exact padding:
each chart's texels are marked at the trial scale, grown by ``padding`` rings and
laid without overlap.  All of it runs in a child Python process (with a time limit
and one retry): xatlas has been seen to segfault on some inputs and, once, to
deadlock in its thread pool; in a child either becomes an error message.  The atlas
follows the texel conventions of ``aobake.targets.texels`` (OBJ-convention UVs,
charts on the texel grid of the target image, ``padding`` empty texels around
every chart).
"""

from __future__ import annotations

import json
import logging
import math
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

from aobake import _native
from aobake.child import python_child
from aobake.errors import InputError
from aobake.vectors import distinct, weld

log = logging.getLogger(__name__)


class Unwrapped(NamedTuple):
    """A fresh atlas: new vertices referring back to the input ones.

    vmapping : (m,) int64   index into the input vertices of each new vertex
    faces : (f, 3) int64    triangles over the new vertices (same order as input)
    uv : (m, 2) float64     UVs in [0, 1], OBJ convention (v = 0 at the bottom)
    charts : int            number of charts
    size : (width, height)  the image the UVs are laid out for (the one asked for, or the
                            one chosen for a texel density); None when not known
    packing_compiled : bool | None  True when the charts were marked and packed by the
                            compiled kernels (aobake/_pack.c), False by the numpy reference
                            (the same atlas either way); None when not known
    charting : str | None   which xatlas charted: "aobake._xatlas" (built from
                            third_party/xatlas) or "xatlas" (the package), the same charts
    """

    vmapping: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    charts: int = 0
    size: tuple | None = None
    packing_compiled: bool | None = None
    charting: str | None = None


#: A chart grows to at most this many triangles' worth of area, counted in the triangles of
#: its own part (``_parts``): xatlas re-parameterises a chart at every face it adds, so
#: charting time grows faster than linearly with the faces per chart.
CHART_FACES = 500
#: ... at the resolution and padding it was tuned at.  Elsewhere the cap follows the
#: padding's share of a chart (``chart_cap``).
CHART_CAP_RESOLUTION, CHART_CAP_PADDING = 1024, 2
#: ... growing as this power of the area factor that would keep the padding's share
#: (between 0.5, cheap, and 1, the same share; measured on the bunny, ``chart_cap``)
CHART_CAP_POWER = 0.75
#: A connected piece above this many triangles is cut into spatial parts, charted in
#: parallel (xatlas charts one piece per thread); smaller pieces whose triangle sizes agree
#: within GROUP_SIZE_RATIO are charted together.
PART_FACES = 20000
GROUP_SIZE_RATIO = 2.0
#: Texels per unit of (normalised) area in xatlas's own pack, which only has to hand back
#: each chart's parameterisation: fine enough that rounding a chart up to whole texels
#: (xatlas stretches it to fill them) barely changes its shape.
FIRST_PACK_TEXELS = 16.0
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


def _split_faces(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> list[np.ndarray]:
    """Median-split face centroids along the widest axis into parts of <= max_faces."""
    centroids = vertices[faces].mean(axis=1)
    todo, parts = [np.arange(len(faces))], []
    while todo:
        part = todo.pop()
        if len(part) <= max_faces:
            parts.append(part)
            continue
        c = centroids[part]
        axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
        order = np.argsort(c[:, axis], kind="stable")
        half = len(part) // 2
        todo += [part[order[half:]], part[order[:half]]]
    return sorted(parts, key=lambda p: int(p[0]))


def _uv_face_areas(uv: np.ndarray, faces: np.ndarray) -> np.ndarray:
    t = uv[faces]
    return 0.5 * np.abs((t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1])
                        - (t[:, 1, 1] - t[:, 0, 1]) * (t[:, 2, 0] - t[:, 0, 0]))


def connected_labels(n: int, faces: np.ndarray) -> np.ndarray:
    """Connected components of the faces over shared vertex indices.

    n : number of vertices; faces : (f, 3) int.  Returns (f,) int64 labels 0..k-1, numbered
    in order of each component's first face.  (Union-find by hooking the larger root onto
    the smaller and pointer jumping, all in numpy.)
    """
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) == 0:
        return np.zeros(0, np.int64)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]]])
    root = np.arange(n, dtype=np.int64)
    while True:
        a, b = root[edges[:, 0]], root[edges[:, 1]]
        differ = a != b
        if not differ.any():
            break
        lo, hi = np.minimum(a[differ], b[differ]), np.maximum(a[differ], b[differ])
        np.minimum.at(root, hi, lo)
        while True:  # pointer jumping: every vertex to its root
            up = root[root]
            if np.array_equal(up, root):
                break
            root = up
    face_root = root[faces[:, 0]]
    _, first, inverse = np.unique(face_root, return_index=True, return_inverse=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    return rank[inverse.ravel()]


def uv_islands(uv, faces_uv) -> np.ndarray:
    """(f,) int64 UV island of each face: faces joined by UV vertices at the same place
    (welded first: an island may repeat its seam vertices, or a mesh have one ``vt`` per
    corner)."""
    uv = np.asarray(uv, np.float64)
    return connected_labels(len(uv), weld(uv)[faces_uv])


def chart_texel_density(uv, faces_uv, positions, faces, width, height):
    """Texel density of each UV island: sqrt(its UV area in texels / its surface area).

    uv (t, 2), faces_uv (f, 3): the UVs; positions (v, 3), faces (f, 3): the surface.
    Returns (k,) float64 over the islands with positive surface area (texels per scene unit).
    UV vertices at the same place count as one (an island may repeat its seam vertices).
    """
    labels = uv_islands(uv, faces_uv)
    texel_area = _uv_face_areas(np.asarray(uv, np.float64) * [width, height], faces_uv)
    p = np.asarray(positions, np.float64)[faces]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    k = int(labels.max()) + 1 if len(labels) else 0
    a2, a3 = np.bincount(labels, texel_area, k), np.bincount(labels, area, k)
    keep = a3 > 0
    return np.sqrt(a2[keep] / a3[keep])


def _vertex_charts(n: int, faces, face_chart) -> np.ndarray:
    """(n,) int64 chart of each vertex (charts share no vertex; unused vertices: 0)."""
    vertex_chart = np.zeros(n, np.int64)
    vertex_chart[faces.ravel()] = np.repeat(face_chart, 3)
    return vertex_chart


def _parts(vertices, faces, face_area) -> list[np.ndarray]:
    """Faces grouped into the meshes given to xatlas (each charted on its own thread).

    Connected pieces (vertices at the same position count as one) are grouped in order of
    their mean triangle area while the sizes agree within GROUP_SIZE_RATIO and the group
    stays under PART_FACES triangles; a piece larger than that is median-split in space.
    Each part is normalised on its own triangles (``_xatlas_charts``), so a finely
    tessellated eye and a coarse body both get charts of about CHART_FACES triangles.
    The parts are a function of the mesh only, never of the core count.
    """
    labels = connected_labels(len(vertices), weld(np.asarray(vertices, np.float64))[faces])
    k = int(labels.max()) + 1
    count = np.bincount(labels, minlength=k)
    mean = np.bincount(labels, face_area, k) / count
    by_piece = np.split(np.argsort(labels, kind="stable"), np.cumsum(count)[:-1])
    parts, group, group_min, group_faces = [], [], 0.0, 0
    for piece in np.argsort(mean, kind="stable"):
        members = by_piece[piece]
        if count[piece] > PART_FACES:
            parts += [members[p] for p in _split_faces(vertices, faces[members], PART_FACES)]
            continue
        if group and (group_faces + count[piece] > PART_FACES
                      or mean[piece] > GROUP_SIZE_RATIO * group_min):
            parts.append(np.concatenate(group))
            group = []
        if not group:
            group_min, group_faces = mean[piece], 0
        group.append(members)
        group_faces += int(count[piece])
    if group:
        parts.append(np.concatenate(group))
    parts = [np.sort(p) for p in parts]
    return sorted(parts, key=lambda p: int(p[0]))


def chart_cap(resolution: int, padding: int) -> float:
    """The chart area cap (in triangles of the chart's own part) for an R x R layout.

    Every chart costs a band of about (P + 1/2) texels along its boundary (its padded
    mask) plus (2P + 1)^2 at least, so the padding's share of a chart of A texels goes as
    (P + 1/2) / sqrt(A).  CHART_FACES keeps that share small at 1024^2 and P = 2; at a
    lower resolution (fewer texels per triangle) or a larger padding the same share would
    need charts of g = ((P + 1/2) / 2.5)^2 (1024 / R)^2 times the area.  Charting time
    grows about linearly with the cap (the bunny: x1.7 at 1000, x2.8 at 2000), so the cap
    grows as g^CHART_CAP_POWER only, never below CHART_FACES; the parts bound a chart
    anyway (``_parts``).  Measured on the bunny (69k triangles; 227 charts at CHART_FACES):
    at 256^2 P = 8 the cap of 500 left 0.5% of the image covered (xatlas's own default
    charts 18%), charts of up to 4000+ triangles (63 charts) cover 22%; at 512^2 P = 2,
    51.8% (xatlas 51.9%) and 55.1% with a cap of 1000; with sqrt(g) (1700) 1024^2 P = 8
    stayed below xatlas (44.4% vs 45.2%).
    """
    share = ((padding + 0.5) / (CHART_CAP_PADDING + 0.5)) ** 2
    growth = share * (CHART_CAP_RESOLUTION / resolution) ** 2
    return CHART_FACES * max(1.0, growth ** CHART_CAP_POWER)


def _chart_parts(V, F, parts, sizes, max_chart_faces):
    """xatlas charts of each part (one xatlas mesh per part, charted on its threads).

    V (v, 3) float64 normalised positions, F (f, 3) int64, parts: list of face index
    arrays, sizes: each part's length unit (its triangles are charted at V / size), cap:
    chart area cap in those units or None.  Returns per part (vmapping (m,) int64 into V,
    faces (p, 3) int64 over the part's new vertices in the part's face order, uv (m, 2)
    float64, any scale: charts are rescaled to their surface area afterwards).

    The charting runs in ``aobake._xatlas`` (xatlas built from third_party/xatlas, ~3x
    faster, the charts left unplaced) when it was built, else in the xatlas package: the
    same charts either way, their UVs differing by each chart's placement
    (``xatlas_charts``, tests/test_xatlas_build.py).
    """
    if not parts:
        return []
    meshes, part_vertices = [], []
    for part, size in zip(parts, sizes):
        used, local = np.unique(F[part], return_inverse=True)
        part_vertices.append(used)
        meshes.append((np.ascontiguousarray(V[used] / size, dtype=np.float32),
                       np.ascontiguousarray(local.reshape(-1, 3), dtype=np.uint32)))
    # xatlas's own pack only hands back each chart's parameterisation; it rounds every chart
    # up to whole texels (stretching it to fill them), so it runs at FIRST_PACK_TEXELS per
    # unit area, where that rounding barely changes a chart's shape.
    width, height, charted = xatlas_charts(meshes, float(max_chart_faces or 0.0),
                                           math.sqrt(FIRST_PACK_TEXELS))
    return [(used[vm.astype(np.int64)], fi.astype(np.int64),
             uv.astype(np.float64) * [width, height])
            for used, (vm, fi, uv) in zip(part_vertices, charted)]


def charting_library() -> str:
    """Which xatlas charts: "aobake._xatlas" (built from third_party/xatlas) or "xatlas"
    (the package)."""
    return "aobake._xatlas" if _built_xatlas() is not None else "xatlas"


def _built_xatlas():
    try:
        from aobake import _xatlas
    except ImportError:  # no C++ compiler at install: the package charts, the same charts
        return None
    return _xatlas


def xatlas_charts(meshes, max_chart_area: float, texels_per_unit: float, library=None,
                  placed: bool = False):
    """Chart and pack ``meshes`` (list of (positions (n, 3) float32, faces (m, 3) uint32))
    with xatlas: ChartOptions' defaults but ``max_chart_area`` (0: none), PackOptions'
    padding 0, no bilinear margin, ``texels_per_unit``.  ``library``: "aobake._xatlas",
    "xatlas" or None (``charting_library``).  Returns (width, height, per mesh (vmapping
    (k,) uint32, faces (m, 3) uint32, uv (k, 2) float32 over width and height)).

    The package places the charts in its atlas; aobake._xatlas only when ``placed``, else
    it transforms each chart as its packing would and leaves it where it is (width =
    height = 1, uv in texels: xatlas's one serial step skipped, the bunny 0.25 s).  The
    charts are the same; a chart's UVs differ from the placed ones by a whole-texel
    translation (and a swap of their axes where packing turned it) and float32 rounding,
    which the layout (``_layout``, its own frame per chart) does not see.
    """
    library = library or charting_library()
    if library == "aobake._xatlas":
        width, height, out = _built_xatlas().chart(
            [(p, len(p), f, len(f)) for p, f in meshes], max_chart_area, texels_per_unit,
            not placed)
        return width, height, [(np.frombuffer(vm, np.uint32), np.frombuffer(fi, np.uint32)
                                .reshape(-1, 3), np.frombuffer(uv, np.float32).reshape(-1, 2))
                               for vm, fi, uv in out]
    import xatlas

    chart_options = xatlas.ChartOptions()
    if max_chart_area:
        chart_options.max_chart_area = max_chart_area
    atlas = xatlas.Atlas()
    for positions, faces in meshes:
        atlas.add_mesh(positions, faces)
    pack = xatlas.PackOptions()
    pack.padding, pack.bilinear, pack.texels_per_unit = 0, False, texels_per_unit
    atlas.generate(chart_options=chart_options, pack_options=pack)
    return atlas.width, atlas.height, [atlas[i] for i in range(len(meshes))]


#: A part is charted again with a larger cap when at least this share of its area is in
#: charts that reached CAP_FULL of the cap (``_cap_share``).
CAP_BINDS, CAP_FULL = 0.6, 0.7


def _cap_share(area, faces) -> float:
    """Share of a part's area (area (p,) float64 per face, in the part's units; faces
    (p, 3) int64 its charted faces) in charts of at least CAP_FULL CHART_FACES: how much
    the cap, not the geometry, ended its charts."""
    chart = connected_labels(int(faces.max()) + 1 if len(faces) else 0, faces)
    per_chart = np.bincount(chart, area)
    total = float(per_chart.sum())
    return float(per_chart[per_chart >= CAP_FULL * CHART_FACES].sum()) / total if total else 0.0


def _xatlas_charts(positions, faces, max_chart_faces: float = CHART_FACES):
    """Chart the mesh with xatlas; each chart's UVs at one texel per normalised unit.

    ``max_chart_faces``: the chart area cap in triangles of the chart's part
    (``chart_cap``); meshes of at most 20 CHART_FACES triangles are charted uncapped.

    Returns (vmapping (m,) int64 into the input vertices, faces (f, 3) int64 over the new
    vertices in input order, uv (m, 2) float64, face_chart (f,) int64, unit): the mesh is
    normalised by ``unit`` (the root mean triangle area), and every chart's UV area equals
    its surface area / unit^2, so a scale s puts s / unit texels on a scene unit everywhere.
    """
    F = np.asarray(faces, dtype=np.int64)
    # xatlas works in float32 with absolute tolerances: recentre on the used vertices'
    # bounding box and scale so the mean triangle area is 1, so the atlas depends on
    # neither where the mesh sits nor its units (a mesh 1e5 from the origin, or 1e-4
    # across, charts like the same mesh at unit size).
    V = np.asarray(positions, dtype=np.float64)
    used_v = V[distinct(F, len(V))]
    lo, hi = used_v.min(axis=0), used_v.max(axis=0)
    V = V - 0.5 * (lo + hi)
    face_area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]),
                                     axis=1)
    area = float(face_area.sum())
    if not area > 0:
        raise InputError("cannot unwrap a mesh whose triangles all have zero area")
    unit = math.sqrt(area / len(F))
    V /= unit
    face_area /= unit * unit

    # One mesh per part, each scaled so that its area-weighted mean triangle area is 1:
    # the chart cap (CHART_FACES units of area) then means about CHART_FACES of the part's
    # own triangles, whatever their size.  (With one unit for the whole mesh, the ogre's
    # coarse body hit the cap with 80-triangle charts while its finely tessellated eyes
    # grew 10,000-triangle ones, slow to chart.)  Weighting the mean by area lets the
    # coarse regions of a part whose tessellation varies grow larger charts.
    parts = _parts(V, F, face_area)
    sizes = []
    for part in parts:
        a = face_area[part]
        sizes.append(math.sqrt(float((a * a).sum() / a.sum())) if a.sum() > 0 else 1.0)
    capped = len(F) > 20 * CHART_FACES  # small meshes chart fast uncapped
    charted = _chart_parts(V, F, parts, sizes, CHART_FACES if capped else None)
    if capped and max_chart_faces > CHART_FACES:
        # A larger cap only makes larger charts where the cap is what stopped them (the
        # bunny: 75% of its area in charts within 70% of the cap); where geometry stops
        # them (the ogre: 36%) xatlas splits what it cannot flatten into more slivers, and
        # is slower for it.  So only the parts whose charts filled the cap are charted again.
        again = [i for i, (part, got) in enumerate(zip(parts, charted))
                 if _cap_share(face_area[part] / sizes[i] ** 2, got[1]) >= CAP_BINDS]
        redone = _chart_parts(V, F, [parts[i] for i in again], [sizes[i] for i in again],
                              max_chart_faces)
        for i, got in zip(again, redone):
            charted[i] = got
        log.debug("charted %d of %d parts again with charts up to %.0f triangles",
                  len(again), len(parts), max_chart_faces)
    vm_list, face_list, uv_list, offset = [], [], [], 0
    for vm, fi, uv in charted:
        vm_list.append(vm)
        face_list.append(fi + offset)
        uv_list.append(uv)
        offset += len(vm)
    vmapping = np.concatenate(vm_list)
    new_faces = np.empty_like(F)
    new_faces[np.concatenate(parts)] = np.concatenate(face_list)
    uv = np.concatenate(uv_list)
    # xatlas never shares a vertex between charts: its charts are the UV islands.
    face_chart = connected_labels(len(uv), new_faces)
    n_charts = int(face_chart.max()) + 1
    # Each chart scaled (about the origin; packing moves it) so its UV area is its surface
    # area: the parts' own scales and xatlas's rounding to whole texels leave no trace in
    # the texel density.  A chart with no UV area keeps its UVs (it covers no texel).
    uv_area = np.bincount(face_chart, _uv_face_areas(uv, new_faces), n_charts)
    surface = np.bincount(face_chart, face_area, n_charts)
    factor = np.where(uv_area > 0, np.sqrt(surface / np.where(uv_area > 0, uv_area, 1.0)), 1.0)
    uv *= factor[_vertex_charts(len(uv), new_faces, face_chart), None]
    log.debug("xatlas charts: %d charts in %d parts", n_charts, len(parts))
    return vmapping, new_faces, uv, face_chart, unit


# --- packing ------------------------------------------------------------------------


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
    vertex_chart = _vertex_charts(len(t), faces, face_chart)
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
    area = float(_uv_face_areas(uv, faces).sum())
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
    vertex_chart = _vertex_charts(len(uv), faces, face_chart)[used]
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


def _better_layout(uv, faces, face_chart, R: int, P: int, chart_image: bool, kernels=None):
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
    from concurrent.futures import ThreadPoolExecutor

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
    vertex_chart = _vertex_charts(len(uv), faces, face_chart)
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


def _layout_at_density(uv, faces, face_chart, scale: float, P: int, chart_image: bool,
                       kernels=None):
    """The smallest square R x R holding every chart at ``scale`` (texels per normalised
    unit, so the texel density is exactly the one asked for).

    The charts' padded texels T bound R from below (R + 2P >= sqrt(T)); strips of that
    width are packed with room below, and the width grown to the geometric mean of the
    width and the rows used until the rows fit in the width (each pack at least 1% wider,
    at most 12 packs).  Returns (uv, scale, image, info, R) as ``_layout``, plus R.
    ``kernels``: the compiled module or None (numpy), as for ``_layout``.
    """
    from aobake.targets.texels.atlas import MAX_RESOLUTION

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


def _packing_kernels(compiled: bool | None):
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


def _xatlas_atlas(positions, faces, resolution, padding, chart_image=False,
                  texel_density=None, compiled: bool | None = None):
    """Chart with xatlas, pack with ``_pack``: (vmapping, faces, uv_xatlas, image or None, info).

    ``uv_xatlas`` is in xatlas's orientation: ``v * height`` is the row counted from the
    FIRST row (the top, as stored), i.e. v runs downwards, opposite to OBJ; ``unwrap`` flips
    it.  Faces come back in input order.  ``info``: the chart count, the estimated coverage
    (texels the charts touch / all texels), the padded footprint over the image
    (``utilization``), the texel density reached (``texels_per_unit``, texels per scene unit
    along the surface, the same in every chart), the packs tried and ``packing_compiled``
    (which packer ran).  ``image`` (``chart_image=True``): (H, W, 3) uint8, each chart's
    texels in its colour.  ``compiled``: mark and pack the charts in the compiled kernels
    (True; default None: when built and not forced off, see ``aobake._native``) or in numpy
    (False, the reference); the atlas is the same bits either way.

    Why it is shaped like this:

    1. Charting: xatlas on parts normalised on their own triangles (``_parts``, chart area
       capped at CHART_FACES triangles' worth: the bunny's 69k triangles chart in ~1.5 s on
       2 cores instead of ~20 s uncapped; larger at a low resolution or a large padding,
       ``chart_cap``).
    2. Each chart scaled to its surface area, so one scale gives one texel density.
    3. Packing (here, not xatlas's: its random placement left 37% of the bunny's image
       empty, like random sequential packing jams): every chart's texels are marked at a
       trial scale, grown by ``padding`` rings, and the grown masks are laid without overlap
       (skyline drop + holes, ``_Packer``), moved by whole texels and quarter turns, so the
       marks hold every texel the rasteriser can cover.  The scale is searched
       for the largest one whose layout fits in R x R, R = min(width, height) (2-4 packs);
       the layout sits in the top-left corner of the image.  It is made twice, of the
       charts as xatlas turned them and of their mirror images, the better kept
       (``_better_layout``).
    4. The marks (``_chart_masks`` from the frame coordinates on: the per-texel tests and
       the growing) and each pack (``_pack_in_order``'s whole loop) run in aobake/_pack.c
       when it was built, step for step as the numpy reference, which stays the fallback
       (tests/test_pack_kernel.py: the same masks, packs, placements, packer state and UVs,
       bit for bit).  The layout (``_layout`` on the same charts, CPU seconds, one thread),
       numpy -> compiled, the atlases identical: the bunny (227 charts) 1024^2 P2 (4 packs)
       1.13 -> 0.15, 1024^2 P8 (2 packs, 70 charts) 0.40 -> 0.07, 512^2 P4 (4) 0.48 -> 0.06;
       the ogre (826 charts) 1024^2 P2 (2) 1.58 -> 0.21, P8 (6) 3.87 -> 0.30, 512^2 P4 (6)
       2.78 -> 0.20.  What is left is ~20 ms per bunny pack, ~9 ms per marking.

    ``resolution`` : N or (width, height); ``texel_density`` (texels per scene unit) or
    None: the charts at exactly that density in the smallest square that holds them
    (``_layout_at_density``; ``resolution`` is then ignored and ``info["width"]``,
    ``info["height"]`` say the size chosen).
    """
    P = int(padding)
    kernels = _packing_kernels(compiled)
    if texel_density is None:
        W, H = (int(resolution), int(resolution)) if np.ndim(resolution) == 0 \
            else map(int, resolution)
        R = min(W, H)
        cap = chart_cap(R, P)
    else:
        # the charts' size follows the texels per triangle: the image side at about the
        # first pack's efficiency (the surface area in texels over FIRST_EFFICIENCY)
        p = np.asarray(positions, np.float64)[np.asarray(faces)]
        area = 0.5 * float(np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]),
                                          axis=1).sum())
        cap = chart_cap(max(1, int(texel_density * math.sqrt(area / FIRST_EFFICIENCY))), P)
    vmapping, new_faces, uv_a, face_chart, unit = _xatlas_charts(positions, faces, cap)
    if texel_density is None:
        uv, scale, image, info = _better_layout(uv_a, new_faces, face_chart, R, P,
                                                chart_image, kernels)
    else:
        uv, scale, image, info, R = _layout_at_density(uv_a, new_faces, face_chart,
                                                       float(texel_density) * unit, P,
                                                       chart_image, kernels)
        W = H = R
    info["packing_compiled"] = kernels is not None
    info["charting"] = charting_library()
    info["width"], info["height"] = W, H
    if image is not None:
        full = np.zeros((H, W, 3), np.uint8)
        full[:R, :R] = image
        image = full
    info["coverage"] *= R * R / (W * H)
    info["utilization"] *= (R + 2 * P) ** 2 / (W * H)
    info["texels_per_unit"] = scale / unit
    return vmapping, new_faces, uv / [W, H], image, info


def _unwrap_in_process(positions, faces, resolution, padding, texel_density=None,
                       compiled: bool | None = None) -> tuple[Unwrapped, dict]:
    vmapping, new_faces, uv, _, info = _xatlas_atlas(positions, faces, resolution, padding,
                                                     texel_density=texel_density,
                                                     compiled=compiled)
    # The packed v runs down the image (row 0 first, as xatlas's); OBJ's v runs up.
    # Flipping keeps texel boundaries on texel boundaries because resolution is
    # integral, so the texel grid the charts were packed on (and its padding) is kept.
    uv[:, 1] = 1.0 - uv[:, 1]
    return Unwrapped(vmapping, new_faces, uv, size=(info["width"], info["height"]),
                     packing_compiled=info["packing_compiled"], charting=info["charting"]), info


def _unwrap_worker(argv: list[str]) -> None:
    """Entry point of the isolated xatlas process: ``in.npz out.npz``.  ``compiled`` in
    in.npz is the parent's decision (its ``_native.numpy_only`` is thread-local and does not
    reach this process); absent: this process's default."""
    with np.load(argv[0]) as data:
        density = float(data["texel_density"]) if "texel_density" in data else 0.0
        compiled = bool(data["compiled"]) if "compiled" in data else None
        result, info = _unwrap_in_process(
            data["positions"], data["faces"], tuple(int(x) for x in data["resolution"]),
            int(data["padding"]), density if density > 0 else None, compiled
        )
    np.savez(argv[1], vmapping=result.vmapping, faces=result.faces, uv=result.uv,
             **{key: info[key] for key in _INFO})


#: what the child reports besides the atlas (see ``_xatlas_atlas``)
_INFO = {"charts": int, "coverage": float, "utilization": float, "texels_per_unit": float,
         "packs": int, "width": int, "height": int, "packing_compiled": bool, "charting": str}


#: time limit of one xatlas child process: base + per triangle (the bunny's 69k
#: triangles take ~3 s on 2 cores; the limit is generous because xatlas's thread
#: pool has been seen to deadlock, which only the time limit catches).
XATLAS_TIMEOUT_BASE_S = 120.0
XATLAS_TIMEOUT_PER_FACE_S = 2e-3

# The child imports this module and runs the worker; kept as data so tests can
# swap in a crashing stand-in.  ``_child`` starts it with aobake.child's prelude, which puts
# this process's package first on the child's path (not the current directory).  The
# packages above it are stubs (their __path__ only): their __init__ modules import the whole
# baker, 0.2 s of the child's start, which is on the bake's critical path.
_WORKER_CODE = """
import importlib.util, sys, types
for name in ("aobake", "aobake.targets", "aobake.targets.texels"):
    stub = types.ModuleType(name)
    stub.__path__ = importlib.util.find_spec(name).submodule_search_locations
    sys.modules[name] = stub
from aobake.targets.texels.unwrap import _unwrap_worker
_unwrap_worker(sys.argv[1:])
"""
# A prestarted child (``prestart``): the same imports, then it waits for its two paths on
# a line of standard input (none: the parent did not need it, or is gone).
_WARM_CODE = _WORKER_CODE.replace("_unwrap_worker(sys.argv[1:])", """import json
from aobake.targets.texels.unwrap import charting_library
if charting_library() == "xatlas":
    import xatlas
line = sys.stdin.readline()
if line:
    _unwrap_worker(json.loads(line))
""")


def _child(code: str, args=()) -> tuple[list[str], dict]:
    """argv and environment of an xatlas child running ``code``: it imports the same aobake
    as this process (``aobake.child``: not the current directory's, such as a checkout's
    source tree without compiled kernels when the installed aobake runs from its root)."""
    argv, env = python_child(code, args)
    # glibc: reuse freed memory rather than fault fresh pages in (see aobake.cli's
    # _keep_freed_memory): the child's own process, so its allocator is ours to tune
    env.setdefault("MALLOC_MMAP_THRESHOLD_", str(32 << 20))
    env.setdefault("MALLOC_TRIM_THRESHOLD_", str(2**31 - 1))
    return argv, env


_prestarted_lock = threading.Lock()
_prestarted: subprocess.Popen | None = None


def prestart() -> None:
    """Start the xatlas child now, before the mesh is read, so that its interpreter start
    and imports (~0.15 s) overlap the loading instead of delaying the unwrap; the next
    ``unwrap`` in this process hands it its job.  At most one waits.  For a command that
    will probably unwrap (aobake's CLI making a lightmap); ``discard_prestarted`` ends it
    when the mesh's own UVs are baked."""
    global _prestarted
    with _prestarted_lock:
        if _prestarted is not None and _prestarted.poll() is None:
            return
        _reap(_prestarted)
        try:
            argv, env = _child(_WARM_CODE)
            _prestarted = subprocess.Popen(argv, env=env, stdin=subprocess.PIPE,
                                           stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                           text=True)
        except OSError as exc:  # only a head start: the unwrap starts its own child
            _prestarted = None
            log.debug("could not prestart the xatlas child: %s", exc)


def _reap(proc: subprocess.Popen | None) -> None:
    """End ``proc`` (if still running) and close its pipes."""
    if proc is not None:
        if proc.poll() is None:
            proc.kill()
        proc.communicate()


def _take_prestarted() -> subprocess.Popen | None:
    global _prestarted
    with _prestarted_lock:
        proc, _prestarted = _prestarted, None
    if proc is not None and proc.poll() is not None:  # died while waiting: not usable
        _reap(proc)
        return None
    return proc


def discard_prestarted() -> None:
    """End a prestarted child that no unwrap will use."""
    _reap(_take_prestarted())


def _run_child(src: Path, dst: Path, limit: float) -> subprocess.CompletedProcess:
    """The job in the prestarted child if there is one, else in a new one (either is killed
    after ``limit`` seconds, subprocess.TimeoutExpired, or on any exception here, such as
    the CLI's SIGTERM).  A prestarted child that fails (killed while it waited, say) hands
    the job to a new one: its failure says nothing about the mesh."""
    proc = _take_prestarted()
    if proc is not None:
        try:
            out, err = proc.communicate(json.dumps([str(src), str(dst)]) + "\n", timeout=limit)
        except BaseException:
            _reap(proc)
            raise
        if proc.returncode == 0 and dst.is_file():
            return subprocess.CompletedProcess(proc.args, 0, out, err)
        log.debug("the prestarted xatlas child failed (exit %s): a new one takes the job",
                  proc.returncode)
    argv, env = _child(_WORKER_CODE, (src, dst))
    return subprocess.run(argv, env=env, capture_output=True, text=True, timeout=limit)


def _unwrap_isolated(positions, faces, resolution, padding, texel_density=None,
                     compiled: bool | None = None) -> tuple[Unwrapped, dict]:
    # xatlas segfaults on some inputs (for example finely subdivided
    # icospheres, jpcy/xatlas#146); in a child process that becomes an error
    # message instead of killing the caller.
    # Which packer runs is decided here, on the caller's thread (``numpy_only`` is
    # thread-local), and handed to the child explicitly.
    compiled = _packing_kernels(compiled) is not None
    with tempfile.TemporaryDirectory(prefix="aobake-xatlas-") as tmp:
        src, dst = Path(tmp, "in.npz"), Path(tmp, "out.npz")
        np.savez(src, positions=positions, faces=faces, resolution=resolution, padding=padding,
                 texel_density=texel_density or 0.0,  # 0: none
                 compiled=bool(compiled))
        # xatlas's own thread pool has been seen to deadlock now and then (all
        # threads in futex waits, no CPU); a child that outlives a generous limit
        # is killed and the unwrap tried once more before giving up.
        limit = XATLAS_TIMEOUT_BASE_S + XATLAS_TIMEOUT_PER_FACE_S * len(faces)
        for attempt in (1, 2):
            try:
                proc = _run_child(src, dst, limit)
                break
            except subprocess.TimeoutExpired:
                log.warning("xatlas did not finish in %.0f s (attempt %d of 2)", limit, attempt)
        else:
            raise InputError(f"xatlas did not finish unwrapping {len(faces)} triangles in "
                             f"{limit:.0f} s, twice; provide your own UVs")
        if proc.returncode < 0:
            try:
                how = f"crashed with {signal.Signals(-proc.returncode).name}"
            except ValueError:
                how = f"was killed by signal {-proc.returncode}"
            raise InputError(
                f"xatlas {how} while unwrapping a mesh of {len(faces)} triangles; "
                "very regular meshes such as finely subdivided icospheres are known to crash it "
                "(jpcy/xatlas#146): provide your own UVs or perturb the mesh"
            )
        if proc.returncode != 0:
            last = proc.stderr.strip().splitlines()[-1:] or [f"exit status {proc.returncode}"]
            message = last[0].split("InputError: ", 1)[-1]  # the child's own message, not its type
            raise InputError(f"unwrapping a mesh of {len(faces)} triangles failed: {message}")
        with np.load(dst) as data:
            info = {key: kind(data[key]) for key, kind in _INFO.items()}
            return Unwrapped(data["vmapping"], data["faces"], data["uv"],
                             size=(info["width"], info["height"]),
                             packing_compiled=info["packing_compiled"],
                             charting=info["charting"]), info


def unwrap(positions, faces, resolution, padding: int, *, isolate: bool = True,
           texel_density: float | None = None, compiled: bool | None = None) -> Unwrapped:
    """Make a fresh, non-overlapping UV atlas with xatlas.

    positions : (n, 3) float; faces : (f, 3) int.
    resolution : N (square) or (width, height) of the target image in texels; the
        charts are packed into the top-left min(width, height) square.
    padding : empty texels kept around each chart.  Two charts' covered texels
        (any texel a triangle overlaps) end up at least ``2 * padding`` empty
        texels apart (8-neighbour rings), so dilating each chart by ``padding``
        rings (``aobake.post.dilate``) never mixes two charts.
    isolate : run xatlas in a child Python process so that an xatlas crash
        raises InputError instead of killing this process (costs ~0.3 s).
    texel_density : None, or texels per scene unit along the surface: every chart at
        exactly this density in the smallest square image that holds them (``resolution``
        is then ignored; ``Unwrapped.size`` is the size chosen).
    compiled : mark and pack the charts in the compiled kernels (True), in numpy (False), or
        (None) when built and not forced off on this thread (``aobake._native``); the atlas
        is the same bits either way and ``Unwrapped.packing_compiled`` says which ran.

    Returns ``Unwrapped(vmapping (m,) int64, faces (f, 3) int64, uv (m, 2)
    float64, charts, size (width, height), packing_compiled)``: new vertex ``i`` sits at ``positions[vmapping[i]]``; uv is in
    [0, 1] in the OBJ convention (v = 0 at the bottom), charts aligned to the
    ``resolution`` texel grid, every chart at the same texel density (its UV area
    over its surface area is the same in all charts).
    """
    positions = np.asarray(positions, dtype=np.float64)
    faces = np.asarray(faces)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise ValueError(f"positions must be (n, 3), got {positions.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"faces must be (f, 3) integers, got {faces.shape} {faces.dtype}")
    if len(faces) == 0:
        raise InputError("cannot unwrap a mesh without triangles")
    if faces.min() < 0 or faces.max() >= len(positions):
        raise ValueError(f"faces index vertices outside 0..{len(positions) - 1}")
    size = (resolution, resolution) if np.ndim(resolution) == 0 else tuple(resolution)
    if len(size) != 2 or any(int(x) != x or x < 1 for x in size):
        raise ValueError(f"resolution must be a positive integer or two, got {resolution}")
    width, height = (int(x) for x in size)
    if int(padding) != padding or padding < 0:
        raise ValueError(f"padding must be a non-negative integer, got {padding}")
    if texel_density is not None and not (math.isfinite(texel_density) and texel_density > 0):
        raise ValueError(f"texel density must be a positive number, got {texel_density}")
    start = time.perf_counter()
    run = _unwrap_isolated if isolate else _unwrap_in_process
    result, info = run(positions, faces.astype(np.int64), (width, height), int(padding),
                       texel_density, compiled)
    width, height = info["width"], info["height"]
    log.info(
        "unwrapped %d triangles into %dx%d texels in %.1f s (%d packs): %d charts covering "
        "%.0f%% of the texels (%.0f%% with padding), %.4g texels per unit, %d -> %d vertices",
        len(faces), width, height, time.perf_counter() - start, info["packs"], info["charts"],
        100 * info["coverage"], 100 * info["utilization"], info["texels_per_unit"],
        len(positions), len(result.vmapping),
    )
    return result._replace(charts=int(info["charts"]))
