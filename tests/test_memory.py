"""The memory work of issue 34 point 3 changes no bit: blocked passes give the whole pass's
values at any block size, Embree reading the mesh in place answers as on its own copies,
and the one-pass angle-weighted normals equal the two-pass ones.
(benchmarks/bench_memory.py measures the bytes; docs/scale.md, "Memory".)"""

from __future__ import annotations

import gc
import pickle

import numpy as np
import pytest
import trimesh

from aobake import _native, occluders, repair
from aobake import scene as scene_module
from aobake import vectors as vectors_module
from aobake.backends import native
from aobake.backends.embree import EmbreeBackend, padded_float32, padded_rows
from aobake.errors import InputError
from aobake.scene import (Scene, face_normals, load_scene, make_scene, pairwise_sum,
                          vertex_normals)
from aobake.targets import vertices as vertices_module
from aobake.targets.vertices import vertex_sizes
from aobake.vectors import column_bounds, column_medians, defined


def _shells():
    """Two spheres and an open sheet, some faces flipped, a sphere turned inside out, a
    degenerate face: every branch of the orientation, over ~2,600 faces."""
    a = trimesh.creation.icosphere(3)
    b = trimesh.creation.icosphere(2)
    b.apply_translation([3.0, 0.0, 0.0])
    sheet = trimesh.creation.box(extents=(1, 1, 0.1))
    sheet.apply_translation([0.0, 3.0, 0.0])
    mesh = trimesh.util.concatenate([a, b, sheet])
    faces = mesh.faces.astype(np.int64).copy()
    rng = np.random.default_rng(4)
    flip = rng.choice(len(a.faces), 40, replace=False)
    faces[flip] = faces[flip][:, [0, 2, 1]]
    inside_out = slice(len(a.faces), len(a.faces) + len(b.faces))
    faces[inside_out] = faces[inside_out][:, [0, 2, 1]]
    faces[-1] = [faces[-1][0], faces[-1][0], faces[-1][1]]  # repeated corner
    return np.asarray(mesh.vertices, dtype=np.float64), faces


def _same(x, y):
    for name in x.__dataclass_fields__:
        a, b = getattr(x, name), getattr(y, name)
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes(), name


@pytest.mark.parametrize("with_normals", [False, True])
def test_orientation_is_the_same_at_any_block_size(monkeypatch, with_normals):
    vertices, faces = _shells()
    normals = vertex_normals(vertices, faces) if with_normals else None
    whole = repair.orient(vertices, faces, normals)
    monkeypatch.setattr(repair, "BLOCK", 7)
    _same(repair.orient(vertices, faces, normals), whole)
    assert whole.flip.any() and whole.inward.any()


def test_local_frame_in_blocks_is_the_cast_of_the_whole(monkeypatch):
    rng = np.random.default_rng(1)
    vertices = rng.normal(size=(1001, 3)) * 1e3 + 5e5
    unused = np.zeros(len(vertices), dtype=bool)
    unused[::17] = True
    center, scale = np.median(vertices, axis=0), 2.0 ** -11
    whole = (vertices - center) * scale
    whole[unused] = 0.0
    monkeypatch.setattr(occluders, "LOCAL_BLOCK", 64)
    local = occluders._local(vertices, center, scale, unused, float32=True)
    assert local.dtype == np.float32
    assert local.tobytes() == whole.astype(np.float32).tobytes()
    assert padded_float32(local) is local.base  # handed to Embree as it is, padded
    assert occluders._local(vertices, center, scale, unused, False).tobytes() == whole.tobytes()


def test_padded_float32_is_the_cast_with_one_float_more():
    rows = np.random.default_rng(2).normal(size=(10, 3))
    flat = padded_float32(rows)
    assert flat.shape == (31,) and flat[-1] == 0
    assert flat[:-1].tobytes() == rows.astype(np.float32).tobytes()
    filled = padded_rows(4)
    assert padded_float32(filled) is filled.base
    assert padded_float32(filled[1:]) is not filled.base  # not the whole array: a copy


@pytest.mark.slow
def test_embree_reading_the_mesh_in_place_answers_as_on_its_copies():
    found = native.binding()
    if found is None:
        pytest.skip("aobake._embree was not built or embreex's libembree4 was not found")
    module, widest = found
    vertices, faces = _shells()
    v32 = vertices.astype(np.float32)
    f32 = np.ascontiguousarray(faces, dtype=np.uint32)
    f32[-1] = [0, 1, 2]  # the degenerate row as a proper one: any triangle will do
    copied = module.scene(v32, len(v32), f32, len(f32), True)
    shared = module.scene(padded_float32(v32), len(v32), f32.copy(), len(f32), True)
    gc.collect()  # the arrays live on in the capsule only
    rng = np.random.default_rng(3)
    n = 4096
    o = rng.uniform(-2, 4, (n, 3)).astype(np.float32)
    d = rng.normal(size=(n, 3))
    d = (d / np.linalg.norm(d, axis=1)[:, None]).astype(np.float32)
    tfar = rng.choice([0.1, 1.0, 1e30], n).astype(np.float32)
    answers = []
    for scene in (copied, shared):
        hit = np.empty(n, dtype=bool)
        module.occluded(scene, o, d, tfar, hit, min(8, widest))
        t, prim = np.empty(n, np.float32), np.empty(n, np.int32)
        module.intersect(scene, o, d, tfar, t, prim)
        answers.append((hit.tobytes(), t.tobytes(), prim.tobytes()))
    assert answers[0] == answers[1]
    assert 0 < np.frombuffer(answers[0][0], bool).mean() < 1
    del copied, shared
    gc.collect()  # the capsules release the scene, then the arrays


def test_front_face_normals_are_read_from_the_scene_without_a_copy():
    vertices, faces = _shells()
    normals = face_normals(vertices, faces)
    backend = EmbreeBackend(vertices, faces, normals, 1e-6)
    assert backend._face_normals is normals
    o = np.zeros((3, 3), np.float32)
    d = np.eye(3, dtype=np.float32)
    t, prim, rows = backend.intersect_normals(o, d, np.full(3, 10, np.float32))
    assert rows.dtype == np.float32
    assert rows.tobytes() == normals.astype(np.float32)[np.maximum(prim, 0)].tobytes()


@pytest.mark.parametrize("mode", ["angle", "area", "file"])
def test_one_pass_normals_equal_the_two_pass_ones(mode):
    vertices, faces = _shells()
    scene = make_scene(vertices, faces, None, mode, fix_normals="off")
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)  # make_scene's frame
    local = (vertices - 0.5 * (lo + hi)) * 2.0 ** -np.frexp((hi - lo).max())[1]
    expected = vertex_normals(local, faces, "area" if mode == "area" else "angle")
    assert scene.vertex_normals.tobytes() == expected.tobytes()
    assert scene.face_normals.tobytes() == face_normals(local, faces).tobytes()


@pytest.mark.slow
def test_a_single_mesh_file_is_not_copied_on_load(tmp_path):
    mesh = trimesh.creation.icosphere(3)
    path = tmp_path / "sphere.ply"
    mesh.export(path)
    scene = load_scene(path)
    assert scene.faces.dtype == np.int64 and scene.faces.flags.c_contiguous
    assert scene.names is None  # nothing named: no per-face name index was made
    assert np.array_equal(scene.faces, mesh.faces)


# ---------------------------------------------------------------- a lean scene (Scene.lean)


def _loaded(tmp_path, numpy_only=False):
    vertices, faces = _shells()
    vertices = np.vstack([vertices, [[9.0, 9.0, 9.0]]])  # unreferenced: no normal, not traced
    path = tmp_path / "shells.ply"
    trimesh.Trimesh(vertices, faces, process=False).export(path)
    if numpy_only:
        with _native.numpy_only():
            return load_scene(path), path
    return load_scene(path), path


@pytest.mark.parametrize("numpy_only", [False, True])
def test_a_lean_scene_remakes_the_loads_face_normals_and_areas(tmp_path, monkeypatch,
                                                                numpy_only):
    scene, _ = _loaded(tmp_path, numpy_only)
    monkeypatch.setattr(scene_module, "FACE_BLOCK", 100)  # blocks, and a short last one
    lean = scene.lean()
    assert lean.__dict__["_face_normals"] is None and lean.face_areas is None
    if numpy_only:
        with _native.numpy_only():
            areas, normals = lean.areas(), lean.face_normals
    else:
        areas, normals = lean.areas(), lean.face_normals
    assert areas.tobytes() == scene.face_areas.tobytes()
    assert normals.tobytes() == scene.face_normals.tobytes()
    assert lean.face_normals is normals  # kept once made
    assert lean.areas(slice(150, 420)).tobytes() == scene.face_areas[150:420].tobytes()
    assert lean.stats() == scene.stats()
    assert pickle.loads(pickle.dumps(scene.lean())).face_normals.tobytes() == \
        scene.face_normals.tobytes()


def test_a_scene_built_directly_is_not_lean():
    vertices, faces = _shells()
    normals = face_normals(vertices, faces)
    scene = Scene(vertices, faces, vertex_normals(vertices, faces), normals)
    assert scene.lean() is scene
    with pytest.raises(InputError, match="face_normals"):
        Scene(vertices, faces, vertex_normals(vertices, faces), None)


def test_vertex_sizes_of_a_lean_scene_in_blocks(tmp_path, monkeypatch):
    scene, _ = _loaded(tmp_path)
    whole = vertex_sizes(scene)
    vertices, faces = _shells()
    direct = Scene(vertices * 1e3 + 5e5, faces, vertex_normals(vertices, faces),
                   face_normals(vertices, faces))  # no frame, no areas: made per block
    direct_whole = vertex_sizes(direct)
    monkeypatch.setattr(vertices_module, "SIZE_BLOCK", 77)
    assert vertex_sizes(scene.lean()).tobytes() == whole.tobytes()
    assert vertex_sizes(direct).tobytes() == direct_whole.tobytes()


@pytest.mark.parametrize("n", [0, 1, 7, 128, 129, 1000, 4099, 70001])
def test_pairwise_sum_of_blocks_is_numpys_sum(monkeypatch, n):
    values = np.random.default_rng(n).random(n) * 10.0 ** np.random.default_rng(1).uniform(
        -8, 8, n)
    monkeypatch.setattr(scene_module, "PAIRWISE_LEAF", 200)  # many splits, as numpy's
    seen = []

    def leaf(start, stop):
        seen.append(stop - start)
        return values[start:stop]

    assert pairwise_sum(n, leaf) == float(values.sum())
    assert max(seen, default=0) <= 200 and sum(seen) == n


def test_columns_give_the_bits_of_the_gathered_rows():
    rng = np.random.default_rng(6)
    rows = rng.normal(size=(1001, 3)) * 10.0 ** rng.uniform(-3, 3, (1001, 1))
    mask = rng.random(1001) < 0.7
    for given in (None, mask):
        picked = rows if given is None else rows[np.flatnonzero(given)]
        assert column_medians(rows, given).tobytes() == np.median(picked, axis=0).tobytes()
        assert column_bounds(rows, given).tobytes() == np.stack(
            [picked.min(axis=0), picked.max(axis=0)]).tobytes()


def test_defined_in_blocks_is_the_whole(monkeypatch):
    rows = np.random.default_rng(5).normal(size=(1000, 3)) * 0.4
    rows[::9] = 0.0
    whole = defined(rows)
    monkeypatch.setattr(vectors_module, "DEFINED_BLOCK", 64)
    assert np.array_equal(defined(rows), whole) and 0 < whole.mean() < 1


@pytest.mark.slow
@pytest.mark.parametrize("options", [{}, {"backfaces": "ignore", "quantities": ("ao", "obscurance")}])
def test_a_bake_that_lets_the_face_rows_go_gives_the_same_bits(tmp_path, options):
    """aobake.bake of a path leans the scene it loads; of a Scene, it keeps the caller's: the
    same values, rays, offsets and report figures (the front-face test remakes the face
    normals it reads; some vertices untraced: the traced points' copy let go)."""
    import aobake

    scene, path = _loaded(tmp_path)
    assert not defined(scene.vertex_normals).all()  # the unreferenced vertex
    kept = aobake.bake(scene, rays=16, seed=3, threads=2, chunk_rays=512, **options)
    lean = aobake.bake(str(path), rays=16, seed=3, threads=2, chunk_rays=512, **options)
    for name, array in kept.values.items():
        assert lean.values[name].tobytes() == array.tobytes(), name
    assert lean.rays.tobytes() == kept.rays.tobytes()
    assert lean.report["scene"] == kept.report["scene"]
    for key in ("ray_offset", "ray_offset_range"):
        assert lean.report["parameters"][key] == kept.report["parameters"][key]


# ---------------------------------------------------------------- a set with every instance baked

_CHILD = """
import json, sys
import aobake
result = aobake.bake(sys.argv[1], rays=4, threads=2)
arrays = [result.positions, result.faces, result.normals, result.rays, *result.values.values()]
outputs = sum({id(a): a.nbytes for a in arrays if a is not None}.values())
with open("/proc/self/status") as status:
    peak = next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmHWM:"))
print(json.dumps({"peak": peak, "outputs": outputs}))
"""


@pytest.mark.slow
def test_a_set_baked_whole_grows_with_its_outputs_not_with_copies_of_the_scene(tmp_path):
    """N copies of one mesh, every one baked (per vertex, as Embree instances), in a fresh
    process each: the peak beyond the result's own arrays (positions, faces, normals, rays,
    values) grows by at most a fifth as much as those arrays do from 2 to 12 copies.  The
    scene made of the whole flattened set (before aobake.placed) grew by ~1.8-1.9 times the
    outputs' growth (140 bytes a placed triangle); with the points' sizes, ray offsets and
    trace order held for every point while the rays were traced (before the trace went an
    instance at a time, tests/test_blocks.py) 0.23-0.28 times (three runs).  Now nothing is
    held for every point besides the outputs: measured 0.04-0.13 over three runs, 2-7 MiB
    of the outputs' 52 MiB, the spread the allocator's (which pages it keeps), not a
    growth; the bound, 0.2 (10 MiB), sits above that spread and below the per-point arrays
    of before.  VmHWM is the process's own high-water mark."""
    import json
    import subprocess
    import sys

    from gltf_scenes import write_instanced

    sphere = trimesh.creation.icosphere(6)  # 81,920 triangles, 40,962 vertices
    rows = {}
    for n in (2, 12):
        nodes = [{"name": f"n{i}", "mesh": 0, "translation": [2.5 * (i % 4), 0.0, 2.5 * (i // 4)]}
                 for i in range(n)]
        path = write_instanced(tmp_path / f"set{n}.glb", [{"name": "sphere",
                               "vertices": sphere.vertices, "faces": sphere.faces}], nodes)
        done = subprocess.run([sys.executable, "-c", _CHILD, str(path)], capture_output=True,
                              text=True, check=True)
        rows[n] = json.loads(done.stdout.strip().splitlines()[-1])
    outputs = rows[12]["outputs"] - rows[2]["outputs"]
    beyond = (rows[12]["peak"] - rows[12]["outputs"]) - (rows[2]["peak"] - rows[2]["outputs"])
    assert outputs > 40 << 20  # 10 copies' outputs: ~54 MB, far above the allocator's noise
    assert beyond <= 0.2 * outputs, (beyond / outputs, rows)


def test_a_point_range_stands_for_the_ids_it_does_not_hold():
    """PointRange (a plan's ids and state where every vertex is its own point): every way the
    bake reads the (n,) int64 0..n-1 gives that array's values."""
    from aobake.records import PointRange

    ids, whole = PointRange(50), np.arange(50, dtype=np.int64)
    order = np.random.default_rng(7).permutation(50).astype(np.int32)
    mask = whole % 3 == 0
    for key in (slice(None), slice(5, 17), slice(40, None, 3), order, order[:9], mask,
                np.array([-1, 0, 49])):
        got = ids[key]
        assert got.dtype == np.int64 and np.array_equal(got, whole[key]), key
    assert np.array_equal(np.asarray(ids), whole) and len(ids) == 50
    assert np.array_equal(mask[ids], mask) and np.asarray(ids, dtype=np.int32).dtype == np.int32
    assert len(pickle.loads(pickle.dumps(ids))) == 50
    with pytest.raises(IndexError):
        ids[np.array([50])]
