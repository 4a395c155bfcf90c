"""Meshes as they come: winding repair (--fix-normals), folded slivers in lightmaps, and own
UVs that stray outside [0, 1] (baked wrapped).  Generated meshes only."""

import json
import logging
import struct

import numpy as np
import pytest
import trimesh

import aobake
from aobake import repair
from aobake.scene import make_scene
from aobake.targets.texels.raster import rasterize
from aobake.targets.texels.surface import surface_points
from aobake.targets.texels.uvcheck import check_uvs, wrap_uvs
from analytic import z_bound
from conftest import run_cli


def _mesh(vertices, faces):
    return trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces), process=False)


def _swap(faces, rows):
    """faces with ``rows`` wound the other way (corners 1 and 2 swapped, as a repair does)."""
    out = np.array(faces, copy=True)
    out[rows] = out[rows][:, [0, 2, 1]]
    return out


def _same_bake(a, b):
    return all(np.array_equal(a.values[k], b.values[k]) for k in a.values) and \
        np.array_equal(a.rays, b.rays)


@pytest.fixture
def box():
    return trimesh.creation.box(extents=[1.0, 1.4, 0.8])


# --- the detector ---------------------------------------------------------------------


def test_detector_finds_exactly_the_flipped_faces():
    sphere = trimesh.creation.icosphere(3)
    rng = np.random.default_rng(5)
    flipped = rng.random(len(sphere.faces)) < 0.1
    found = repair.orient(sphere.vertices, _swap(sphere.faces, flipped))
    assert np.array_equal(found.against, flipped) and np.array_equal(found.flip, flipped)
    assert found.counts() == {"components": 1, "closed_components": 1,
                              "nearly_closed_components": 0,
                              "faces_against_neighbours": int(flipped.sum()),
                              "components_with_faces_against": 1, "inward_components": 0,
                              "conflicting_edges": 0}
    assert np.array_equal(repair.flip_faces(_swap(sphere.faces, flipped), found.flip),
                          sphere.faces)


def test_detector_components_closed_open_and_degenerate():
    sphere = trimesh.creation.icosphere(2)
    n = len(sphere.vertices)
    plane = trimesh.creation.box().faces[:2]  # two triangles of a box side: open
    vertices = np.concatenate([sphere.vertices, sphere.vertices + 3, trimesh.creation.box().vertices])
    faces = np.concatenate([sphere.faces, _swap(sphere.faces + n, slice(None)), plane + 2 * n,
                            [[0, 0, 1]]])  # a face with a repeated corner: no orientation
    found = repair.orient(vertices, faces)
    assert found.n_components == 3 and found.closed.tolist() == [True, True, False]
    assert found.inward.tolist() == [False, True, False]  # open: no file normals, no verdict
    assert found.component[-1] == -1 and not found.flip[-1]
    assert found.flip.sum() == len(sphere.faces)  # the inward sphere, all of it


def test_nearly_closed_component_is_oriented_by_its_capped_volume():
    sphere = trimesh.creation.icosphere(3)
    holed = sphere.faces[sphere.triangles_center[:, 2] < 0.97]  # a small hole at the top
    found = repair.orient(sphere.vertices, _swap(holed, slice(None)))
    assert found.nearly_closed.tolist() == [True] and found.inward.tolist() == [True]
    assert not repair.orient(sphere.vertices, holed).inward.any()
    # A bowl (half a sphere) has no inside: neither winding is called inward.
    bowl = sphere.faces[sphere.triangles_center[:, 2] < 0]
    for faces in (bowl, _swap(bowl, slice(None))):
        found = repair.orient(sphere.vertices, faces)
        assert not found.nearly_closed.any() and not found.inward.any()


def test_open_component_is_oriented_by_the_file_normals():
    grid = trimesh.creation.box().faces[:2]
    vertices = trimesh.creation.box().vertices
    face_n = repair.orient(vertices, grid)  # no normals: the majority stays
    assert not face_n.inward.any()
    up = np.cross(*(vertices[grid[0, 1:]] - vertices[grid[0, 0]]))
    against = np.tile(-up, (len(vertices), 1))
    found = repair.orient(vertices, grid, against)
    assert found.inward.tolist() == [True] and found.flip.all()
    assert not repair.orient(vertices, grid, -against).inward.any()


def _moebius(k=12):
    """(vertices, faces) of a Moebius strip of 2 k triangles."""
    t = np.linspace(0, 2 * np.pi, k, endpoint=False)
    half = t / 2
    ring = np.stack([np.cos(t), np.sin(t), np.zeros(k)], axis=1)
    offset = np.stack([np.cos(half) * np.cos(t), np.cos(half) * np.sin(t), np.sin(half)], axis=1)
    vertices = np.concatenate([ring + 0.3 * offset, ring - 0.3 * offset])
    faces = []
    for i in range(k):
        j = (i + 1) % k
        a, b = i, i + k
        c, d = (j, j + k) if j else (j + k, j)  # the half twist joins the two edges
        faces += [[a, b, d], [a, d, c]]
    return vertices, np.array(faces)


def test_moebius_strip_is_counted_not_forced():
    found = repair.orient(*_moebius())
    assert found.conflicting_edges >= 1 and found.n_components == 1


def test_detector_is_deterministic_under_face_order():
    sphere = trimesh.creation.icosphere(2)
    flipped = np.arange(len(sphere.faces)) % 7 == 0
    faces = _swap(sphere.faces, flipped)
    order = np.random.default_rng(1).permutation(len(faces))
    a = repair.orient(sphere.vertices, faces)
    b = repair.orient(sphere.vertices, faces[order])
    assert np.array_equal(a.flip[order], b.flip) and a.counts() == b.counts()


def _same_union_find(n, a, b, odd, kernel):
    expected = repair._parity_union_find(n, a, b, odd)
    got = repair._parity_union_find(n, a, b, odd, kernel)
    return all(x.dtype == y.dtype and np.array_equal(x, y) for x, y in zip(expected, got))


def test_compiled_union_find_is_the_numpy_rounds_bit_for_bit(kernel):
    """The compiled parity union-find returns the numpy rounds' (root, parity): also the
    parities of non-orientable components (odd cycles), which depend on the rounds."""
    rng = np.random.default_rng(11)
    for trial in range(200):
        n = int(rng.integers(1, 300))
        e = int(rng.integers(0, 3 * n))
        a, b = rng.integers(0, n, e), rng.integers(0, n, e)  # self-loops and repeats too
        odd = rng.random(e) < [0.0, 0.5, 1.0][trial % 3]
        assert _same_union_find(n, a, b, odd, kernel), trial
    # odd cycles (a triangle of all-odd edges has no 2-colouring) strung into long chains
    # whose node numbers are shuffled, so trees hook over many rounds
    for trial in range(20):
        k = int(rng.integers(1, 60))
        cycles = [[3 * i, 3 * i + 1, 3 * i + 1, 3 * i + 2, 3 * i + 2, 3 * i] for i in range(k)]
        a = np.array([c[j] for c in cycles for j in (0, 2, 4)] + list(range(0, 3 * k - 3, 3)))
        b = np.array([c[j] for c in cycles for j in (1, 3, 5)] + list(range(3, 3 * k, 3)))
        odd = rng.random(len(a)) < 0.7
        label = rng.permutation(3 * k)
        assert _same_union_find(3 * k, label[a], label[b], odd, kernel), trial
    # a mesh's triangle graph, as orient builds it: a closed sphere with random faces
    # flipped, faces shuffled, and a Moebius strip beside it
    sphere = trimesh.creation.icosphere(5)
    faces = _swap(sphere.faces, rng.random(len(sphere.faces)) < 0.3)[rng.permutation(len(sphere.faces))]
    edges = repair.manifold_pairs(faces, len(sphere.vertices))
    assert _same_union_find(len(faces), edges.a, edges.b, edges.same, kernel)
    strip_vertices, strip = _moebius(40)
    faces = np.concatenate([faces, strip + len(sphere.vertices)])
    edges = repair.manifold_pairs(faces, len(sphere.vertices) + len(strip_vertices))
    root, parity = repair._parity_union_find(len(faces), edges.a, edges.b, edges.same)
    assert np.count_nonzero((parity[edges.a] ^ parity[edges.b]) != edges.same) >= 1
    assert _same_union_find(len(faces), edges.a, edges.b, edges.same, kernel)


def test_detector_is_the_same_on_the_numpy_path(kernel):
    from aobake import _native

    sphere = trimesh.creation.icosphere(3)
    faces = _swap(sphere.faces, np.arange(len(sphere.faces)) % 5 == 0)
    holed = faces[sphere.triangles_center[:, 2] < 0.9]  # open: its caps' loops too
    for f in (faces, holed):
        compiled = repair.orient(sphere.vertices, f)
        with _native.numpy_only():
            reference = repair.orient(sphere.vertices, f)
        assert compiled.counts() == reference.counts()
        assert all(np.array_equal(getattr(compiled, name), getattr(reference, name))
                   for name in ("component", "against", "flip", "closed", "nearly_closed",
                                "inward"))


def test_compiled_face_terms_are_the_numpy_bits(kernel):
    """orient's per-face terms (areas, mean corners, normal votes, volumes about the
    centres) from aobake/_orient.c equal numpy's bit for bit, on coordinates spread over
    many binades (so any other order of the sums would show), and on a real winding."""
    rng = np.random.default_rng(11)
    v = 300
    vertices = rng.normal(size=(v, 3)) * np.exp(rng.normal(size=(v, 3)) * 6)
    normals = rng.normal(size=(v, 3)) * np.exp(rng.normal(size=(v, 3)) * 6)
    # signed zeros: numpy's sums of negative zeros are +0.0
    vertices[:40] = np.where(rng.random((40, 3)) < 0.5, -0.0, 0.0)
    normals[:40] = np.where(rng.random((40, 3)) < 0.5, -0.0, 0.0)
    for m in (1, 7, 5000):
        corners = rng.integers(0, v, size=(m, 3))
        corners[: m // 3] %= 40  # faces of zero vertices, degenerate ones among them
        centre = rng.normal(size=(4, 3))
        centre[0] = -0.0
        comp = rng.integers(0, 4, size=m)
        for n in (normals, None):
            got = repair._face_terms(vertices, corners, n, kernel)
            want = repair._face_terms(vertices, corners, n)
            for a, b in zip(got, want):
                assert (a is None and b is None) or a.tobytes() == b.tobytes()
        assert repair._face_volumes(vertices, corners, centre, comp, kernel).tobytes() == \
            repair._face_volumes(vertices, corners, centre, comp).tobytes()
    # an index out of range: the kernel declines, numpy raises
    assert not kernel.orient_terms(vertices, np.array([[0, 1, v]]), np.empty(0), np.empty(1),
                                   np.empty(3), np.empty(0))
    assert not kernel.orient_volumes(vertices, np.array([[0, 1, 2]]), centre, np.array([4]),
                                     np.empty(1))


# --- --fix-normals in the bake ----------------------------------------------------------


def test_box_with_one_flipped_face_is_detected_and_fixed_bit_for_bit(box, caplog):
    flipped = _mesh(box.vertices, _swap(box.faces, [3]))
    good = aobake.bake(_mesh(box.vertices, box.faces), rays=64, ground_plane=True, up_axis="z")
    with caplog.at_level(logging.WARNING, logger="aobake.scene"):
        fixed = aobake.bake(flipped, rays=64, ground_plane=True, up_axis="z", fix_normals="fix")
    record = fixed.report["scene"]["fix_normals"]
    assert record["mode"] == "fix" and record["faces_against_neighbours"] == 1
    assert record["components_with_faces_against"] == 1 and record["faces_flipped"] == 1
    assert record["inward_components"] == 0
    assert "flipped 1 faces" in caplog.text
    # The repair swaps the face back to its original corners: the scene, hence the bake,
    # is the unflipped box's, bit for bit.
    assert np.array_equal(fixed.faces, box.faces) and _same_bake(fixed, good)
    # Not fixing changes the computed normals at the flipped face (so the test can fail).
    kept = aobake.bake(flipped, rays=64, ground_plane=True, up_axis="z", fix_normals="off")
    assert not np.array_equal(kept.normals, good.normals)


def test_closed_mesh_wound_inward_is_fixed():
    sphere = trimesh.creation.icosphere(3)
    outward = aobake.bake(_mesh(sphere.vertices, sphere.faces), rays=64)
    inward = _swap(sphere.faces, slice(None))
    fixed = aobake.bake(_mesh(sphere.vertices, inward), rays=64, fix_normals="fix")
    assert fixed.report["scene"]["fix_normals"]["inward_components"] == 1
    assert fixed.report["scene"]["fix_normals"]["faces_flipped"] == len(inward)
    assert _same_bake(fixed, outward)
    # Reversed as [c, b, a], a repair gives [c, a, b]: the same triangles with their
    # corners rotated, so the angle-weighted normals sum in another order and may differ
    # in the last bit; the values agree within their error bars.
    rotated = aobake.bake(_mesh(sphere.vertices, sphere.faces[:, ::-1]), rays=64,
                          fix_normals="fix")
    assert np.allclose(rotated.normals, outward.normals, atol=1e-12)
    se = np.hypot(rotated.ao_stderr, outward.ao_stderr)
    assert np.all(np.abs(rotated.ao - outward.ao) <= z_bound(len(se), 7) * se)


def test_file_normals_of_flipped_faces_are_replaced_when_they_point_against_them(box):
    # An inward box whose file normals follow its (wrong) winding.
    inward = _swap(box.faces, slice(None))
    normals = -np.asarray(box.vertex_normals)
    fixed = make_scene(box.vertices, inward, normals, fix_normals="fix")
    assert fixed.repair["normals_replaced"] == len(box.vertices)
    reference = make_scene(box.vertices, box.faces, normals_mode="angle")
    assert np.array_equal(fixed.vertex_normals, reference.vertex_normals)
    assert np.array_equal(fixed.faces, box.faces)
    # Outward file normals on a face flipped by mistake agree with the repair: kept.
    one = make_scene(box.vertices, _swap(box.faces, [5]), box.vertex_normals, fix_normals="fix")
    assert one.repair["normals_replaced"] == 0
    assert np.allclose(one.vertex_normals, box.vertex_normals)


def test_warn_mode_warns_and_changes_nothing(box, caplog):
    faces = _swap(box.faces, [3, 7])
    mesh = _mesh(box.vertices, faces)
    with caplog.at_level(logging.WARNING, logger="aobake.scene"):
        warned = aobake.bake(mesh, rays=32)  # warn is the default
    off = aobake.bake(mesh, rays=32, fix_normals="off")
    text = ("<memory>: 2 faces of 1 components are wound against their neighbours; "
            "0 components point inward: --fix-normals fix repairs them")
    assert text in caplog.text and text in warned.report["warnings"]
    assert np.array_equal(warned.faces, faces) and _same_bake(warned, off)
    assert np.array_equal(warned.normals, off.normals)
    record = warned.report["scene"]["fix_normals"]
    assert record["mode"] == "warn" and record["faces_against_neighbours"] == 2
    assert record["faces_flipped"] == 0 and record["normals_replaced"] == 0


def test_off_mode_looks_at_nothing(box, caplog):
    mesh = _mesh(box.vertices, _swap(box.faces, slice(None)))
    with caplog.at_level(logging.WARNING, logger="aobake.scene"):
        scene = aobake.load_scene(mesh, fix_normals="off")
    assert "wound" not in caplog.text and not scene.warnings
    assert np.array_equal(scene.faces, mesh.faces)
    record = scene.stats()["fix_normals"]
    assert record["mode"] == "off" and record["components"] is None
    assert record["faces_flipped"] == 0


def test_consistent_mesh_is_untouched_by_fix(box):
    good = _mesh(box.vertices, box.faces)
    assert _same_bake(aobake.bake(good, rays=32, fix_normals="fix"), aobake.bake(good, rays=32))
    assert aobake.load_scene(good).warnings == []


def test_cli_fix_normals(tmp_path, box):
    path = tmp_path / "flipped.ply"
    _mesh(box.vertices, _swap(box.faces, [2])).export(path)
    out, report = tmp_path / "ao.npz", tmp_path / "report.json"
    result = run_cli(path, "--out", out, "--rays", 16, "--fix-normals", "fix", "--report", report,
                     "--quiet")
    assert result.exit_code == 0, result.output
    data = json.loads(report.read_text())
    assert data["config"]["fix_normals"] == "fix"
    assert data["scene"]["fix_normals"]["faces_flipped"] == 1
    bad = run_cli(path, "--out", out, "--fix-normals", "maybe")
    assert bad.exit_code == 2 and "--fix-normals" in bad.output


# --- slivers in lightmaps ---------------------------------------------------------------


def _sliver_plate(delta=0.02):
    """A unit plate at z = 1 over a large floor at z = 0, both with up file normals.  The
    plate is ABE, BCE, ACD and the sliver AEC, with E just past the diagonal AC: a folded
    sliver, wound consistently with its neighbours but with its face normal pointing down.
    Each face has its own UV triangle in a 3 x 2 grid, so the sliver gets many texels."""
    vertices = np.array([[0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1], [0.5, 0.5 + delta, 1],
                         [-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], float)
    a, b, c, d, e = range(5)
    faces = np.array([[a, b, e], [b, c, e], [a, e, c], [a, c, d], [5, 6, 7], [5, 7, 8]])
    normals = np.tile([0.0, 0.0, 1.0], (len(vertices), 1))
    uv, faces_uv = [], []
    for i in range(len(faces)):
        x0, y0 = (i % 3) / 3, (i // 3) / 2
        uv += [[x0 + 0.02, y0 + 0.02], [x0 + 0.31, y0 + 0.02], [x0 + 0.02, y0 + 0.47]]
        faces_uv.append([3 * i, 3 * i + 1, 3 * i + 2])
    return make_scene(vertices, faces, normals, uv=np.array(uv), faces_uv=np.array(faces_uv))


def test_folded_sliver_makes_no_dark_texels():
    scene = _sliver_plate()
    assert scene.face_normals[2, 2] < 0  # the sliver faces down, into the space under the plate
    width = 48
    res = aobake.bake_texels(scene, rays=256, resolution=width, padding=0, texel_samples=4)
    assert res.report["texture"]["atlas"] == "mesh UVs"
    ao, se = res.channels["ao"], res.channels["ao_stderr"]
    centres = rasterize(scene.uv, scene.faces_uv, width, width, 1)
    face_of = np.full(width * width, -1)
    face_of[centres.texel] = centres.face
    face_of = face_of.reshape(width, width)
    sliver = (face_of == 2) & res.covered
    plate = np.isin(face_of, [0, 1, 3]) & res.covered
    assert sliver.sum() > 100 and plate.sum() > 300
    # Nothing above the plate: its texels are open (AO 1); the sliver's must be in their range.
    low = ao[plate].min()
    assert np.all(ao[sliver] >= low - 3 * se[sliver]), ao[sliver].min()
    # The shading normals on the sliver are its vertex normals (up), not its face normal.
    samples = rasterize(scene.uv, scene.faces_uv, width, width, 4)
    _, shading, faces_n = surface_points(scene.vertices, scene.vertex_normals, scene.faces, samples)
    on = samples.face == 2
    assert np.allclose(shading[on], [0, 0, 1]) and np.all(faces_n[on, 2] < 0)


def test_face_normal_still_wins_where_the_face_agrees_with_its_normals():
    # A right-angle crease: the vertex normals on the edge tip 45 degrees; interpolated
    # towards a corner whose normal points away from the face, the face normal takes over.
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    faces = np.array([[0, 1, 2]])
    normals = np.array([[0, 0, 1], [0, 0, 1], [0, -1, -0.2]], float)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    samples = rasterize(np.array([[0, 0], [1, 0], [0, 1]], float), faces, 16, 16, 1)
    _, shading, face_n = surface_points(vertices, normals, faces, samples)
    interpolated = samples.bary @ normals
    below = np.einsum("ij,ij->i", interpolated, face_n) <= 0
    assert below.any() and (~below).any()
    assert np.allclose(shading[below], [0, 0, 1])
    assert np.all(np.einsum("ij,ij->i", shading[~below], interpolated[~below]) > 0.99 *
                  np.linalg.norm(interpolated[~below], axis=1))


# --- own UVs outside [0, 1], baked wrapped -----------------------------------------------


def _floor_under_ceiling(shift=(-0.15, 0.03), n=10):
    """A unit floor grid (n x n quads) at z = 0 with UVs = (x, y) + shift, under a large
    ceiling at z = 1 facing down whose UVs are one degenerate point (it gets no texels)."""
    xs = np.linspace(0.0, 1.0, n + 1)
    gx, gy = np.meshgrid(xs, xs, indexing="xy")
    floor_v = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    faces = []
    for j in range(n):
        for i in range(n):
            p = j * (n + 1) + i
            faces += [[p, p + 1, p + n + 2], [p, p + n + 2, p + n + 1]]
    m = len(floor_v)
    ceiling_v = np.array([[-5, -5, 1.0], [6, -5, 1.0], [6, 6, 1.0], [-5, 6, 1.0]])
    faces += [[m, m + 2, m + 1], [m, m + 3, m + 2]]
    uv = np.concatenate([floor_v[:, :2] + shift, np.full((4, 2), 0.5)])
    return make_scene(np.concatenate([floor_v, ceiling_v]), np.array(faces), uv=uv)


def test_wrap_layout_moves_and_splits_faces():
    scene = _floor_under_ceiling()
    layout = wrap_uvs(scene.uv, scene.faces_uv)
    assert layout.wrapped and layout.oversized_faces == 0
    # u: the column x in [0, 0.1] is moved (u < 0); x in [0.1, 0.2] straddles u = 0 and
    # is split, and the half of its faces whose centroid has u < 0 is moved too;
    # v: the row y in [0.9, 1] straddles v = 1; their corner square is split four ways.
    assert layout.moved_faces == 20 + 10 and layout.split_faces == 20 + 20 - 2
    assert np.all(np.diff(layout.face) >= 0)
    assert np.bincount(layout.face).max() == 4
    # UVs already in [0, 1] are the input's, untouched.
    inside = wrap_uvs(np.array([[0, 0], [1, 0], [0, 1]], float), np.array([[0, 1, 2]]))
    assert not inside.wrapped and inside.face is None
    # A face wider than one tile cannot be wrapped.
    wide = wrap_uvs(np.array([[-0.2, 0], [1.1, 0], [0, 1]], float), np.array([[0, 1, 2]]))
    assert wide.oversized_faces == 1 and not wide.wrapped
    assert not check_uvs(wide.uv, wide.faces, 8, 8).valid


def test_wrapped_own_uvs_are_baked_without_a_new_atlas(tmp_path):
    h, d = 1.0, 2.3
    exact = (h / d) ** 2  # floor under a ceiling, max distance D: (h / D)^2
    scene = _floor_under_ceiling()
    width = 20
    res = aobake.bake_texels(scene, rays=256, resolution=width, padding=0, texel_samples=2,
                             max_distance=d, sampler="random")
    texture = res.report["texture"]
    assert texture["atlas"] == "mesh UVs" and texture["wrap"] == "repeat"
    assert texture["uv_check"]["valid"] and texture["uv_check"]["out_of_range_faces"] > 0
    assert not any("new atlas" in w for w in res.report["warnings"])
    # The floor fills one whole tile: wrapped, it covers every texel exactly once.
    assert res.covered.all() and texture["texels_shared"] == 0
    ao, se = res.channels["ao"], res.channels["ao_stderr"]
    k = z_bound(ao.size, None)
    assert np.all(np.abs(ao - exact) <= k * se)

    written = aobake.write(res, tmp_path / "ao.glb")
    gltf = _glb_json(written[0])
    occlusion = gltf["materials"][0]["occlusionTexture"]["index"]
    sampler = gltf["samplers"][gltf["textures"][occlusion]["sampler"]]
    assert sampler["wrapS"] == sampler["wrapT"] == 10497  # REPEAT
    assert gltf["asset"]["extras"]["texture"]["wrap"] == "repeat"
    for suffix in (".exr", ".png"):
        path = aobake.write(res, tmp_path / f"ao{suffix}")[0]
        assert json.loads(_image_attribute(path, "aobake:texture"))["wrap"] == "repeat"


def test_in_range_uvs_clamp_and_overlapping_wraps_are_rejected(tmp_path):
    res = aobake.bake_texels(_floor_under_ceiling(shift=(0.0, 0.0)), rays=8, resolution=16,
                             padding=0)
    assert res.report["texture"]["wrap"] == "clamp"
    gltf = _glb_json(aobake.write(res, tmp_path / "ao.glb")[0])
    occlusion = gltf["materials"][0]["occlusionTexture"]["index"]
    assert gltf["samplers"][gltf["textures"][occlusion]["sampler"]]["wrapS"] == 33071
    # Stretched to 1.2 tiles wide, the wrapped floor covers a fifth of the tile twice.
    scene = _floor_under_ceiling(shift=(-0.1, 0.0))
    stretched = make_scene(scene.vertices, scene.faces, uv=scene.uv * [1.2, 1.0])
    check = check_uvs(stretched.uv, stretched.faces_uv, 20, 20)
    assert not check.valid and check.overlapping_texels > 0 and check.wrapped


def _glb_json(path) -> dict:
    data = path.read_bytes()
    length, kind = struct.unpack_from("<II", data, 12)
    assert kind == 0x4E4F534A
    return json.loads(data[20:20 + length])


def _image_attribute(path, name):
    import OpenImageIO as oiio

    image = oiio.ImageInput.open(str(path))
    try:
        return image.spec().getattribute(name)
    finally:
        image.close()
