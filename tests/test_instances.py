"""Scenes of instances (issue 34): glTF nodes sharing a mesh (and EXT_mesh_gpu_instancing)
load as one copy of each mesh plus a transform per placement, trace as Embree instances,
and bake only the nodes ``--bake`` names while every node occludes.

- loading: every instance baked gives the flattened loader's arrays, bit for bit; copies of
  EXT_mesh_gpu_instancing; the selection and its refusals;
- tracing: the instanced backend answers as the flattened triangles do (reference backend)
  except for rays that graze an edge; a bake through instances equals the flattened bake
  within its error bars (z-test, independent seeds), and the subset bake equals the whole
  bake at those vertices;
- the same bits for every split, thread count and executor (processes, Dask: slow);
- the NPZ's per-instance arrays, and ``aobake compare`` against the flattened bake;
- memory: the Embree scene of N instances of one mesh does not grow with N (slow).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import trimesh

import aobake
from aobake import api, instances as placed, occluders
from aobake.errors import InputError, UsageError
from aobake.outputs import npz
from aobake.scene import load_scene
from aobake.settings import BakeConfig
from aobake.targets import TARGETS

from analytic import z_bound
from gltf_scenes import write_instanced

needs_native = pytest.mark.skipif(
    not __import__("aobake.backends.instanced", fromlist=["available"]).available(),
    reason="aobake._embree not built: Embree instances need it")


def _rotation(axis, degrees):
    """glTF's xyzw quaternion of a rotation about ``axis`` (3,)."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    half = math.radians(degrees) / 2
    return [*(axis * math.sin(half)).tolist(), math.cos(half)]


def _rock(seed=0, subdivisions=2):
    """A lumpy closed mesh (an icosphere pushed in and out): concave places to occlude."""
    mesh = trimesh.creation.icosphere(subdivisions)
    rng = np.random.default_rng(seed)
    mesh.vertices *= (1.0 + 0.25 * rng.random(len(mesh.vertices)))[:, None]
    return mesh


def _set(path, extension=False):
    """A cluster of one rock placed 9 times (rotations, a non-uniform scale, a mirror, two
    under a parent node) on a floor, touching and shading each other; optionally a node of
    3 EXT_mesh_gpu_instancing copies."""
    rock = _rock()
    floor = trimesh.creation.box((9.0, 0.2, 9.0))
    meshes = [{"name": "rock", "vertices": rock.vertices, "faces": rock.faces},
              {"name": "floor", "vertices": floor.vertices, "faces": floor.faces}]
    nodes = [{"name": "floor", "mesh": 1, "translation": [0.0, -1.3, 0.0]}]
    spots = [(0, 0), (2.1, 0.2), (-2.0, 0.4), (0.3, 2.2), (-0.2, -2.1), (2.0, 2.0), (-2.1, -2.0)]
    for i, (x, z) in enumerate(spots):
        nodes.append({"name": f"rock{i}", "mesh": 0, "translation": [x, 0.0, z],
                      "rotation": _rotation([1, 2 - i, 0.5], 37 * i),
                      "scale": [1.0, 1.0 + 0.08 * i, 1.0 - 0.05 * i]})
    nodes[-1]["scale"] = [-1.0, 1.0, 1.0]  # a mirrored placement
    nodes.append({"name": "pair", "translation": [0.0, 0.0, 4.0], "rotation": _rotation([0, 1, 0], 30),
                  "children": [len(nodes) + 1, len(nodes) + 2]})
    nodes.append({"name": "pair_a", "mesh": 0, "translation": [-1.0, 0.0, 0.0]})
    nodes.append({"name": "pair_b", "mesh": 0, "translation": [1.0, 0.0, 0.0],
                  "scale": [0.7, 0.7, 0.7]})
    if extension:
        nodes.append({"name": "row", "mesh": 0, "translation": [0.0, 0.0, -4.2],
                      "instancing": {"TRANSLATION": [[-2.2, 0, 0], [0, 0, 0], [2.2, 0, 0]],
                                     "ROTATION": [_rotation([0, 1, 0], 20 * k) for k in range(3)],
                                     "SCALE": [[1, 1, 1], [0.8, 1.2, 0.8], [1, 1, 1]]}})
    return write_instanced(path, meshes, nodes)


@pytest.fixture(scope="module")
def rocks(tmp_path_factory):
    return _set(tmp_path_factory.mktemp("instances") / "rocks.gltf")


def _flat_load(path, monkeypatch):
    """The flattened loader's scene of ``path`` (trimesh's Scene.dump: no instances)."""
    with monkeypatch.context() as patch:
        patch.setattr(placed, "read", lambda *a, **k: None)
        return load_scene(path)


def _bake(scene, **options):
    """A per-vertex bake of ``scene`` (256 i.i.d. rays unless given): BakeConfig fields and
    ``run``'s keywords (threads, executor, workers, chunk_points) in ``options``."""
    run = {k: options.pop(k) for k in ("threads", "executor", "workers", "chunk_points")
           if k in options}
    config = BakeConfig(**{"rays": 256, "sampler": "random", **options})
    return api.run(config, scene, TARGETS["vertices"](), **run)


def _same_within_error_bars(a, b, se_a, se_b):
    """Independent estimates of the same values: no point beyond the Bonferroni bound, no
    bias beyond 4 standard errors of the mean difference."""
    d = a - b
    se = np.hypot(se_a, se_b)
    z = d / se
    bound = z_bound(len(d), None)
    assert np.abs(z).max() <= bound, (np.abs(z).max(), bound, int(np.argmax(np.abs(z))))
    assert abs(d.mean()) <= 4 * math.sqrt(np.sum(se ** 2)) / len(d), d.mean()
    return z


# --------------------------------------------------------------------------- loading


@pytest.mark.slow
def test_every_instance_baked_is_the_flattened_scene_bit_for_bit(rocks, monkeypatch):
    scene = load_scene(rocks)
    flat = _flat_load(rocks, monkeypatch)
    assert scene.instances is not None and flat.instances is None
    for name in ("vertices", "faces", "vertex_normals", "face_normals"):
        np.testing.assert_array_equal(getattr(scene, name), getattr(flat, name), err_msg=name)
    assert scene.names["node"][0] == flat.names["node"][0]
    np.testing.assert_array_equal(scene.names["node"][1], flat.names["node"][1])
    record = scene.instances.record()
    assert record == {"instances": 10, "meshes": 2, "unique_triangles": 320 + 12,
                      "instanced_triangles": 9 * 320 + 12, "baked": 10, "patterns": []}
    assert scene.instances.everything
    np.testing.assert_array_equal(scene.bounds, flat.bounds)
    # the bounds of every instance, from the hull's vertices: exact up to rounding
    np.testing.assert_allclose(scene.instances.bounds, flat.bounds, rtol=0, atol=1e-12)


def _dressed(path):
    """Two meshes with normals and UVs, placed 6 times (rotations, a mirror): one wound
    against itself in places, the other (an open sheet) inside out, against its normals."""
    rock = _rock(1, 3)
    faces = rock.faces.copy()
    faces[:30] = faces[:30][:, [0, 2, 1]]
    normals = rock.vertex_normals.copy()
    normals[::7] = 0.0  # no file normal: filled from the faces
    sheet = trimesh.creation.box((2.0, 0.01, 2.0))
    meshes = [{"name": "rock", "vertices": rock.vertices, "faces": faces, "normals": normals,
               "uv": rock.vertices[:, :2] * 0.3 + 0.5},
              {"name": "sheet", "vertices": sheet.vertices, "faces": sheet.faces[:, [0, 2, 1]],
               "normals": sheet.vertex_normals, "uv": sheet.vertices[:, [0, 2]] * 0.2 + 0.5}]
    nodes = [{"name": f"n{i}", "mesh": i % 2, "translation": [3.0 * i, 0.1 * i, 0.0],
              "rotation": _rotation([1, i, 0.3], 23 * i),
              "scale": [1.0, 1.0 + 0.1 * i, -1.0 if i % 3 == 2 else 1.0]} for i in range(6)]
    return write_instanced(path, meshes, nodes)


@pytest.mark.slow
@pytest.mark.parametrize("normals", ["file", "angle", "area"])
@pytest.mark.parametrize("fix", ["warn", "fix"])
def test_the_set_is_made_an_instance_at_a_time_as_the_flattened_loader_makes_it(
        tmp_path, monkeypatch, normals, fix):
    """aobake.placed: the winding check, normals and warnings per instance give the
    flattened loader's scene bit for bit (file normals, some missing, faces flipped by the
    check, a mirrored placement, UVs and materials); face normals and the name index are
    not held until read."""
    path = _dressed(tmp_path / "dressed.glb")
    scene = load_scene(path, normals, fix)
    flat = _flat_load_with(path, monkeypatch, normals, fix)
    assert scene.__dict__["_face_normals"] is None and scene.face_areas is None
    assert callable(scene.__dict__["_names"])  # not made yet
    for name in ("vertices", "faces", "vertex_normals", "face_normals", "uv", "faces_uv",
                 "face_material"):
        a, b = getattr(scene, name), getattr(flat, name)
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), name
    assert scene.areas().tobytes() == flat.areas().tobytes()
    stats = scene.stats()
    stats.pop("instances")
    assert stats == flat.stats()
    assert scene.repair["faces_against_neighbours"] > 0 and scene.repair["inward_components"] > 0
    assert scene.warnings == flat.warnings and scene.materials == flat.materials
    assert scene.names.keys() == flat.names.keys()
    for kind, (given, index) in flat.names.items():
        assert scene.names[kind][0] == given and scene.names[kind][1].tobytes() == index.tobytes()


def _flat_load_with(path, monkeypatch, normals, fix):
    with monkeypatch.context() as patch:
        patch.setattr(placed, "read", lambda *a, **k: None)
        return load_scene(path, normals, fix)


@pytest.mark.slow
def test_a_file_that_places_each_mesh_once_loads_flat(tmp_path):
    box = trimesh.creation.box()
    path = write_instanced(tmp_path / "once.gltf", [{"vertices": box.vertices, "faces": box.faces}],
                           [{"name": "only", "mesh": 0}])
    assert load_scene(path).instances is None
    chosen = load_scene(path, bake="only")  # a selection reads it as instances all the same
    assert chosen.instances is not None and chosen.instances.everything


@pytest.mark.slow
def test_ext_mesh_gpu_instancing_places_each_copy(tmp_path):
    path = _set(tmp_path / "row.glb", extension=True)
    scene = load_scene(path, bake="row")
    inst = scene.instances
    assert [inst.names[i] for i in inst.baked] == ["row#0", "row#1", "row#2"]
    rock = _rock()
    for k, i in enumerate(inst.baked):
        translation = np.array([[-2.2, 0, 0], [0, 0, 0], [2.2, 0, 0]])[k] + [0, 0, -4.2]
        angle = math.radians(20 * k)
        rotation = np.array([[math.cos(angle), 0, math.sin(angle)], [0, 1, 0],
                             [-math.sin(angle), 0, math.cos(angle)]])
        scale = np.array([[1, 1, 1], [0.8, 1.2, 0.8], [1, 1, 1]])[k]
        # the file holds float32 values: compare at float32's resolution
        expected = (rock.vertices * scale) @ rotation.T + translation
        got = scene.vertices[inst.vertex_offsets[k]:inst.vertex_offsets[k + 1]]
        np.testing.assert_allclose(got, expected, atol=1e-5)
    assert len(inst) == 13 and scene.instances.record()["baked"] == 3


@pytest.mark.slow
def test_bake_chooses_nodes_by_name_and_mesh(rocks):
    scene = load_scene(rocks, bake=("rock1", "pair_*"))
    names = [scene.instances.names[i] for i in scene.instances.baked]
    assert names == sorted(names, key=list(scene.instances.names).index)  # instance order
    assert set(names) == {"rock1", "pair_a", "pair_b"}
    assert len(scene.faces) == 3 * 320
    whole = load_scene(rocks)
    # the whole set's, not theirs (from the mesh's hull placed: up to rounding)
    np.testing.assert_allclose(scene.bounds, whole.bounds, rtol=1e-15, atol=0)
    assert scene.diagonal == pytest.approx(whole.diagonal, rel=1e-15)
    only_floor = load_scene(rocks, bake="mesh:floor")
    assert [only_floor.instances.names[i] for i in only_floor.instances.baked] == ["floor"]
    with pytest.raises(InputError, match=r"--bake 'chair' matches no instance \(its names: "
                                         r"node 'pair_b', .*'rock6'.*; mesh 'rock', 'floor'\)"):
        load_scene(rocks, bake="chair")


@pytest.mark.slow
def test_bake_is_refused_where_it_cannot_hold(tmp_path, rocks):
    obj = tmp_path / "box.obj"
    trimesh.creation.box().export(obj)
    with pytest.raises(InputError, match="matches no object or group"):
        load_scene(obj, bake="box")  # an OBJ's objects and groups (test_bake_obj.py)
    ply = tmp_path / "box.ply"
    trimesh.creation.box().export(ply)
    with pytest.raises(InputError, match="--bake names glTF nodes or OBJ objects"):
        load_scene(ply, bake="box")
    for other in (dict(exclude="floor"), dict(receive_only="floor"), dict(alpha_cutout=True),
                  dict(source=str(obj)), dict(quantities=("indirect",))):
        with pytest.raises(InputError, match="--bake"):
            BakeConfig(bake="rock1", **other)
    config = BakeConfig(bake="rock1")
    with pytest.raises(UsageError, match="--method discs builds its occluders"):
        placed.check("discs", "vertices", config)
    with pytest.raises(UsageError, match="a camera view"):
        placed.check("rays", "view", config)
    with pytest.raises(UsageError, match="--uv-set 1"):  # the set's atlas lays out set 0
        placed.check("rays", "texels", BakeConfig(bake="rock1", uv_set=1))
    placed.check("rays", "vertices", config)
    placed.check("rays", "texels", config)  # a lightmap of the set: a region per instance
    placed.check("discs", "texels", BakeConfig())  # nothing to check without --bake
    # a scene loaded without the selection: the occluders refuse, nothing bakes quietly
    with pytest.raises(InputError, match="loaded without it"):
        occluders.build(load_scene(rocks), config)


# --------------------------------------------------------------------------- tracing


@needs_native
@pytest.mark.parametrize("oracle", ["embree", pytest.param("reference", marks=pytest.mark.slow)])
def test_instances_answer_as_the_flattened_triangles(rocks, oracle):
    """Random rays from inside the cluster against the instanced backend and a backend of
    the flattened triangles (Embree's, and the float64 reference): the same answers but for
    rays grazing an edge."""
    from aobake.backends import BACKENDS
    from aobake.scene import face_normals

    scene = load_scene(rocks, bake="rock0")
    built = occluders.build(scene, BakeConfig())
    assert type(built.backend).__name__ == "InstancedEmbree"
    vertices, faces = placed.flattened(scene.instances)
    reference = BACKENDS[oracle](built.to_local(vertices), faces, face_normals(vertices, faces),
                                 built.step)
    rng = np.random.default_rng(4)
    n = 4000 if oracle == "embree" else 1500
    origins = built.to_local(rng.uniform([-3, -1, -3], [3, 1.5, 5], (n, 3))).astype(np.float32)
    directions = rng.normal(size=(n, 3))
    directions = (directions / np.linalg.norm(directions, axis=1)[:, None]).astype(np.float32)
    tmax = np.float32(0.5)
    hit = built.backend.occluded(origins, directions, tmax)
    assert 0.2 < hit.mean() < 0.8  # rays that hit and rays that miss
    assert np.count_nonzero(hit != reference.occluded(origins, directions, tmax)) <= 2
    t, prim = built.backend.intersect(origins, directions, tmax)
    t_ref, prim_ref = reference.intersect(origins, directions, tmax)
    agree = prim == prim_ref
    assert np.count_nonzero(~agree) <= 2
    both = agree & (prim >= 0)
    np.testing.assert_allclose(t[both], t_ref[both], rtol=1e-5, atol=1e-6)
    front = built.backend.front_distance(origins, directions, tmax)
    front_ref = reference.front_distance(origins, directions, tmax)
    assert np.count_nonzero(np.isfinite(front) != np.isfinite(front_ref)) <= 2
    # a mirrored placement's faces face outward, as Scene.dump's reversed ones do
    assert np.isfinite(front).mean() < hit.mean()


@needs_native
@pytest.mark.slow
def test_a_bake_through_instances_equals_the_flattened_bake_within_its_error_bars(rocks):
    scene = load_scene(rocks)
    traced = _bake(scene, seed=1, rays=128)
    flat = _bake(scene, seed=2, rays=128, instances="flatten")
    assert traced.report["parameters"]["instances"]["traced_as"].startswith("embree instances")
    assert flat.report["parameters"]["instances"]["traced_as"].startswith("flattened")
    assert 0.3 < traced.ao.mean() < 0.9
    _same_within_error_bars(traced.ao, flat.ao, traced.ao_stderr, flat.ao_stderr)
    # the same seed: the same rays, and hits that differ only where a ray grazes an edge
    same = _bake(scene, seed=2, rays=128)
    assert np.mean(same.ao == flat.ao) > 0.98
    assert np.abs(same.ao - flat.ao).max() <= 4 / 128


@needs_native
@pytest.mark.slow
def test_one_baked_instance_equals_its_place_in_the_whole_bake(rocks):
    whole = load_scene(rocks)
    inst = whole.instances
    k = list(inst.names).index("rock1")
    start, stop = inst.vertex_offsets[k], inst.vertex_offsets[k + 1]
    one = load_scene(rocks, bake="rock1")
    np.testing.assert_array_equal(one.vertices, whole.vertices[start:stop])
    a = _bake(one, seed=5, bake=("rock1",))
    b = _bake(whole, seed=6)
    _same_within_error_bars(a.ao, b.ao[start:stop], a.ao_stderr, b.ao_stderr[start:stop])
    # ... and the flattened tracing of the same selection, vertex by vertex, with the
    # bounded obscurance and back faces ignored (every query the instances answer)
    options = dict(quantities=("ao", "obscurance"), max_distance="20%", backfaces="ignore",
                   bake=("rock1",))
    c = _bake(one, seed=7, **options)
    d = _bake(one, seed=8, instances="flatten", **options)
    for name in ("ao", "obscurance"):
        _same_within_error_bars(c.values[name], d.values[name], c.values[f"{name}_stderr"],
                                d.values[f"{name}_stderr"])


@pytest.mark.slow
def test_backends_without_instances_flatten_for_tracing(rocks, caplog):
    one = load_scene(rocks, bake="rock1")
    with caplog.at_level("WARNING", logger="aobake.occluders"):
        built = occluders.build(one, BakeConfig(bake="rock1", backend="reference"))
    record = built.record()["instances"]
    assert record["traced_as"].startswith("flattened for tracing (--backend reference")
    assert "traced flattened" in caplog.text and "2892 triangles" in caplog.text
    with aobake._native.embreex_only():
        built = occluders.build(one, BakeConfig(bake="rock1"))
    assert "embreex traces" in built.record()["instances"]["traced_as"]


@needs_native
@pytest.mark.slow
def test_the_same_bits_for_every_split_and_thread_count(rocks):
    scene = load_scene(rocks, bake=("rock1", "rock2"))
    base = _bake(scene, rays=32, seed=3, bake=("rock1", "rock2"), threads=1)
    for run in (dict(threads=2, chunk_points=7), dict(threads=2, chunk_points=1000)):
        other = _bake(scene, rays=32, seed=3, bake=("rock1", "rock2"), **run)
        np.testing.assert_array_equal(base.ao, other.ao)
        np.testing.assert_array_equal(base.ao_stderr, other.ao_stderr)
        assert base.report["parameters"] == other.report["parameters"]


@pytest.mark.slow
@needs_native
def test_the_same_bits_on_processes(rocks):
    scene = load_scene(rocks, bake=("rock1", "rock2"))
    base = _bake(scene, rays=32, seed=3, bake=("rock1", "rock2"), threads=1)
    other = _bake(scene, rays=32, seed=3, bake=("rock1", "rock2"), executor="processes",
                  workers=2, chunk_points=50)
    np.testing.assert_array_equal(base.ao, other.ao)
    assert base.report["parameters"] == other.report["parameters"]


@pytest.mark.slow
@needs_native
def test_the_same_bits_on_dask(rocks):
    pytest.importorskip("distributed")
    from aobake.executors import dask as dask_executor

    scene = load_scene(rocks, bake=("rock1", "rock2"))
    base = _bake(scene, rays=32, seed=3, bake=("rock1", "rock2"), threads=1)
    with dask_executor.cluster(workers=2):
        other = _bake(scene, rays=32, seed=3, bake=("rock1", "rock2"), executor="dask",
                      chunk_points=60)
    np.testing.assert_array_equal(base.ao, other.ao)


# --------------------------------------------------------------------------- outputs


@pytest.mark.slow
def test_the_npz_cuts_the_bake_per_instance_and_compare_scores_it(rocks, tmp_path):
    from aobake.compare import compare

    scene = load_scene(rocks, bake=("rock*",))
    traced = _bake(scene, rays=64, seed=1, bake=("rock*",))
    flat = _bake(scene, rays=64, seed=2, bake=("rock*",), instances="flatten")
    aobake.write(traced, tmp_path / "traced.npz")
    aobake.write(flat, tmp_path / "flat.npz")
    slices = npz.instance_slices(tmp_path / "traced.npz")
    layout = traced.report["parameters"]["instances"]["layout"]
    assert [name for name, _, _ in slices] == [entry["name"] for entry in layout]
    assert len(slices) == 9 and slices[-1][1].stop == len(traced.positions)
    arrays = npz.read_npz(tmp_path / "traced.npz")
    inst = scene.instances
    for k, (name, vertices, faces) in enumerate(slices):
        i = inst.baked[k]
        np.testing.assert_array_equal(arrays["instance_transforms"][k], inst.transforms[i])
        own = arrays["faces"][faces] - vertices.start
        np.testing.assert_array_equal(np.sort(own, axis=1),
                                      np.sort(inst.meshes[inst.mesh[i]][1], axis=1))
    assert str(arrays["instance_meshes"][0]) == "rock"
    result = compare(tmp_path / "flat.npz", tmp_path / "traced.npz")
    assert result["matched_by"] == "order" and result["n"] == len(traced.positions)
    assert 0.7 < result["z_rms"] < 1.3
    # an ordinary bake has no instance arrays
    plain = aobake.bake(trimesh.creation.box(), rays=4)
    aobake.write(plain, tmp_path / "plain.npz")
    assert npz.instance_slices(tmp_path / "plain.npz") == []


@pytest.mark.slow
def test_the_glb_keeps_instances_sharing_their_geometry(rocks, tmp_path):
    """One POSITION / NORMAL / index accessor per mesh, a node and a colour per instance;
    read back (and compared) as the flattened bake's vertices."""
    from aobake.compare import compare
    from aobake.outputs import glb
    from aobake.outputs.gltf import read_gltf

    scene = load_scene(rocks, bake=("rock*", "floor"))
    traced = _bake(scene, rays=32, seed=1, bake=("rock*", "floor"))
    aobake.write(traced, tmp_path / "set.glb")
    aobake.write(_bake(scene, rays=32, seed=2, bake=("rock*", "floor"), instances="flatten"),
                 tmp_path / "flat.npz")
    gltf, _ = read_gltf(tmp_path / "set.glb")
    assert len(gltf["nodes"]) == 10 and len(gltf["meshes"]) == 10  # rock* is the mesh too
    primitives = [m["primitives"][0] for m in gltf["meshes"]]
    rocks_only = [p for m, p in zip(gltf["meshes"], primitives) if m["name"] == "rock"]
    assert len({p["attributes"]["POSITION"] for p in rocks_only}) == 1
    assert len({p["indices"] for p in rocks_only}) == 1
    assert len({p["attributes"]["COLOR_0"] for p in primitives}) == 10
    mirrored = [n for n in gltf["nodes"] if n["name"] == "rock6"][0]
    assert np.linalg.det(np.reshape(mirrored["matrix"], (4, 4))[:3, :3]) < 0
    table = glb.read(tmp_path / "set.glb")
    np.testing.assert_allclose(table.positions, traced.positions, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(table.faces, traced.faces)  # mirrored ones reversed back
    np.testing.assert_allclose(table.columns["_AO"], traced.ao, atol=1e-7)
    result = compare(tmp_path / "flat.npz", tmp_path / "set.glb")
    assert result["matched_by"] == "order" and result["n"] == len(traced.positions)


@pytest.mark.slow
def test_the_command_line_bakes_the_nodes_it_names(rocks, tmp_path):
    from conftest import run_cli

    result = run_cli(rocks, "--bake", "rock1", "--rays", "8", "--out", tmp_path / "one.npz")
    assert result.exit_code == 0, result.output
    assert [n for n, _, _ in npz.instance_slices(tmp_path / "one.npz")] == ["rock1"]


# --------------------------------------------------------------------------- memory


_MEMORY = textwrap.dedent("""
    import json, sys
    import numpy as np, trimesh
    from aobake import instances, occluders
    from aobake.scene import make_scene
    from aobake.settings import BakeConfig
    from dataclasses import replace
    n = int(sys.argv[1])
    mesh = trimesh.util.concatenate([trimesh.creation.icosphere(6),  # 81,920 + 20,480
                                     trimesh.creation.icosphere(5).apply_translation([3, 0, 0])])
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)
    transforms = np.tile(np.eye(4), (n, 1, 1))
    transforms[:, 0, 3] = 5.0 * np.arange(n)
    placed = instances.Instances(((v, f),), ("m",), np.zeros(n, np.int64), transforms,
                                 tuple(f"i{k}" for k in range(n)), tuple(f"i{k}" for k in range(n)),
                                 np.array([0]), np.array([0, len(v)]), np.array([0, len(f)]),
                                 instances.world_bounds(((v, f),), np.zeros(n, np.int64), transforms))
    scene = replace(make_scene(v, f), instances=placed)
    def status(key):
        with open("/proc/self/status") as lines:
            return next(int(line.split()[1]) for line in lines if line.startswith(key))
    with open("/proc/self/clear_refs", "w") as handle:  # the peak starts again from here
        handle.write("5")
    before = status("VmRSS:")
    built = occluders.build(scene, BakeConfig())
    hit = built.backend.occluded(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32), 10.0)
    print(json.dumps({"kib": status("VmHWM:") - before, "faces": len(f),
                      "backend": type(built.backend).__name__}))
""")


@pytest.mark.slow
@needs_native
def test_the_embree_scene_of_n_instances_does_not_grow_with_n():
    """Peak RSS of building the occluders of 1 and of 200 instances of a 100k-triangle mesh
    (a fresh process each): the 199 more placements cost far less than one more copy of
    the mesh's acceleration structure would (flattened: 200 copies, ~2 GiB)."""
    grown = {}
    for n in (1, 200):
        out = subprocess.run([sys.executable, "-c", _MEMORY, str(n)], capture_output=True,
                             text=True, check=True)
        grown[n] = json.loads(out.stdout.strip().splitlines()[-1])
    assert grown[1]["backend"] == "InstancedEmbree" and grown[1]["faces"] > 100_000
    one, many = grown[1]["kib"], grown[200]["kib"]
    assert one > 5_000  # the mesh's own structure: megabytes
    assert many < one + 8_000, grown  # 199 instances: a few KiB each, not the mesh again


def test_a_node_placed_by_trs_or_not_at_all_is_read_as_glTF_places_it():
    """glTF 2.0: a node's transform is its matrix, else translation x rotation x scale, each
    absent part the identity (a set's GLB leaves an instance placed at the origin without
    one); the instanced reader places each node so."""
    from aobake.outputs.glb import node_matrix

    rng = np.random.default_rng(4)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    t, s = rng.normal(size=3), rng.uniform(0.5, 2.0, size=3)
    node = {"translation": t.tolist(), "rotation": q.tolist(), "scale": s.tolist()}
    want = trimesh.transformations.compose_matrix(
        scale=s, angles=trimesh.transformations.euler_from_quaternion([q[3], *q[:3]]),
        translate=t)
    np.testing.assert_allclose(node_matrix(node), want, atol=1e-12)
    np.testing.assert_array_equal(node_matrix({}), np.eye(4))
    matrix = rng.normal(size=(4, 4))
    matrix[3] = [0, 0, 0, 1]
    np.testing.assert_array_equal(node_matrix({"matrix": matrix.T.reshape(-1).tolist()}), matrix)
