"""``--bake`` beyond glTF nodes, and comparing what it bakes (issue 34 point 2):

- an OBJ's objects and groups chosen by name (``object:``, ``group:``; a glob on both
  without a prefix), the rest of the file occluding: the scene is the chosen faces, their
  vertices in file order with the whole file's normals (a group sharing vertices with
  another keeps the whole mesh's normal there), the diagonal and ground plane the file's;
  the bake equals the whole file's bake at those vertices within the error bars; through
  the command line, the library, a batch manifest and the report; a lightmap of them;
- ``aobake compare`` of a subset bake (an OBJ's objects, some glTF instances) against the
  whole set's bake, either way round, vertex by vertex: by instance (node, mesh) and vertex
  index where both carry their instance layout, else by the place each vertex has in the
  whole set (the NPZ's ``source_vertex``, the metadata's ``parameters.instances.source``);
  a clear error where the files do not correspond.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh

import aobake
from aobake.compare import compare, format_table
from aobake.errors import InputError
from aobake.outputs import npz
from aobake.scene import load_scene

from analytic import z_bound
from conftest import run_cli
from test_instances import _set, needs_native


def _write_obj(path, parts, groups=()):
    """An OBJ of named parts: [(label, trimesh mesh)], each an ``o`` (``g`` where ``groups``
    names it instead), vertices in order."""
    lines, offset = [], 0
    for label, part in parts:
        lines.append(f"{'g' if label in groups else 'o'} {label}\n")
        lines += ["v %r %r %r\n" % tuple(v) for v in np.asarray(part.vertices).tolist()]
        lines += ["f %d %d %d\n" % tuple(f + 1 + offset) for f in np.asarray(part.faces)]
        offset += len(part.vertices)
    path.write_text("".join(lines))
    return str(path)


@pytest.fixture(scope="module")
def level(tmp_path_factory):
    """A floor, two crates and a barrel as OBJ objects."""
    root = tmp_path_factory.mktemp("subsets")
    floor = trimesh.creation.box((6.0, 0.2, 6.0)).apply_translation((0, -0.1, 0))
    crate_a = trimesh.creation.box((1.0, 1.0, 1.0)).apply_translation((0.0, 0.5, 0.0))
    crate_b = trimesh.creation.box((0.8, 0.8, 0.8)).apply_translation((1.05, 0.4, 0.2))
    barrel = trimesh.creation.cylinder(0.4, 1.2, sections=24).apply_translation((-1.0, 0.6, 0))
    return _write_obj(root / "level.obj", [("floor", floor), ("crate_a", crate_a),
                                           ("crate_b", crate_b), ("barrel", barrel)])


def _sphere_in_two_groups(path):
    """One connected sphere whose faces are split into two ``g`` groups (the upper and the
    lower half share the equator's vertices)."""
    sphere = trimesh.creation.icosphere(2)
    upper = sphere.triangles_center[:, 2] > 0
    lines = ["v %r %r %r\n" % tuple(v) for v in sphere.vertices.tolist()]
    for name, faces in (("upper", sphere.faces[upper]), ("lower", sphere.faces[~upper])):
        lines.append(f"g {name}\n")
        lines += ["f %d %d %d\n" % tuple(f + 1) for f in faces]
    path.write_text("".join(lines))
    return str(path), sphere


# --------------------------------------------------------------------------- OBJ


def test_an_objs_objects_are_chosen_by_name_and_the_rest_occludes(level):
    whole = load_scene(level)
    crates = load_scene(level, bake="crate*")
    record = crates.instances
    assert record.record()["baked"] == {"object": ["crate_a", "crate_b"]}
    assert len(crates.faces) == 24 and not record.everything
    np.testing.assert_array_equal(crates.vertices, whole.vertices[record.source_vertex])
    np.testing.assert_array_equal(crates.vertex_normals,
                                  whole.vertex_normals[record.source_vertex])
    np.testing.assert_array_equal(whole.faces[record.baked_faces],
                                  record.source_vertex[crates.faces])
    np.testing.assert_array_equal(crates.bounds, whole.bounds)  # the file's diagonal
    assert np.all(np.diff(record.source_vertex) > 0)  # file order
    # prefixes: one kind; the same set either way
    np.testing.assert_array_equal(load_scene(level, bake=("object:crate_a", "crate_b")).faces,
                                  crates.faces)
    with pytest.raises(InputError, match="matches no object or group.*'floor'"):
        load_scene(level, bake="chair*")
    with pytest.raises(InputError, match="not by material"):
        load_scene(level, bake="material:wood")
    with pytest.raises(InputError, match="matches no object or group"):
        load_scene(level, bake="group:crate_a")  # an object, not a group


def test_a_group_sharing_vertices_keeps_the_whole_meshs_normals(tmp_path):
    path, sphere = _sphere_in_two_groups(tmp_path / "sphere.obj")
    whole = load_scene(path)
    upper = load_scene(path, bake="group:upper")
    source = upper.instances.source_vertex
    np.testing.assert_array_equal(upper.vertex_normals, whole.vertex_normals[source])
    # at the equator the upper half's own faces alone would tilt the normal upward
    on_equator = np.abs(upper.vertices[:, 2]) < 1e-9
    assert on_equator.sum() > 4
    assert np.abs(upper.vertex_normals[on_equator, 2]).max() < 1e-9


def test_the_subset_bake_equals_the_whole_bake_at_its_vertices(level):
    whole = aobake.bake(level, rays=512, sampler="random", seed=1)
    crates = aobake.bake(level, rays=512, sampler="random", seed=2, bake="crate*")
    source = load_scene(level, bake="crate*").instances.source_vertex
    d = crates.ao - whole.ao[source]
    se = np.hypot(crates.ao_stderr, whole.ao_stderr[source])
    known = se > 0
    assert np.abs(d[known] / se[known]).max() <= z_bound(int(known.sum()), None)
    record = crates.report["parameters"]["instances"]
    assert record["traced_as"].startswith("the file's faces")
    assert record["source"]["vertex_runs"] == [[8, 24]]
    assert list(crates.report["config"]["bake"]) == ["crate*"]


@pytest.mark.slow
def test_the_command_line_a_manifest_and_a_lightmap(level, tmp_path):
    out = tmp_path / "crates.npz"
    done = run_cli(level, "--bake", "crate_b", "--bake", "object:crate_a", "--rays", 8,
                   "--out", out, "--report", tmp_path / "r.json")
    assert done.exit_code == 0, done.output
    arrays = npz.read_npz(out)
    assert arrays["source_vertex"].tolist() == list(range(8, 24))
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["config"]["bake"] == ["crate_b", "object:crate_a"]
    assert report["scene"]["instances"]["baked_faces"] == 24
    manifest = tmp_path / "level.jsonl"
    manifest.write_text(json.dumps({"mesh": level, "output": "barrel.ply", "rays": "4",
                                    "bake": "barrel"}) + "\n")
    done = run_cli("batch", manifest, "--out-dir", tmp_path / "out")
    assert done.exit_code == 0, done.output
    batch = json.loads(next((tmp_path / "out").glob("*.report.json")).read_text())
    assert batch["config"]["bake"] == ["barrel"]
    assert batch["scene"]["triangles"] < load_scene(level).faces.shape[0]
    # a lightmap of the chosen objects (a new atlas of their faces), the rest occluding
    image = tmp_path / "crates.exr"
    done = run_cli(level, "--bake", "crate*", "--rays", 8, "--resolution", 64, "--out", image,
                   "--report", tmp_path / "t.json")
    assert done.exit_code == 0, done.output
    texture = json.loads((tmp_path / "t.json").read_text())
    assert texture["scene"]["triangles"] == 24 and texture["texture"]["texels_covered"] > 100


def test_bake_of_some_objects_is_refused_with_the_face_roles(level):
    for other in (dict(exclude="floor"), dict(occluder_only="barrel")):
        with pytest.raises(InputError, match="--bake chooses what is baked"):
            aobake.bake(level, rays=4, bake="crate*", **other)


@pytest.mark.slow
def test_the_same_bits_on_processes(level):
    one = aobake.bake(level, rays=32, bake="crate*", threads=2)
    other = aobake.bake(level, rays=32, bake="crate*", threads=1, executor="processes",
                        workers=2, chunk_points=5)
    np.testing.assert_array_equal(one.ao, other.ao)


# --------------------------------------------------------------------------- compare


def test_compare_scores_some_objects_against_the_whole_file(level, tmp_path):
    aobake.write(aobake.bake(level, rays=256, sampler="random", seed=1), tmp_path / "whole.npz")
    aobake.write(aobake.bake(level, rays=256, sampler="random", seed=2, bake="crate*"),
                 tmp_path / "crates.npz")
    result = compare(tmp_path / "whole.npz", tmp_path / "crates.npz")
    assert result["matched_by"] == "source" and result["n"] == 16
    assert 0.5 < result["z_rms"] < 1.6
    assert "by their place in the whole set" in format_table(result)
    # either way round, and a heatmap over the whole file (0 where nothing was compared)
    reverse = compare(tmp_path / "crates.npz", tmp_path / "whole.npz",
                      heatmap=tmp_path / "crates_error.ply")
    assert reverse["n"] == 16 and math.isclose(reverse["rmse"], result["rmse"])
    # every format carries the metadata that places the vertices
    crates = aobake.bake(level, rays=64, sampler="random", seed=3, bake="crate*")
    for suffix in (".ply", ".glb"):
        aobake.write(crates, tmp_path / f"crates{suffix}")
        other = compare(tmp_path / "whole.npz", tmp_path / f"crates{suffix}")
        assert other["matched_by"] == "source" and other["n"] == 16
    # two subsets, one inside the other
    aobake.write(aobake.bake(level, rays=64, bake="crate_a"), tmp_path / "a.npz")
    assert compare(tmp_path / "crates.npz", tmp_path / "a.npz")["n"] == 8


def test_compare_says_when_the_files_do_not_correspond(level, tmp_path):
    aobake.write(aobake.bake(level, rays=16, bake="crate*"), tmp_path / "crates.npz")
    other = tmp_path / "other.obj"  # another file: a different vertex count
    _write_obj(other, [("crate", trimesh.creation.box())])
    aobake.write(aobake.bake(str(other), rays=16), tmp_path / "other.npz")
    with pytest.raises(InputError, match="not that set's whole bake"):
        compare(tmp_path / "other.npz", tmp_path / "crates.npz")
    moved = tmp_path / "moved.obj"  # the same counts, a crate moved
    text = open(level).read().replace("o crate_a", "o crate_a", 1)
    lines = text.splitlines(keepends=True)
    first = next(i for i, line in enumerate(lines) if line.startswith("v ")
                 and lines[i - 1].startswith("o crate_a"))
    x, y, z = (float(v) for v in lines[first].split()[1:])
    lines[first] = f"v {x + 0.3!r} {y!r} {z!r}\n"
    moved.write_text("".join(lines))
    aobake.write(aobake.bake(str(moved), rays=16), tmp_path / "moved.npz")
    with pytest.raises(InputError, match="are not where"):
        compare(tmp_path / "moved.npz", tmp_path / "crates.npz")
    aobake.write(aobake.bake(level, rays=16, bake="barrel"), tmp_path / "barrel.npz")
    with pytest.raises(InputError, match="neither bake holds the other's vertices"):
        compare(tmp_path / "barrel.npz", tmp_path / "crates.npz")


@pytest.fixture(scope="module")
def rocks(tmp_path_factory):
    return _set(tmp_path_factory.mktemp("subset_rocks") / "rocks.gltf")


@needs_native
@pytest.mark.slow
def test_compare_scores_some_instances_against_the_flattened_set(rocks, tmp_path):
    """A bake of two nodes (traced as Embree instances) against the flattened bake of the
    whole set: matched by node and vertex index; the NPZ places each vertex in the set."""
    aobake.write(aobake.bake(rocks, rays=128, sampler="random", seed=1, instances="flatten"),
                 tmp_path / "flat.npz")
    aobake.write(aobake.bake(rocks, rays=128, sampler="random", seed=2,
                             bake=("rock5", "pair_b")), tmp_path / "two.npz")
    result = compare(tmp_path / "flat.npz", tmp_path / "two.npz")
    arrays = npz.read_npz(tmp_path / "two.npz")
    assert result["matched_by"] == "instance" and result["n"] == len(arrays["positions"])
    assert 0.5 < result["z_rms"] < 1.6
    whole = npz.read_npz(tmp_path / "flat.npz")
    np.testing.assert_allclose(whole["positions"][arrays["source_vertex"]],
                               arrays["positions"], rtol=0, atol=1e-12)
    assert "source_vertex" not in whole  # the whole set is in its own order
    # a bake of another set of the same nodes' names is told apart
    other = _set(tmp_path / "other.gltf", extension=True)
    aobake.write(aobake.bake(other, rays=8, bake=("rock5",)), tmp_path / "other.npz")
    with pytest.raises(InputError, match="not the same set"):
        compare(tmp_path / "flat.npz", tmp_path / "other.npz")


@pytest.mark.slow
def test_compare_places_a_node_of_a_set_loaded_flat(tmp_path):
    """A glTF file that places no mesh twice loads flat (its bake has no instance layout):
    a bake of one node of it is lined up by its place in the whole set."""
    from gltf_scenes import write_instanced

    box, ball = trimesh.creation.box(), trimesh.creation.icosphere(2)
    path = write_instanced(tmp_path / "two.gltf",
                           [{"name": "box", "vertices": box.vertices, "faces": box.faces},
                            {"name": "ball", "vertices": ball.vertices, "faces": ball.faces}],
                           [{"name": "box", "mesh": 0},
                            {"name": "ball", "mesh": 1, "translation": [1.6, 0.0, 0.0]}])
    whole = aobake.bake(path, rays=64, seed=1)
    assert "instances" not in whole.report["parameters"]
    aobake.write(whole, tmp_path / "whole.npz")
    aobake.write(aobake.bake(path, rays=64, seed=2, bake="ball"), tmp_path / "ball.npz")
    result = compare(tmp_path / "whole.npz", tmp_path / "ball.npz")
    assert result["matched_by"] == "source" and result["n"] == len(ball.vertices)
