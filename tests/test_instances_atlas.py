"""A lightmap of a set of instances (issue 34 point 2): one image with a region per baked
instance, each instance's material reading its region through ``KHR_texture_transform``
(``aobake.targets.texels.instanced``).

- the set's atlas is, bit for bit, the lightmap of the flattened scene whose own UVs are the
  atlas's (an OBJ of every instance placed), and each region is the lightmap of that
  instance's faces with every other instance occluding (the same OBJ, the others
  ``--occluder-only``): covered texels bit for bit without seam erasing, within the seam
  solver's tolerance with it; traced through Embree instances, within the error bars;
- the same bits for every split, thread count and executor;
- regions: disjoint, margins of ``padding`` texels, each instance's UVs inside its own, the
  same texels per scene unit on every instance (``density``) or one size per mesh
  (``mesh``); a mesh's own UVs used where they can be, else one xatlas atlas of the unique
  mesh shared by its instances;
- the GLB: instances share their geometry, each material's occlusion (and ORM) texture
  carries the instance's offset and scale; the Khronos validator and Blender's importer
  (``AOBAKE_BLENDER_PYTHON``: benchmarks/check_blender_instances.py) read it so;
- the command line, ``--bake`` of some instances, the report.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh

import aobake
from aobake import api
from aobake.errors import InputError
from aobake.outputs.gltf import read_gltf
from aobake.scene import load_scene
from aobake.settings import BakeConfig
from aobake.targets import TARGETS

from analytic import z_bound
from gltf_scenes import write_instanced
from test_instances import _rock, _rotation, needs_native

ROOT = Path(__file__).resolve().parent.parent
BLENDER_CHECK = ROOT / "benchmarks" / "check_blender_instances.py"
#: a small map, few rays: the checks are of layout and bits, not of AO's accuracy
BAKE = dict(rays=16, resolution=(128, 128), normals="angle")


def _own_uv_rock():
    """The rock split along the seams of a new atlas of it: (vertices, faces, uv), own UVs
    a lightmap can bake as they are."""
    from aobake.targets.texels.unwrap import unwrap

    rock = _rock()
    made = unwrap(np.asarray(rock.vertices), np.asarray(rock.faces), 64, 2, isolate=False)
    return np.asarray(rock.vertices)[made.vmapping], made.faces, made.uv


def _write_set(path, own_uvs=True):
    """Five rocks (turned, scaled unevenly, one mirrored, one small) on a floor; the rocks with
    their own UVs (or none), the floor without (a new atlas)."""
    if own_uvs:
        vertices, faces, uv = _own_uv_rock()
        rock = {"name": "rock", "vertices": vertices, "faces": faces, "uv": uv}
    else:
        mesh = _rock()
        rock = {"name": "rock", "vertices": mesh.vertices, "faces": mesh.faces}
    floor = trimesh.creation.box((7.0, 0.2, 7.0))
    meshes = [rock, {"name": "floor", "vertices": floor.vertices, "faces": floor.faces}]
    nodes = [{"name": "floor", "mesh": 1, "translation": [0.0, -1.3, 0.0]}]
    spots = [(0, 0), (2.1, 0.2), (-2.0, 0.4), (0.3, 2.2), (-0.2, -2.1)]
    for i, (x, z) in enumerate(spots):
        nodes.append({"name": f"rock{i}", "mesh": 0, "translation": [x, 0.0, z],
                      "rotation": _rotation([1, 2 - i, 0.5], 37 * i),
                      "scale": [1.0, 1.0 + 0.08 * i, 1.0 - 0.05 * i]})
    nodes[-2]["scale"] = [-1.0, 1.0, 1.0]  # a mirrored placement
    nodes[-1]["scale"] = [0.5, 0.5, 0.5]  # a small one: a smaller region
    return write_instanced(path, meshes, nodes)


@pytest.fixture(scope="module")
def sets(tmp_path_factory):
    root = tmp_path_factory.mktemp("atlas")
    return {"own": _write_set(root / "own.gltf"), "none": _write_set(root / "none.gltf", False),
            "root": root}


def _texels(mesh, **options):
    run = {k: options.pop(k) for k in ("threads", "executor", "workers", "chunk_points")
           if k in options}
    return api.run(BakeConfig(**{**BAKE, **options}), mesh, TARGETS["texels"](), **run)


def _flat_obj(result, path, scene, names=True) -> str:
    """The flattened scene of ``result`` (every instance placed, the set's vertices bit for
    bit) as an OBJ whose own UVs are the atlas's, one ``o`` per instance."""
    atlas, instances = result.atlas, scene.instances
    lines = ["v %r %r %r\n" % tuple(v) for v in scene.vertices.tolist()]
    lines += ["vt %r %r\n" % tuple(t) for t in atlas.uv.tolist()]
    for k, i in enumerate(instances.baked.tolist()):
        if names:
            lines.append(f"o {instances.names[i]}\n")
        f0, f1 = instances.face_offsets[k], instances.face_offsets[k + 1]
        for face in atlas.faces[f0:f1].tolist():
            lines.append("f " + " ".join(f"{atlas.source_vertex[c] + 1}/{c + 1}"
                                         for c in face) + "\n")
    Path(path).write_text("".join(lines))
    return str(path)


def _window(region):
    return (slice(region["y"], region["y"] + region["height"]),
            slice(region["x"], region["x"] + region["width"]))


# --------------------------------------------------------------------------- the layout


@pytest.mark.parametrize("kind", ["own", pytest.param("none", marks=pytest.mark.slow)])
def test_one_region_per_instance_each_holding_its_instance(sets, kind):
    result = _texels(sets[kind], padding=2)
    texture = result.report["texture"]
    record = texture["instances"]
    assert texture["atlas"] == "instance regions" and texture["uv_check"]["valid"]
    placed = record["placed"]
    assert sorted(r["name"] for r in placed) == ["floor", "rock0", "rock1", "rock2", "rock3",
                                                 "rock4"]
    layouts = {m["mesh"]: m["uvs"] for m in record["meshes"]}
    assert layouts == {"floor": "new xatlas atlas of the mesh",
                       "rock": "own UVs (set 0)" if kind == "own" else
                       "new xatlas atlas of the mesh"}
    width, height = texture["width"], texture["height"]
    owner = np.full((height, width), -1)
    scene = load_scene(sets[kind], normals_mode="angle")
    atlas, instances = result.atlas, scene.instances
    for k, region in enumerate(placed):
        rows, cols = _window(region)
        margin = (slice(rows.start - 2, rows.stop + 2), slice(cols.start - 2, cols.stop + 2))
        assert rows.start >= 2 and cols.start >= 2 and rows.stop <= height - 2 \
            and cols.stop <= width - 2
        assert (owner[margin] == -1).all(), "regions (with their margins) overlap"
        owner[margin] = k
        # the instance's UVs lie inside its region (texel space)
        f0, f1 = instances.face_offsets[k], instances.face_offsets[k + 1]
        uv = atlas.uv[atlas.faces[f0:f1].reshape(-1)]
        x, y = uv[:, 0] * width, (1.0 - uv[:, 1]) * height
        assert x.min() >= cols.start - 1e-6 and x.max() <= cols.stop + 1e-6
        assert y.min() >= rows.start - 1e-6 and y.max() <= rows.stop + 1e-6
        # offset and scale map the layout to these UVs
        transform = region["KHR_texture_transform"]
        assert transform["scale"] == region["uv_scale"]
    # the same texels per scene unit on every instance (the regions round up to whole texels)
    density = np.array([r["texels_per_unit"] for r in placed])
    assert density.max() / density.min() < 1.15, density
    assert np.isclose(record["texels_per_unit"], density, rtol=0.15).all()
    # the small rock has the smaller region, the mirrored one the same as its neighbours
    sizes = {r["name"]: r["width"] * r["height"] for r in placed}
    assert sizes["rock4"] < 0.4 * sizes["rock0"]


@pytest.mark.slow
def test_mesh_regions_give_every_instance_of_a_mesh_one_size(sets):
    result = _texels(sets["own"], instance_regions="mesh")
    placed = result.report["texture"]["instances"]["placed"]
    rocks = {(r["width"], r["height"]) for r in placed if r["mesh"] == "rock"}
    assert len(rocks) == 1
    assert result.report["config"]["instance_regions"] == "mesh"


@pytest.mark.slow
def test_a_texel_density_sizes_the_image(sets):
    result = _texels(sets["own"], resolution=(1024, 1024), texel_density=6.0)
    texture = result.report["texture"]
    assert texture["width"] == texture["height"] < 1024
    density = [r["texels_per_unit"] for r in texture["instances"]["placed"]]
    assert min(density) >= 6.0 * 0.99 and max(density) < 6.0 * 1.2


@pytest.mark.slow
def test_overlapping_own_uvs_get_one_new_atlas_of_the_mesh(tmp_path):
    rock = _rock()
    uv = np.asarray(rock.vertices)[:, :2] * 0.4 + 0.5  # a projection: front and back overlap
    path = write_instanced(tmp_path / "flat_uv.gltf",
                           [{"name": "rock", "vertices": rock.vertices, "faces": rock.faces,
                             "uv": uv}],
                           [{"name": "a", "mesh": 0}, {"name": "b", "mesh": 0,
                                                       "translation": [3.0, 0.0, 0.0]}])
    result = _texels(path)
    record = result.report["texture"]["instances"]
    assert [m["uvs"] for m in record["meshes"]] == ["new xatlas atlas of the mesh"]
    assert any("made a new atlas of the mesh" in w for w in result.report["warnings"])
    with pytest.raises(InputError, match="own UVs overlap"):
        _texels(path, uv_overlap="refuse")
    averaged = _texels(path, uv_overlap="average")
    assert [m["uvs"] for m in averaged.report["texture"]["instances"]["meshes"]] == \
        ["own UVs (set 0)"]


# --------------------------------------------------------------------------- the values


@pytest.mark.slow
def test_the_atlas_is_the_flattened_scenes_lightmap_in_its_uvs_bit_for_bit(sets, tmp_path):
    scene = load_scene(sets["own"], normals_mode="angle")
    result = _texels(sets["own"], instances="flatten")
    flat = _flat_obj(result, tmp_path / "flat.obj", scene)
    reference = _texels(flat)
    assert reference.report["texture"]["atlas"] == "mesh UVs"
    assert set(reference.channels) == set(result.channels)
    for name, image in result.channels.items():
        np.testing.assert_array_equal(image, reference.channels[name], err_msg=name)


@pytest.mark.parametrize("seams", ["off", pytest.param("erase", marks=pytest.mark.slow)])
def test_each_region_is_its_instances_lightmap_with_the_rest_occluding(sets, tmp_path, seams):
    """The flattened OBJ with every other instance --occluder-only: the region's covered
    texels bit for bit (seams off); seam erasing solves the whole map's seams at once, to
    its tolerance, so within a small fraction of the noise."""
    scene = load_scene(sets["own"], normals_mode="angle")
    result = _texels(sets["own"], instances="flatten", seams=seams)
    flat = _flat_obj(result, tmp_path / "flat.obj", scene)
    placed = result.report["texture"]["instances"]["placed"]
    by_name = {r["name"]: r for r in placed}
    for region in (by_name["rock1"], by_name["rock3"]):  # a rock, and the mirrored one
        others = tuple(r["name"] for r in placed if r["name"] != region["name"])
        alone = _texels(flat, seams=seams, occluder_only=others)
        window = _window(region)
        covered = alone.covered[window]
        assert covered.sum() > 50 and np.array_equal(covered, result.covered[window])
        got, want = result.channels["ao"][window][covered], alone.channels["ao"][window][covered]
        if seams == "off":
            np.testing.assert_array_equal(got, want)
            np.testing.assert_array_equal(result.channels["ao_stderr"][window][covered],
                                          alone.channels["ao_stderr"][window][covered])
            # the instance's faces alone as the scene (--bake of its OBJ object: other point
            # ids, another tracing frame), the rest occluding: within the error bars
            only = _texels(flat, seams=seams, bake=(region["name"],), sampler="random",
                           seed=7)
            assert np.array_equal(only.covered[window], covered)
            se = np.hypot(only.channels["ao_stderr"][window][covered],
                          alone.channels["ao_stderr"][window][covered])
            known = se > 0
            z = (only.channels["ao"][window][covered] - want)[known] / se[known]
            assert np.abs(z).max() <= z_bound(int(known.sum()), None)
        else:
            se = alone.channels["ao_stderr"][window][covered]
            assert np.abs(got - want).max() < 0.05 * float(np.median(se[se > 0]))


@pytest.mark.slow
@needs_native
def test_traced_as_instances_the_atlas_equals_the_flattened_within_its_error_bars(sets):
    traced = _texels(sets["own"], seams="off", rays=64, sampler="random", seed=3)
    flat = _texels(sets["own"], seams="off", rays=64, sampler="random", seed=4,
                   instances="flatten")
    assert traced.report["parameters"]["instances"]["traced_as"].startswith("embree instances")
    covered = traced.covered & flat.covered
    assert np.array_equal(traced.covered, flat.covered)
    a, b = traced.channels["ao"][covered], flat.channels["ao"][covered]
    se = np.hypot(traced.channels["ao_stderr"][covered], flat.channels["ao_stderr"][covered])
    known = se > 0
    z = (a - b)[known] / se[known]
    assert np.abs(z).max() <= z_bound(int(known.sum()), None), np.abs(z).max()
    assert abs(float((a - b).mean())) <= 4 * math.sqrt(float(np.sum(se ** 2))) / len(a)
    # the same seed: the same bits but for rays grazing an edge
    again = _texels(sets["own"], seams="off", rays=64, sampler="random", seed=4)
    same = np.mean(again.channels["ao"][covered] == b)
    assert same > 0.95, same


@pytest.mark.slow
def test_the_same_bits_for_every_split_and_thread_count(sets):
    one = _texels(sets["none"], threads=1)
    for options in (dict(threads=2, chunk_points=97), dict(threads=3, chunk_points=1000)):
        other = _texels(sets["none"], **options)
        for name, image in one.channels.items():
            np.testing.assert_array_equal(image, other.channels[name], err_msg=name)


@pytest.mark.slow
def test_the_same_bits_on_processes(sets):
    one = _texels(sets["none"], threads=2)
    other = _texels(sets["none"], threads=1, executor="processes", workers=2, chunk_points=200)
    for name, image in one.channels.items():
        np.testing.assert_array_equal(image, other.channels[name], err_msg=name)


@pytest.mark.slow
def test_the_same_bits_on_dask(sets):
    pytest.importorskip("distributed")
    from aobake.executors import dask as dask_executor

    one = _texels(sets["own"], threads=1, bake=("rock*",))
    with dask_executor.cluster(workers=2):
        other = _texels(sets["own"], executor="dask", chunk_points=300, bake=("rock*",))
    for name, image in one.channels.items():
        np.testing.assert_array_equal(image, other.channels[name], err_msg=name)


@pytest.mark.slow
def test_denoised_and_tangent_space_maps_of_a_set(sets, tmp_path):
    """The lightmap's other passes run on the set's atlas as on one mesh's."""
    result = _texels(sets["none"], quantities=("ao", "bent_normal"), denoise=True,
                     bent_space="tangent", rays=32)
    assert {"ao_denoised", "bent_normal.X"} <= set(result.channels)
    covered = result.covered
    bent = np.stack([result.channels[f"bent_normal.{a}"][covered] for a in "XYZ"], axis=1)
    lengths = np.linalg.norm(bent, axis=1)
    assert np.median(bent[lengths > 0, 2] / lengths[lengths > 0]) > 0.5  # around +Z
    aobake.write(result, tmp_path / "set.exr")


@pytest.mark.slow
def test_baking_some_instances_gives_their_regions_alone(sets):
    result = _texels(sets["own"], bake=("rock1", "rock3"))
    placed = result.report["texture"]["instances"]["placed"]
    assert sorted(r["name"] for r in placed) == ["rock1", "rock3"]
    assert list(result.report["config"]["bake"]) == ["rock1", "rock3"]
    # both at one density, filling the map as well as they can
    assert placed[0]["width"] > 40


# --------------------------------------------------------------------------- the files


def _glb_checks(path, result, orm=False):
    gltf, _ = read_gltf(path)
    placed = result.report["texture"]["instances"]["placed"]
    assert gltf["extensionsUsed"] == ["KHR_texture_transform"]
    assert [n["name"] for n in gltf["nodes"]] == [r["name"] for r in placed]
    assert len(gltf["images"]) == 1  # one atlas
    rocks = [m["primitives"][0] for m, n in zip(gltf["meshes"], gltf["nodes"])
             if n["name"].startswith("rock")]
    for key in ("POSITION", "NORMAL", "TEXCOORD_0"):  # shared by the rocks
        assert len({p["attributes"][key] for p in rocks}) == 1, key
    assert len({p["indices"] for p in rocks}) == 1
    assert len({p["material"] for p in rocks}) == len(rocks)  # each its own region
    for node, region in zip(gltf["nodes"], placed):
        primitive = gltf["meshes"][node["mesh"]]["primitives"][0]
        material = gltf["materials"][primitive["material"]]
        transform = material["occlusionTexture"]["extensions"]["KHR_texture_transform"]
        assert transform == region["KHR_texture_transform"]
        assert node["extras"]["aobake_region"] == [region["x"], region["y"], region["width"],
                                                   region["height"]]
        if orm:
            mr = material["pbrMetallicRoughness"]["metallicRoughnessTexture"]
            assert mr["extensions"]["KHR_texture_transform"] == transform
            assert mr["index"] == material["occlusionTexture"]["index"]
    mirrored = [n for n in gltf["nodes"] if n["name"] == "rock3"][0]
    assert np.linalg.det(np.reshape(mirrored["matrix"], (4, 4))[:3, :3]) < 0
    # the layout's UVs through the offset and scale are the flattened atlas's
    scene_uv = result.atlas.uv
    assert scene_uv.min() >= 0 and scene_uv.max() <= 1


@pytest.mark.slow
def test_base_colours_stay_on_the_own_uvs_beside_a_new_atlas(tmp_path):
    """A textured material: its base colour reads the mesh's own UVs (TEXCOORD_0); the
    occlusion the layout: the same set where the own UVs are the layout, TEXCOORD_1 where a
    new atlas was made (overlapping own UVs)."""
    from gltf_scenes import png

    vertices, faces, uv = _own_uv_rock()
    slab = trimesh.creation.box((3.0, 0.2, 3.0))
    flat_uv = np.asarray(slab.vertices)[:, [0, 2]] / 3.0 + 0.5  # top and bottom overlap
    path = write_instanced(
        tmp_path / "textured.glb",
        [{"name": "rock", "vertices": vertices, "faces": faces, "uv": uv},
         {"name": "slab", "vertices": slab.vertices, "faces": slab.faces, "uv": flat_uv}],
        [{"name": "slab", "mesh": 1, "translation": [0.0, -1.2, 0.0]},
         {"name": "r0", "mesh": 0}, {"name": "r1", "mesh": 0, "translation": [2.2, 0, 0]}],
        base_color_png=png(np.ones((4, 4))))
    result = _texels(path, rays=4)
    kinds = {m["mesh"]: m["uvs"] for m in result.report["texture"]["instances"]["meshes"]}
    assert kinds == {"rock": "own UVs (set 0)", "slab": "new xatlas atlas of the mesh"}
    out = tmp_path / "set.glb"
    aobake.write(result, out)
    gltf, _ = read_gltf(out)
    for node in gltf["nodes"]:
        primitive = gltf["meshes"][node["mesh"]]["primitives"][0]
        material = gltf["materials"][primitive["material"]]
        pbr = material["pbrMetallicRoughness"]
        assert pbr["baseColorTexture"]["texCoord"] == 0
        assert pbr["baseColorFactor"] == [0.8, 0.8, 0.8, 1.0]
        layout = 0 if node["name"].startswith("r") else 1
        assert material["occlusionTexture"]["texCoord"] == layout
        assert ("TEXCOORD_1" in primitive["attributes"]) == (layout == 1)
    assert len(gltf["images"]) == 2  # the atlas and the one base colour
    _validate(out)


@pytest.mark.slow
def test_an_orm_map_of_a_set_takes_g_and_b_from_a_texture_in_its_layout(tmp_path):
    """The meshes' own metallic-roughness texture is laid out in their own UVs, not in the
    regions: refused with the reason; --orm-from a texture of the atlas's size is used."""
    from aobake.errors import OutputError
    from aobake.outputs import image
    from gltf_scenes import png

    vertices, faces, uv = _own_uv_rock()
    path = write_instanced(tmp_path / "mr.glb",
                           [{"name": "rock", "vertices": vertices, "faces": faces, "uv": uv}],
                           [{"name": "a", "mesh": 0}, {"name": "b", "mesh": 0,
                                                       "translation": [2.2, 0.0, 0.0]}],
                           metallic_roughness_png=png(np.full((4, 4), 255, np.uint8)))
    result = _texels(path, rays=4, resolution=(64, 64))
    with pytest.raises(OutputError, match="one region per instance"):
        aobake.write(result, tmp_path / "orm.glb", orm=True)
    source = tmp_path / "mr_atlas.png"
    image.write_rgb(source, np.random.default_rng(1).random((64, 64, 3)))
    aobake.write(result, tmp_path / "orm.glb", orm_from=source)
    gltf, _ = read_gltf(tmp_path / "orm.glb")
    assert all("metallicRoughnessTexture" in m["pbrMetallicRoughness"]
               for m in gltf["materials"])


def _validate(path):
    from test_orm import _validator

    command = _validator()
    done = subprocess.run(command + [str(path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["issues"]["numErrors"] == 0, report["issues"]["messages"]
    assert report["issues"]["numWarnings"] == 0, report["issues"]["messages"]
    assert report["info"]["extensionsUsed"] == ["KHR_texture_transform"]


@pytest.mark.slow
@pytest.mark.parametrize("orm", [False, True])
def test_the_glb_keeps_instances_sharing_their_geometry_each_reading_its_region(sets, tmp_path,
                                                                               orm):
    from conftest import run_cli

    out = tmp_path / "set_ao.glb"
    report = tmp_path / "report.json"
    args = ["--orm"] if orm else []
    done = run_cli(sets["own"], "--out", out, "--target", "texels", "--rays", 8,
                   "--resolution", 128, "--report", report, *args)
    assert done.exit_code == 0, done.output
    result = _texels(sets["own"], rays=8, normals="file")
    _glb_checks(out, result, orm)
    recorded = json.loads(report.read_text())
    assert recorded["texture"]["instances"]["placed"] == \
        result.report["texture"]["instances"]["placed"]
    _validate(out)


@pytest.mark.slow
def test_the_command_line_writes_the_image_and_the_flattened_atlas_mesh(sets, tmp_path):
    from conftest import run_cli

    out = tmp_path / "set_ao.png"
    done = run_cli(sets["none"], "--out", out, "--rays", 8, "--resolution", 96,
                   "--bake", "rock*", "--report", tmp_path / "r.json")
    assert done.exit_code == 0, done.output
    # beside the image, the set itself (each mesh once, each instance reading its region),
    # not every instance flattened into an OBJ
    assert out.is_file() and (tmp_path / "set_ao.glb").is_file()
    assert not (tmp_path / "set_ao.obj").exists()
    gltf, _ = read_gltf(tmp_path / "set_ao.glb")
    assert gltf["extensionsUsed"] == ["KHR_texture_transform"] and len(gltf["nodes"]) == 5
    report = json.loads((tmp_path / "r.json").read_text())
    assert sorted(r["name"] for r in report["texture"]["instances"]["placed"]) == \
        [f"rock{i}" for i in range(5)]
    exr = tmp_path / "set_ao.exr"
    assert run_cli(sets["none"], "--out", exr, "--rays", 8, "--resolution", 96,
                   "--bake", "rock*", "--instance-regions", "mesh").exit_code == 0
    from readers import read_image

    _, _, attrs = read_image(exr)
    # asked for: the flattened set in the atlas's UVs; and where <stem>.glb is the input,
    # the set's GLB is <stem>.set.glb
    flat = tmp_path / "flat.obj"
    assert run_cli(sets["none"], "--out", tmp_path / "b.png", "--rays", 4, "--resolution", 64,
                   "--mesh-out", flat).exit_code == 0
    assert flat.read_text().count("\nf ") == len(load_scene(sets["none"]).faces)
    source = _write_set(tmp_path / "set.glb", own_uvs=False)
    done = run_cli(source, "--out", tmp_path / "set.png", "--rays", 4, "--resolution", 64)
    assert done.exit_code == 0 and (tmp_path / "set.set.glb").is_file(), done.output
    meta = json.loads(attrs["aobake:metadata"])
    assert meta["texture"]["instances"]["instance_regions"] == "mesh"


@pytest.mark.slow
def test_a_batch_manifest_bakes_a_set_to_an_atlas(sets, tmp_path):
    from conftest import run_cli

    manifest = tmp_path / "sets.jsonl"
    manifest.write_text(json.dumps({"mesh": sets["own"], "output": "set.exr", "rays": "4",
                                    "resolution": "64", "bake": "rock*",
                                    "instance_regions": "mesh"}) + "\n")
    done = run_cli("batch", manifest, "--out-dir", tmp_path / "out")
    assert done.exit_code == 0, done.output
    report = json.loads(next((tmp_path / "out").glob("*.report.json")).read_text())
    assert report["config"]["bake"] == ["rock*"]
    assert report["config"]["instance_regions"] == "mesh"
    assert len(report["texture"]["instances"]["placed"]) == 5


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("AOBAKE_BLENDER_PYTHON"),
                    reason="AOBAKE_BLENDER_PYTHON (a Python with bpy) not set")
@pytest.mark.parametrize("kind, orm", [("own", False), ("none", False), ("own", True)])
def test_blender_reads_each_instance_through_its_region(sets, tmp_path, kind, orm):
    out = tmp_path / "set.glb"
    aobake.write(_texels(sets[kind], rays=4), out, orm=orm)
    done = subprocess.run([os.environ["AOBAKE_BLENDER_PYTHON"], str(BLENDER_CHECK), str(out)],
                          capture_output=True, text=True, timeout=600)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert done.returncode == 0 and result["ok"], result
    assert result["objects"] == 6 and len(result["images"]) == 1
    if orm:
        assert all(entry["roughness_through_region"] for entry in result["instances"])
