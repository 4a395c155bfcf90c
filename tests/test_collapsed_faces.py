"""Faces whose UVs collapse (issue 35, point 3): every face with surface area gets a texel
footprint inside a chart on a new atlas (xatlas charts tiny faces nowhere: they join a
neighbour's chart, ``charts.attach_collapsed``), and own UVs with faces collapsed to a point
are reported and baked (``uvcheck.bake_collapsed``).  Generated meshes only."""

import numpy as np
import pytest
import trimesh

from aobake import bake_texels
from aobake.targets.texels import charts
from aobake.targets.texels.charts import chart_mesh, collapsed_faces, uv_face_areas
from aobake.targets.texels.raster import rasterize
from aobake.targets.texels.seams import bilinear, degenerate_faces
from aobake.targets.texels.unwrap import unwrap
from aobake.targets.texels.uvcheck import check_uvs

#: the tiny triangles' size, in units of the floor's cells (0.25): their area, about 1e-9
#: against the floor's 0.03 a triangle, is below xatlas's FLT_EPSILON of its mean
EPS = 3e-5


def _grid(n, size):
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    vertices = np.stack([i * size / n - size / 2, j * size / n - size / 2,
                         np.zeros(i.shape)], -1).reshape(-1, 3)

    def idx(a, b):
        return a * (n + 1) + b

    faces = []
    for a in range(n):
        for b in range(n):
            faces += [(idx(a, b), idx(a + 1, b), idx(a + 1, b + 1)),
                      (idx(a, b), idx(a + 1, b + 1), idx(a, b + 1))]
    return list(map(tuple, vertices)), faces, idx


def _truncate(vertices, faces, centre, ring, eps, flat=None):
    """Vertex ``centre`` (``ring``: its six neighbours, counter-clockwise) replaced by a
    tiny triangle of size ``eps`` (``flat``: a sliver, its middle corner ``flat`` eps off
    the line of the other two), joined to the ring by nine triangles.  Returns the tiny
    triangle's three vertex indices."""
    faces[:] = [f for f in faces if centre not in f]
    p = np.array(vertices[centre])

    def towards(k):
        d = np.array(vertices[ring[k]]) - p
        return d / np.linalg.norm(d)

    if flat is None:
        inner = [p + eps * towards(0), p + eps * towards(2), p + eps * towards(4)]
    else:
        a = towards(0)
        across = np.array([-a[1], a[0], 0.0])
        inner = [p + eps * a, p + eps * (0.3 * a + flat * across), p - eps * a]
    base = len(vertices)
    vertices += [tuple(x) for x in inner]
    v = [base, base + 1, base + 2]
    for k in range(3):
        n0, n1, n2 = ring[2 * k], ring[2 * k + 1], ring[(2 * k + 2) % 6]
        faces += [(v[k], n0, n1), (v[k], n1, v[(k + 1) % 3]), (v[(k + 1) % 3], n1, n2)]
    faces.append(tuple(v))
    return tuple(v)


def tiny_faces_scene():
    """A floor (4 x 4, 16 x 16 cells) with a box standing on it, so AO varies over it, and
    on the floor: two tiny triangles (sides ~EPS, where a vertex was), a tiny sliver (its
    height 1% of its length) and, as on the ogre, a face of no area at a T-junction (three
    corners on one line).  xatlas charts all four nowhere.  Returns (mesh, tiny face
    indices (3,), the zero-area face's index)."""
    vertices, faces, idx = _grid(16, 4.0)
    tiny = []
    for (a, b), flat in (((5, 6), None), ((10, 9), None), ((7, 11), 1e-2)):
        ring = [idx(a + 1, b), idx(a + 1, b + 1), idx(a, b + 1), idx(a - 1, b),
                idx(a - 1, b - 1), idx(a, b - 1)]
        tiny.append(_truncate(vertices, faces, idx(a, b), ring, EPS, flat))
    # the T-junction: (A, C, D) against (E, C, B) and (E, B, A), B the midpoint of AC, and
    # the face (A, B, C) of no area between them
    a, c, e = idx(12, 4), idx(13, 4), idx(12, 3)
    vertices.append(tuple(0.5 * (np.array(vertices[a]) + np.array(vertices[c]))))
    b = len(vertices) - 1
    faces.remove((e, c, a))
    faces += [(e, c, b), (e, b, a), (a, b, c)]
    box = trimesh.creation.box(extents=[0.6, 0.6, 0.8])
    box.apply_translation([0.0, 0.0, 0.4])
    floor = trimesh.Trimesh(np.array(vertices), np.array(faces), process=False)
    mesh = trimesh.util.concatenate([floor, box])
    rows = [int(np.flatnonzero((mesh.faces == t).all(axis=1))[0]) for t in tiny]
    zero = int(np.flatnonzero((mesh.faces == (a, b, c)).all(axis=1))[0])
    return mesh, np.array(rows), zero


@pytest.fixture(scope="module")
def scene():
    return tiny_faces_scene()


def test_the_scene_is_what_it_says(scene):
    mesh, tiny, zero = scene
    p = mesh.vertices[mesh.faces]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    up = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:len(mesh.faces) - 12, 2]
    assert np.all(np.delete(up, zero) > 0)  # the floor faces up, every face the same way
    assert np.all(area[tiny] > 0) and np.all(area[tiny] < 1e-7 * np.median(area))
    assert not degenerate_faces(mesh.vertices, mesh.faces)[tiny].any()  # they have area
    assert area[zero] == 0 and degenerate_faces(mesh.vertices, mesh.faces)[zero]


def test_xatlas_charts_the_tiny_faces_nowhere(scene, monkeypatch):
    """What the fix is about: xatlas hands the faces it will not flatten back at UV (0, 0),
    each in an island of its own."""
    mesh, tiny, zero = scene
    monkeypatch.setattr(charts, "attach_collapsed",
                        lambda p, a, vm, f, uv, fc, fa=None: (vm, f, uv, fc))
    _, faces, uv, face_chart, _ = chart_mesh(mesh.vertices, mesh.faces)
    collapsed = collapsed_faces(uv, faces, face_chart)
    assert set(np.flatnonzero(collapsed)) == set(tiny) | {zero}


def test_faces_charted_nowhere_join_a_neighbours_chart(scene):
    """Each shares its chart with the faces around it (no island of its own, none without
    UV area), and the atlas still maps back to the input faces."""
    mesh, tiny, zero = scene
    vmapping, faces, uv, face_chart, _ = chart_mesh(mesh.vertices, mesh.faces)
    np.testing.assert_array_equal(vmapping[faces], mesh.faces)
    assert not collapsed_faces(uv, faces, face_chart).any()
    for f in [*tiny, zero]:
        assert np.count_nonzero(face_chart == face_chart[f]) > 100
    assert len(np.unique(faces)) == len(uv)  # no vertex left over


def _footprint_covered(un, size):
    """(f,) bool: the texel under each face's UV centroid holds samples of the surface."""
    samples = rasterize(un.uv, un.faces, size, size, texel_samples=4)
    centroid = un.uv[un.faces].mean(axis=1)
    col = np.clip(np.floor(centroid[:, 0] * size), 0, size - 1).astype(int)
    row = np.clip(np.floor((1 - centroid[:, 1]) * size), 0, size - 1).astype(int)
    return samples.coverage[row, col] > 0


@pytest.mark.parametrize("size", [64, 256])
def test_every_face_with_area_has_a_footprint_inside_a_chart(scene, size):
    """On the new atlas, the texel under every face with area (and under the zero-area one)
    is covered by the surface; before, the four read texels no sample reached, outside
    every chart."""
    mesh, tiny, zero = scene
    un = unwrap(mesh.vertices, mesh.faces, size, 2, isolate=False)
    covered = _footprint_covered(un, size)
    assert covered.all(), np.flatnonzero(~covered)
    # the footprint: their UV triangles lie in their neighbours' parameterisation, a
    # fraction of a texel across (not a stray point)
    texels = uv_face_areas(un.uv * size, un.faces)
    assert np.all(texels[tiny] < 1e-3)
    assert check_uvs(un.uv, un.faces, size, size).valid


@pytest.mark.slow
def test_lookups_on_the_tiny_faces_read_their_neighbours(scene):
    """The baked map read at each tiny face and at the zero-area one (bilinear at its UV
    centroid) agrees with the map read at the same vertices from the faces around it,
    within 4 of their combined standard errors; before, each read a lone uncovered texel
    (here 0.99 where the neighbours read 0.79; on the ogre 0.81 against 0.18)."""
    mesh, tiny, zero = scene
    result = bake_texels(mesh, resolution=64, rays=256, texel_samples=4, padding=2,
                         unwrap="always", quantities=("ao",), seed=3)
    atlas = result.atlas
    ao, se = result.channels["ao"], result.channels["ao_stderr"]
    source = atlas.source_vertex[atlas.faces]  # (f, 3) input vertex of each corner
    np.testing.assert_array_equal(source, mesh.faces)
    values = []
    for f in [*tiny, zero]:
        at = atlas.uv[atlas.faces[f]].mean(axis=0)[None]
        mine, mine_se = bilinear(ao, at)[0], bilinear(se, at)[0]
        near = np.flatnonzero(np.isin(source, source[f]).any(axis=1))
        near = near[near != f]
        corners = [atlas.uv[atlas.faces[g][np.isin(source[g], source[f])]] for g in near]
        points = np.concatenate(corners)
        theirs, theirs_se = bilinear(ao, points).mean(), bilinear(se, points).mean()
        assert abs(mine - theirs) <= 4 * np.hypot(mine_se, theirs_se) + 1e-6, \
            (f, mine, theirs, mine_se, theirs_se)
        values.append(mine)
    assert 0.05 < min(values) and max(values) < 0.98  # the box shades them


# --- own UVs ---------------------------------------------------------------------------


def _obj(path, vertices, faces, corner_uv):
    """OBJ of ``vertices`` (v, 3), ``faces`` (f, 3) and one UV per corner (f, 3, 2)."""
    lines = [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in vertices]
    lines += [f"vt {u:.17g} {v:.17g}" for u, v in corner_uv.reshape(-1, 2)]
    lines += ["f " + " ".join(f"{i + 1}/{3 * k + j + 1}" for j, i in enumerate(tri))
              for k, tri in enumerate(faces)]
    path.write_text("\n".join(lines) + "\n")
    return path


def own_uv_floor(path, n=12):
    """A floor (12 x 12 cells over [-1, 1]^2) under a plate that shades part of it, its
    UVs planar in [0.05, 0.55] x [0.05, 0.95], and four of its faces (with area) collapsed
    to a point, their three UVs at one spot: two on the chart (at their first corner's UV)
    and a quad's two triangles off every chart, at (0.8, 0.5), clear of it.  The plate has
    a UV island per triangle along the top.  Returns (path, vertices, faces, corner UVs
    (f, 3, 2), the faces collapsed onto the chart, the faces collapsed off it)."""
    vertices, faces, _ = _grid(n, 2.0)
    vertices, faces = np.array(vertices), np.array(faces)
    uv = np.stack([0.05 + 0.25 * (vertices[:, 0] + 1), 0.05 + 0.45 * (vertices[:, 1] + 1)], 1)
    corner_uv = uv[faces]
    on_chart = [2 * (3 * n + 3), 2 * (5 * n + 8) + 1]  # quads (3, 3) and (5, 8)
    off_chart = [2 * (8 * n + 2), 2 * (8 * n + 2) + 1]  # quad (8, 2)
    for f in on_chart:
        corner_uv[f] = corner_uv[f, 0]
    corner_uv[off_chart] = (0.8, 0.5)
    plate = trimesh.creation.box(extents=[1.2, 0.8, 0.05])
    plate.apply_translation([0.2, 0.3, 0.3])
    u0 = 0.6 + 0.03 * np.arange(len(plate.faces))
    plate_uv = np.stack([np.stack([u0, np.full_like(u0, 0.9)], 1),
                         np.stack([u0 + 0.02, np.full_like(u0, 0.9)], 1),
                         np.stack([u0, np.full_like(u0, 0.93)], 1)], axis=1)
    vertices = np.concatenate([vertices, plate.vertices])
    faces = np.concatenate([faces, plate.faces + n * n + 2 * n + 1])
    corner_uv = np.concatenate([corner_uv, plate_uv])
    return _obj(path, vertices, faces, corner_uv), vertices, faces, corner_uv, on_chart, \
        off_chart


def test_uv_check_counts_collapsed_faces_with_area(tmp_path):
    _, vertices, faces, corner_uv, _, _ = own_uv_floor(tmp_path / "floor.obj")
    uv, faces_uv = corner_uv.reshape(-1, 2), np.arange(corner_uv.size // 2).reshape(-1, 3)
    has_area = ~degenerate_faces(vertices, faces)
    check = check_uvs(uv, faces_uv, 64, 64, has_area=has_area)
    assert check.valid and check.collapsed_faces == 4, check.message
    assert "(4 of them with surface area)" in check.message
    assert check_uvs(uv, faces_uv, 64, 64).collapsed_faces is None
    # a face of no area whose UVs collapse is no such face
    has_area[0] = False
    assert check_uvs(uv, faces_uv, 64, 64, has_area=has_area).collapsed_faces == 4


def test_own_uvs_with_collapsed_faces_are_baked_and_reported(tmp_path):
    """Own UVs with four faces collapsed to points are baked, with a warning naming them:
    the two on the chart read its texels, the two off it get the texel at their point
    baked with their own surface, which agrees with the texels of the floor around them
    (the floor's values at their corners) within 4 combined standard errors.  Seams off:
    the texel's own bake (erasure would also make it agree, its faces' edges being seams)."""
    path, vertices, faces, _, on_chart, off_chart = own_uv_floor(tmp_path / "floor.obj")
    size = 64
    result = bake_texels(path, resolution=size, rays=256, texel_samples=4, padding=2,
                         quantities=("ao",), seed=1, seams="off")
    report = result.report
    assert report["texture"]["atlas"] == "mesh UVs"
    assert "(4 of them with surface area)" in report["texture"]["uv_check"]["message"]
    warning = [w for w in report["warnings"] if "collapsed to a point" in w]
    assert len(warning) == 1 and "4 faces with surface area" in warning[0], report["warnings"]
    assert "2 lie on other faces' texels" in warning[0] and "2 off every chart" in warning[0]
    assert "gutter" not in warning[0]
    ao, se = result.channels["ao"], result.channels["ao_stderr"]
    assert result.covered[size // 2, int(0.8 * size)]  # the texel at (0.8, 0.5)
    point = np.array([[0.8, 0.5]])
    mine, mine_se = bilinear(ao, point)[0], bilinear(se, point)[0]
    # the floor read at the off-chart quad's corners, from the faces around it
    atlas = result.atlas
    source = atlas.source_vertex[atlas.faces]
    quad = np.unique(faces[off_chart])
    near = [g for g in np.flatnonzero(np.isin(source, quad).any(axis=1))
            if g not in off_chart]
    lookups = np.concatenate([atlas.uv[atlas.faces[g]][np.isin(source[g], quad)] for g in near])
    theirs, theirs_se = bilinear(ao, lookups).mean(), bilinear(se, lookups).mean()
    assert abs(mine - theirs) <= 4 * np.hypot(mine_se, theirs_se), (mine, theirs, mine_se)
    assert 0.05 < theirs < 0.98  # the plate shades the floor there


def test_a_cluster_touching_no_chart_starts_its_own():
    """``attach_collapsed`` on a hand-made chart list: a chart of two triangles, and two
    collapsed faces with area that share an edge but touch no chart (an island xatlas
    flattened nowhere): the first gets a chart of its own, flat in its plane (its UV
    triangle congruent to it), the second joins it through their shared edge; a collapsed
    face of no area elsewhere keeps its point."""
    positions = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],  # the chart's quad
                          [5, 0, 0], [5, 0.01, 0], [5.01, 0, 0.01], [5.0, -0.01, 0.0],
                          [9, 0, 0], [9, 1, 0], [9, 2, 0]], dtype=float)
    faces_in = np.array([[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6], [8, 9, 10]])
    vmapping = np.array([0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10])
    uv = np.concatenate([positions[:4, :2], np.zeros((7, 2))])
    faces = faces_in.copy()
    face_chart = charts.connected_labels(len(uv), faces)
    p = positions[faces_in]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    vm, new_faces, new_uv, chart = charts.attach_collapsed(positions, area, vmapping, faces,
                                                           uv, face_chart)
    np.testing.assert_array_equal(vm[new_faces], faces_in)
    assert chart[2] == chart[3] != chart[0] and chart[4] not in (chart[0], chart[2])
    uv_area = uv_face_areas(new_uv, new_faces)
    np.testing.assert_allclose(uv_area[2:4], area[2:4], rtol=1e-9)  # flat: as in 3-D
    assert uv_area[4] == 0  # no area: its point
    assert len(np.unique(new_faces)) == len(new_uv)
    assert new_faces[2, 0] == new_faces[3, 0] and new_faces[2, 1] == new_faces[3, 2]
