"""Charting for fresh UV atlases: xatlas cuts the mesh into charts and flattens them.

The mesh is normalised (recentred, scaled to a mean triangle area of 1) and split into
parts (``_parts``) that xatlas charts side by side, each with a chart area cap
(``chart_cap``); every chart is then scaled so its UV area equals its surface area
(``chart_mesh``), so one scale gives one texel density everywhere.  The charts are laid out
by ``aobake.targets.texels.packing``; ``aobake.targets.texels.unwrap`` runs both, in a
child process.  Also the UV islands of any UVs (``connected_labels``, ``uv_islands``) and
their texel densities (``chart_texel_density``).
"""

from __future__ import annotations

import logging
import math

import numpy as np

from aobake.errors import InputError
from aobake.vectors import distinct, weld

log = logging.getLogger(__name__)

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


def uv_face_areas(uv: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(f,) float64 area of each face in UV units: uv (t, 2) float64, faces (f, 3) int."""
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
    texel_area = uv_face_areas(np.asarray(uv, np.float64) * [width, height], faces_uv)
    p = np.asarray(positions, np.float64)[faces]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    k = int(labels.max()) + 1 if len(labels) else 0
    a2, a3 = np.bincount(labels, texel_area, k), np.bincount(labels, area, k)
    keep = a3 > 0
    return np.sqrt(a2[keep] / a3[keep])


def vertex_charts(n: int, faces, face_chart) -> np.ndarray:
    """(n,) int64 chart of each vertex (charts share no vertex; unused vertices: 0)."""
    vertex_chart = np.zeros(n, np.int64)
    vertex_chart[faces.ravel()] = np.repeat(face_chart, 3)
    return vertex_chart


def _parts(vertices, faces, face_area) -> list[np.ndarray]:
    """Faces grouped into the meshes given to xatlas (each charted on its own thread).

    Connected pieces (vertices at the same position count as one) are grouped in order of
    their mean triangle area while the sizes agree within GROUP_SIZE_RATIO and the group
    stays under PART_FACES triangles; a piece larger than that is median-split in space.
    Each part is normalised on its own triangles (``chart_mesh``), so a finely
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
    which the layout (``packing._layout``, its own frame per chart) does not see.
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


def collapsed_faces(uv, faces, face_chart, face_uv_area=None) -> np.ndarray:
    """(f,) bool the faces of UV islands without UV area: in an xatlas atlas, the faces it
    charted nowhere (``attach_collapsed``).  uv (m, 2), faces (f, 3), face_chart (f,);
    face_uv_area: ``uv_face_areas(uv, faces)`` when already made."""
    if face_uv_area is None:
        face_uv_area = uv_face_areas(uv, faces)
    n_charts = int(face_chart.max()) + 1 if len(face_chart) else 0
    return np.bincount(face_chart, face_uv_area, n_charts)[face_chart] == 0


def _plane_frame(p: np.ndarray) -> np.ndarray:
    """(3, 2) float64 the corners p (3, 3) of a triangle with area in an orthonormal frame
    of its plane: x along its longest edge from that edge's first corner."""
    k = int(np.argmax(np.linalg.norm(p - np.roll(p, -1, axis=0), axis=1)))
    p = np.roll(p, -k, axis=0)
    e1 = p[1] - p[0]
    e1 /= np.linalg.norm(e1)
    n = np.cross(p[1] - p[0], p[2] - p[0])
    e2 = np.cross(n / np.linalg.norm(n), e1)
    flat = np.stack([(p - p[0]) @ e1, (p - p[0]) @ e2], axis=1)
    return np.roll(flat, k, axis=0)


def attach_collapsed(positions, face_area, vmapping, faces, uv, face_chart, face_uv_area=None):
    """The faces xatlas charts nowhere, placed in a neighbour's chart.

    xatlas leaves out of its charts every face it will not flatten: one whose float32 area
    is at most FLT_EPSILON in its units (here the part's area-weighted mean triangle area,
    ``chart_mesh``: a triangle below 1.2e-7 of it, such as the tiny triangles of a finely
    tessellated spot or a short sliver), one with an edge of float32 length 0, and one of
    no area at all (the ogre has four: three corners on one line, at T-junctions).  It hands them back at UV (0, 0), every corner,
    sharing vertices only among themselves.  Packed as they came, each was a chart of one
    point: a texel reserved for it that no sample reaches (no UV area), outside every
    chart, so a lookup on the face read whatever the gutter was filled with (the ogre's
    four zero-area faces at 1024^2, 64 rays: 0.81, 0.84, 0.00 and 0.78 where their
    neighbours read 0.18, 0.22, 0.09 and 0.17; now 0.21, 0.23, 0.07 and 0.15 against 0.20, 0.23,
    0.07 and 0.15).

    Each such face now joins the chart that holds most of its corners (a vertex of the
    chart at the same welded position; the first chart on a tie), taking that chart's
    vertices there (copied when the chart's vertex is another input vertex at that place,
    so ``vmapping[faces]`` stays the input faces).  A corner the chart lacks gets the UV
    that the 3-D -> UV map of the chart's largest face at another of its corners gives it
    (the affine map of that face, least squares in its plane).  So the face's UV triangle
    lies in its neighbours' parameterisation, packing marks its texels with the chart's
    (``packing._chart_masks`` marks a triangle of no UV area along its segment), and its
    lookups read the texels of the surface around it.  A face that touches no chart yet
    waits for its neighbours to attach (their new vertices count); one that touches none
    at all and has surface area starts a chart of its own, flat in its plane (scaled to
    its area like every chart: a fraction of a texel, whose texel the rasteriser's
    fallback sample gives its value), which the faces around it then join.  A face of no
    area that touches no chart keeps its point.

    positions : (v, 3) float64 input positions; face_area : (f,) float64 their areas;
    vmapping (m,) int64, faces (f, 3) int64, uv (m, 2) float64, face_chart (f,) int64 as
    in ``chart_mesh``; face_uv_area: ``uv_face_areas(uv, faces)`` when already made.
    Returns (vmapping, faces, uv, face_chart), vertices no face uses dropped and charts
    numbered in order of their first face; the inputs themselves when no face is collapsed.
    """
    collapsed = collapsed_faces(uv, faces, face_chart, face_uv_area)
    if not collapsed.any():
        return vmapping, faces, uv, face_chart
    positions = np.asarray(positions, dtype=np.float64)
    faces, face_chart = faces.copy(), face_chart.copy()
    # The places (exact positions) of the collapsed faces' corners, and the input vertices
    # at them: only those are looked up (welding the whole mesh cost the ogre 30 ms).
    spots = np.unique(positions[vmapping[faces[collapsed]]].reshape(-1, 3), axis=0)
    label = {tuple(p): i for i, p in enumerate(spots.tolist())}
    near = np.flatnonzero(np.isin(positions[:, 0], spots[:, 0]))
    place = {int(v): label[tuple(p)] for v, p in zip(near.tolist(), positions[near].tolist())
             if tuple(p) in label}  # input vertex -> its place
    # where those places are in the charts: place -> chart -> vertices, and each such
    # vertex's charted faces (for its 3-D -> UV map)
    charted = np.flatnonzero(~collapsed)
    at_place = np.zeros(len(positions), dtype=bool)
    at_place[list(place)] = True
    corner_v = faces[charted].reshape(-1)
    keep = at_place[vmapping[corner_v]]
    corner_v, corner_f = corner_v[keep], np.repeat(charted, 3)[keep]
    at: dict = {}
    faces_at: dict = {}
    for v, f in sorted(zip(corner_v.tolist(), corner_f.tolist())):
        by_chart = at.setdefault(place[int(vmapping[v])], {}).setdefault(int(face_chart[f]), [])
        if not by_chart or by_chart[-1] != v:
            by_chart.append(v)
        faces_at.setdefault(v, []).append(f)
    m = len(vmapping)
    extra_vm, extra_uv = [], []  # vertices added after the m of xatlas

    def source_of(v):
        return int(vmapping[v]) if v < m else extra_vm[v - m]

    def uv_of(v):
        return uv[v] if v < m else extra_uv[v - m]

    maps: dict = {}  # vertex -> (2, 3) its chart's 3-D -> UV map near it

    def uv_map(v):
        if v not in maps:
            f = max(faces_at[v], key=lambda g: (face_area[g], -g))
            x = positions[[source_of(i) for i in faces[f]]]
            t = np.array([uv_of(i) for i in faces[f]])
            e, d = (x[1:] - x[0]).T, (t[1:] - t[0]).T  # (3, 2), (2, 2)
            maps[v] = d @ np.linalg.pinv(e)
        return maps[v]

    def add(source, where, chart, jacobian):
        extra_vm.append(int(source))
        extra_uv.append(np.asarray(where, dtype=np.float64))
        v = m + len(extra_vm) - 1
        at.setdefault(place[int(source)], {}).setdefault(chart, []).append(v)
        if jacobian is not None:
            maps[v] = jacobian
        return v

    n_charts = int(face_chart.max()) + 1
    pending = np.flatnonzero(collapsed).tolist()
    while pending:
        left = []
        for f in pending:
            source = [source_of(v) for v in faces[f]]
            spot = [at.get(place[s], {}) for s in source]
            votes: dict = {}
            for charts_there in spot:
                for chart in charts_there:
                    votes[chart] = votes.get(chart, 0) + 1
            if not votes:
                left.append(f)
                continue
            host = min(votes, key=lambda c: (-votes[c], c))
            corners = [None] * 3
            for j in range(3):
                if host in spot[j]:
                    there = spot[j][host]
                    same = [v for v in there if source_of(v) == source[j]]
                    corners[j] = same[0] if same else add(source[j], uv_of(there[0]), host,
                                                          uv_map(there[0]))
            ref = next(j for j in range(3) if corners[j] is not None)
            for j in range(3):
                if corners[j] is None:
                    jac = uv_map(corners[ref])
                    where = uv_of(corners[ref]) + jac @ (positions[source[j]]
                                                         - positions[source[ref]])
                    corners[j] = add(source[j], where, host, jac)
            faces[f] = corners
            face_chart[f] = host
        if len(left) == len(pending):  # nothing attached: a face with area starts a chart
            first = next((f for f in left if face_area[f] > 0), None)
            if first is None:
                break  # faces of no area, touching no chart: they keep their point
            source = [source_of(v) for v in faces[first]]
            flat = _plane_frame(positions[source])
            corners = [add(s, t, n_charts, None) for s, t in zip(source, flat)]
            faces[first], face_chart[first] = corners, n_charts
            for v in corners:
                faces_at[v] = [first]  # its map, when asked, is the face's own
            n_charts += 1
            left.remove(first)
        pending = left
    vmapping = np.concatenate([vmapping, np.array(extra_vm, dtype=np.int64)])
    uv = np.concatenate([uv, np.array(extra_uv, dtype=np.float64).reshape(-1, 2)])
    used = distinct(faces, len(vmapping))
    renumber = np.full(len(vmapping), -1, dtype=np.int64)
    renumber[used] = np.arange(len(used))
    _, first, inverse = np.unique(face_chart, return_index=True, return_inverse=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    log.debug("%d faces xatlas charted nowhere placed in a neighbour's chart (%d vertices "
              "added)", int(np.count_nonzero(collapsed)), len(extra_vm))
    return vmapping[used], renumber[faces], uv[used], rank[inverse.ravel()]


def chart_mesh(positions, faces, max_chart_faces: float = CHART_FACES):
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
    # ... but for the faces it charts nowhere, all at UV (0, 0): they join a neighbour's chart
    face_uv_area = uv_face_areas(uv, new_faces)
    attached = attach_collapsed(V, face_area, vmapping, new_faces, uv, face_chart, face_uv_area)
    if attached[1] is not new_faces:
        vmapping, new_faces, uv, face_chart = attached
        face_uv_area = uv_face_areas(uv, new_faces)
    n_charts = int(face_chart.max()) + 1
    # Each chart scaled (about the origin; packing moves it) so its UV area is its surface
    # area: the parts' own scales and xatlas's rounding to whole texels leave no trace in
    # the texel density.  A chart with no UV area keeps its UVs (it covers no texel: only
    # faces of no surface area that no chart could take, ``attach_collapsed``).
    uv_area = np.bincount(face_chart, face_uv_area, n_charts)
    surface = np.bincount(face_chart, face_area, n_charts)
    factor = np.where(uv_area > 0, np.sqrt(surface / np.where(uv_area > 0, uv_area, 1.0)), 1.0)
    uv *= factor[vertex_charts(len(uv), new_faces, face_chart), None]
    log.debug("xatlas charts: %d charts in %d parts", n_charts, len(parts))
    return vmapping, new_faces, uv, face_chart, unit
