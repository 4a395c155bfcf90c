"""The pipeline's contracts: registries drive the CLI and the docs, a report reproduces its
bake, ``aobake.write`` gives the CLI's files, the report names the kernels that ran."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import trimesh
from conftest import run_cli
from readers import read_image

import aobake
from aobake.backends import BACKENDS
from aobake.settings import CHOICES, DEFAULTS, BakeConfig
from aobake.outputs.registry import WRITERS, markdown_table
from aobake.outputs.strictjson import to_jsonable
from aobake.quantities import FIELDS, QUANTITIES
from aobake.samplers import SAMPLERS

README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.fixture(scope="module")
def torus():
    return trimesh.creation.torus(major_radius=1.0, minor_radius=0.4, major_sections=24,
                                  minor_sections=12)


def _through_json(config: dict) -> dict:
    """What a report file gives back: strict JSON (inf as "inf", tuples as lists)."""
    return json.loads(json.dumps(to_jsonable(config), allow_nan=False))


def test_readme_output_table_is_the_registry():
    assert markdown_table() in README.read_text(), (
        "README's output table differs from aobake.outputs.registry.markdown_table(); "
        "paste the new table into the README")


def test_help_offers_every_registry_choice():
    text = run_cli("--help-on", "all").output
    for name in (*BACKENDS, *SAMPLERS, *QUANTITIES, *CHOICES["weighting"]):
        assert name in text, name
    for writer in WRITERS:
        assert writer.suffix in text, writer.suffix


def test_every_field_has_one_name_everywhere():
    for name, field in FIELDS.items():
        assert len(field.ply) == field.width
        assert field.exr == () or len(field.exr) == field.width
        assert field.gltf is None or field.gltf.startswith("_")
    for q in QUANTITIES.values():
        assert q.value.name == q.name and q.error.name in FIELDS
        assert set(q.conventions) == set(CHOICES["weighting"])


def test_config_round_trips_through_a_report_with_every_field_changed():
    changed = BakeConfig(quantities=("obscurance", "bent_normal"), rays=33, max_distance="7%",
                         tau=2.5, seed=9, sampler="random", replicates=6, weighting="uniform", normals="area",
                         fix_normals="fix", ground_plane=True, up_axis="z", backfaces="ignore",
                         ray_offset=2e-5,
                         backend="reference", embree_mode="fast", confidence=0.9,
                         tolerance=0.03, max_rays=1000,
                         resolution="48x32", padding=3,
                         texel_samples=9,
                         unwrap="always", bent_space="tangent", seams="off", denoise=True,
                         uv_set=1, uv_overlap="refuse", overlap_mask="overlap.png",
                         ao_from="bake.npz", albedo=0.25, bounces=3, discs_k=3.0,
                         discs_model="chapter", discs_passes=3, discs_weight=0.5, discs_kappa=2.0,
                         discs_traversal="brute", discs_indirect_passes=3,
                         discs_indirect_weight=0.5, hemicube_resolution=32,
                         depthmaps_directions=64, depthmaps_resolution=512, depthmaps_bias=0.75,
                         ssao_radius=0.25, ssao_samples=8, ssao_rotate=False, ssao_blur=False,
                         ssao_pattern=2, ssao_depth="opengl", ssao_normals="shading",
                         ssao_blur_depth=2.0, ssao_blur_normal=20.0, crytek_normalise="none",
                         crytek_range="depth", gtao_slices=2, gtao_steps=8,
                         gtao_multiplier=1.0, gtao_falloff=0.5, heightfield_thickness=0.1,
                         pixel_filter="box", pixel_samples=8, box_sampling="positions",
                         lightmap_filter="trilinear",
                         source="high.obj", cage_offset=0.25, low_occludes=True, alpha_cutout=True,
                         exclude=("a*",),
                         receive_only=("b",), occluder_only=("c",), instances="flatten")
    # keep_distances cannot go with a tolerance: the second config changes it
    kept = replace(changed, tolerance=None, keep_distances=True, cage_offset=None,
                   cage="cage.obj")
    # a texel density replaces the resolution: the third config sets it
    dense = replace(kept, resolution=DEFAULTS["resolution"], texel_density=12.5)
    # --bake goes with none of the groups, cut-outs or --from: a config of its own
    chosen = BakeConfig(bake=("node*", "mesh:rock"), instance_regions="mesh")
    assert all(getattr(changed, k) != v or getattr(kept, k) != v or getattr(dense, k) != v
               or getattr(chosen, k) != v for k, v in DEFAULTS.items()), "change every field"
    for config in (BakeConfig(), changed, kept, dense, chosen, BakeConfig(max_distance=0.5)):
        assert BakeConfig.from_dict(_through_json(config.to_dict())) == config
    with pytest.raises(ValueError, match="unknown configuration keys"):
        BakeConfig.from_dict({"rayz": 3})


def test_rebaking_from_the_report_config_gives_identical_bits(torus):
    first = aobake.bake(torus, rays=40, quantities=("ao", "obscurance", "bent_normal"),
                        max_distance="30%", sampler="stratified", seed=4)
    again = aobake.bake(torus, BakeConfig.from_dict(_through_json(first.report["config"])))
    assert first.fields().keys() == again.fields().keys()
    for name, array in first.fields().items():
        np.testing.assert_array_equal(array, again.fields()[name], err_msg=name)


@pytest.mark.slow
def test_rebaking_a_lightmap_from_the_report_config_gives_identical_bits(torus):
    first = aobake.bake_texels(torus, rays=8, resolution="40x24", padding=2, texel_samples=2,
                               quantities=("ao", "bent_normal"), bent_space="tangent", seed=3)
    config = BakeConfig.from_dict(_through_json(first.report["config"]))
    assert config.resolution == (40, 24) and config.bent_space == "tangent"
    again = aobake.bake_texels(torus, config)
    assert first.channels.keys() == again.channels.keys()
    for name, image in first.channels.items():
        np.testing.assert_array_equal(image, again.channels[name], err_msg=name)


def _npz(path):
    with np.load(path) as data:
        return {k: data[k] for k in data.files}


@pytest.mark.slow
def test_write_gives_the_files_the_cli_writes(torus, tmp_path):
    mesh = tmp_path / "torus.ply"
    torus.export(mesh)
    options = ["--rays", "16", "-q", "ao", "-q", "bent_normal", "--seed", "2"]
    res = run_cli(mesh, "--out", tmp_path / "cli.npz", "--report", tmp_path / "cli.json",
                  "--quiet", *options)
    assert res.exit_code == 0, res.output
    result = aobake.bake(mesh, rays=16, quantities=("ao", "bent_normal"), seed=2)
    written = aobake.write(result, tmp_path / "lib.npz", report=tmp_path / "lib.json",
                           mesh=mesh)
    assert written == [tmp_path / "lib.npz"]
    cli, lib = _npz(tmp_path / "cli.npz"), _npz(tmp_path / "lib.npz")
    assert cli.keys() == lib.keys()
    for name in cli:
        if name != "metadata":
            np.testing.assert_array_equal(cli[name], lib[name], err_msg=name)
    assert json.loads(str(cli["metadata"]))["config"] == json.loads(str(lib["metadata"]))["config"]
    assert json.loads((tmp_path / "lib.json").read_text())["outputs"] == [str(written[0])]


@pytest.mark.slow
def test_write_of_a_lightmap_writes_the_atlas_mesh_like_the_cli(tmp_path):
    mesh = tmp_path / "box.ply"
    trimesh.creation.box().export(mesh)  # no UVs: a new atlas, so a mesh to write
    res = run_cli(mesh, "--out", tmp_path / "cli.exr", "--resolution", 32, "--padding", 1,
                  "--rays", 4, "--quiet")
    assert res.exit_code == 0, res.output
    result = aobake.bake_texels(mesh, rays=4, resolution=32, padding=1)
    written = aobake.write(result, tmp_path / "lib.exr")
    assert written == [tmp_path / "lib.exr", tmp_path / "lib.obj"]
    a, names_a, _ = read_image(tmp_path / "cli.exr")
    b, names_b, _ = read_image(tmp_path / "lib.exr")
    assert names_a == names_b
    np.testing.assert_array_equal(a, b)
    assert (tmp_path / "cli.obj").read_text() == (tmp_path / "lib.obj").read_text()


def test_reference_backend_is_selectable_and_reported(tmp_path):
    plane = trimesh.creation.box(extents=[2, 2, 0.1])
    res = aobake.bake(plane, rays=8, backend="reference")
    assert res.report["parameters"]["backend"] == "reference"
    assert res.report["config"]["backend"] == "reference"
    out = tmp_path / "ao.npz"
    assert run_cli(tmp_path / "missing.obj", "--out", out, "--backend", "nope").exit_code == 2


def test_readme_lists_every_cli_option():
    """Every flag of the main command, aobake view and aobake batch is in the README."""
    from aobake.cli import main
    from aobake.cli.batch import batch_command
    from aobake.cli.view import view_command

    text = README.read_text()
    missing = sorted({f"{command.name}: {flag}"
                      for command in (main, view_command(), batch_command())
                      for param in command.params for flag in getattr(param, "opts", [])
                      if flag.startswith("--") and flag not in ("--help", "--version")
                      and flag not in text})
    assert not missing, missing


@pytest.mark.slow
def test_lazy_registries_resolve_every_plugin_and_a_vertex_bake_imports_none_it_does_not_need():
    """TARGETS, METHODS and EXECUTORS name their plugins without importing them (issue 21:
    the command's start-up cost); each name resolves to its class, whose ``name`` is the
    key, and a fresh interpreter's per-vertex bake never imports the lightmap target's
    stages, the screen-space methods, the hemicube's GL worker, the process pool or Dask."""
    import subprocess
    import sys

    from aobake.executors import EXECUTORS
    from aobake.methods import METHODS
    from aobake.methods.ssao import SCREEN_METHODS
    from aobake.targets import TARGETS

    for registry in (TARGETS, METHODS, EXECUTORS):
        for key in registry:
            assert registry[key] is registry[key]
    for key in METHODS:
        assert METHODS[key].name == key
    assert {k: METHODS[k] for k in SCREEN_METHODS} == SCREEN_METHODS
    assert TARGETS["texels"].name == "texels" and TARGETS["vertices"].name == "vertices"
    code = ("import sys, trimesh, aobake; aobake.bake(trimesh.creation.icosphere(1), rays=4); "
            "print(' '.join(sorted(m for m in sys.modules if m.startswith('aobake'))))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            check=True).stdout.split()
    for module in ("aobake.targets.texels.target", "aobake.targets.texels.atlas",
                   "aobake.targets.projected", "aobake.targets.view", "aobake.methods.ssao",
                   "aobake.methods.discs", "aobake.methods.hemicube", "aobake.screen.gbuffer",
                   "aobake.camera", "aobake.executors.dask", "aobake.executors.processes",
                   "aobake.compare"):
        assert module not in loaded, module
