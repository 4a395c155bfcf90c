"""compare refuses a camera view against a lightmap of the same size (issue 35): both are
images, but a view's pixels and a lightmap's texels are not the same points, so their
difference means nothing; the message names both kinds.  Two views are reported as a view
(``"target": "view"``), not as texels."""

from __future__ import annotations

import json

import pytest
import trimesh

import aobake
from aobake.compare import compare
from conftest import run_cli

SIZE = 32


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("kinds")
    mesh = tmp / "sphere.ply"
    trimesh.creation.icosphere(1).export(mesh)
    out = {}
    for name, seed in (("view", 1), ("view2", 2)):
        out[name] = tmp / f"{name}.exr"
        aobake.write(aobake.bake_view(mesh, size=(SIZE, SIZE), rays=8, seed=seed), out[name])
    out["lightmap"] = tmp / "lightmap.exr"
    aobake.write(aobake.bake_texels(mesh, resolution=SIZE, rays=8), out["lightmap"])
    return out


@pytest.mark.slow
@pytest.mark.parametrize("reference, candidate", [("view", "lightmap"), ("lightmap", "view")])
def test_library_refuses_a_view_against_a_lightmap(files, reference, candidate):
    with pytest.raises(aobake.InputError) as info:
        compare(files[reference], files[candidate])
    message = str(info.value)
    assert message.startswith(f"{files[candidate]}: holds ")
    assert "camera view" in message and "lightmap" in message
    assert str(files[reference]) in message


@pytest.mark.slow
def test_cli_refuses_a_view_against_a_lightmap(files):
    result = run_cli("compare", files["view"], files["lightmap"])
    assert result.exit_code == 1, result.output
    assert result.output.startswith(f"aobake: error: {files['lightmap']}: holds a lightmap")
    assert len(result.output.strip().splitlines()) == 1


def test_two_views_are_reported_as_a_view(files):
    record = compare(files["view"], files["view2"])
    assert record["target"] == "view" and record["matched_by"] == "pixel"
    assert record["screen"] is not None
    result = run_cli("compare", files["view"], files["view2"], "--json")
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["target"] == "view"


def test_two_lightmaps_are_still_texels(files):
    assert compare(files["lightmap"], files["lightmap"])["target"] == "texels"
