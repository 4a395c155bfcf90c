"""--texel-density D: texels per scene unit instead of a resolution.

A new atlas puts every chart at exactly D (charts are scaled to their surface area and
all by one scale, moved only by whole texels and quarter turns) in the smallest square
the packer fits them into; own UVs get the smallest square at which their mean density
reaches D.  Checked on generated meshes.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from aobake.api import bake_texels
from aobake.settings import BakeConfig
from aobake.errors import InputError
from aobake.targets.texels.charts import chart_texel_density
from aobake.targets.texels.unwrap import unwrap
from conftest import run_cli


def _sphere():
    # jittered: xatlas has crashed on finely subdivided regular icospheres (jpcy/xatlas#146)
    mesh = trimesh.creation.icosphere(subdivisions=3)
    rng = np.random.default_rng(2)
    return trimesh.Trimesh(mesh.vertices * (1 + rng.normal(scale=2e-3, size=(len(mesh.vertices), 1))),
                           mesh.faces, process=False)


@pytest.mark.parametrize("make, density, padding", [
    (_sphere, 20.0, 2), (_sphere, 45.0, 4), (lambda: trimesh.creation.box(extents=[2, 1, 3]), 12.5, 1),
])
@pytest.mark.slow
def test_every_chart_at_the_density_asked_for(make, density, padding):
    """Each chart's sqrt(UV texels / surface area) is D to rounding (the layout fixes the
    scale; only the image side is quantised), and the side is the smallest the charts'
    padded texels allow within the packer's slack: (N + 2P)^2 holds them, and the covered
    share is that of a dense atlas (>= 40%)."""
    mesh = make()
    un = unwrap(mesh.vertices, mesh.faces, 64, padding, texel_density=density)
    width, height = un.size
    assert width == height
    got = chart_texel_density(un.uv, un.faces, mesh.vertices[un.vmapping], un.faces, width, height)
    assert len(got) == un.charts
    np.testing.assert_allclose(got, density, rtol=1e-9)
    # the surface alone needs D^2 A texels: the side can never be below D sqrt(A)
    assert width >= density * math.sqrt(mesh.area)
    from aobake.targets.texels.raster import rasterize

    covered = np.unique(rasterize(un.uv, un.faces, width, height, 1, 0).texel).size
    assert covered / (width * height) >= 0.4


@pytest.mark.slow
def test_bake_at_a_texel_density_reports_and_reproduces(tmp_path):
    """The report records the density asked for, the size chosen and the charts at that
    density; its config rebuilds the same bake (the same size)."""
    path = tmp_path / "sphere.ply"
    _sphere().export(path)
    res = bake_texels(path, rays=4, texel_density=16.0, texel_samples=1)
    tex = res.report["texture"]
    assert tex["texel_density_requested"] == 16.0
    assert tex["width"] == tex["height"] == res.channels["ao"].shape[0]
    assert tex["chart_density"]["p50"] == pytest.approx(16.0, rel=1e-9)
    assert tex["chart_density"]["spread"] == pytest.approx(1.0, abs=1e-9)
    config = BakeConfig.from_dict(res.report["config"])
    assert config.texel_density == 16.0
    again = bake_texels(path, config)
    assert again.report["texture"]["width"] == tex["width"]
    np.testing.assert_array_equal(again.channels["ao"], res.channels["ao"])


def test_own_uvs_get_the_side_that_reaches_the_density(tmp_path):
    """A unit square with UVs over half of [0, 1]^2 (area 1/2): the mean density at side N
    is N sqrt(1/2), so D = 10 needs N = ceil(10 sqrt(2)) = 15."""
    path = tmp_path / "quad.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
                    "vt 0 0\nvt 1 0\nvt 1 0.5\nvt 0 0.5\nvn 0 0 1\n"
                    "f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n")
    res = bake_texels(path, rays=4, texel_density=10.0, texel_samples=1)
    tex = res.report["texture"]
    assert tex["atlas"] == "mesh UVs"
    assert tex["width"] == tex["height"] == math.ceil(10 * math.sqrt(2))


@pytest.mark.parametrize("value", [0, -1.0, float("nan"), float("inf"), "dense", True])
def test_bad_texel_density_is_refused(value):
    with pytest.raises(InputError, match="texel density"):
        BakeConfig(texel_density=value)


def test_texel_density_and_resolution_exclude_each_other(tmp_path):
    with pytest.raises(InputError, match="not both"):
        BakeConfig(texel_density=10.0, resolution=512)
    path = tmp_path / "sphere.ply"
    _sphere().export(path)
    res = run_cli(path, "--out", tmp_path / "ao.exr", "--texel-density", "10",
                  "--resolution", "64")
    assert res.exit_code == 2 and "not both" in res.output
    res = run_cli(path, "--out", tmp_path / "ao.exr", "--texel-density", "0")
    assert res.exit_code == 2 and "--texel-density" in res.output
    assert not (tmp_path / "ao.exr").exists()


@pytest.mark.slow
def test_too_large_an_image_is_refused_before_charting(tmp_path):
    """A density whose surface alone needs more than MAX_RESOLUTION per side: one clear
    error naming the density and the size, before xatlas runs."""
    path = tmp_path / "sphere.ply"
    _sphere().export(path)
    res = run_cli(path, "--out", tmp_path / "ao.exr", "--texel-density", "1e5")
    assert res.exit_code == 1
    assert "texel density 100000 needs an image of at least" in res.output
    assert "16384" in res.output and "Traceback" not in res.output
    assert not (tmp_path / "ao.exr").exists()


@pytest.mark.slow
def test_cli_bake_at_a_texel_density(tmp_path):
    path = tmp_path / "sphere.ply"
    _sphere().export(path)
    res = run_cli(path, "--out", tmp_path / "ao.exr", "--texel-density", "12", "--rays", "4",
                  "--texel-samples", "1")
    assert res.exit_code == 0, res.output
    assert "texel density 12-12 per scene unit" in res.output


@pytest.mark.slow
def test_the_sparse_chart_warning_names_the_option_in_use():
    """Too few texels per chart: with --texel-density the advice is to raise the density
    (a resolution cannot be given with it), else the resolution."""
    import trimesh

    import aobake

    mesh = trimesh.creation.icosphere(3)
    dense = aobake.bake_texels(mesh, rays=1, texel_density=2.0, padding=1)
    sized = aobake.bake_texels(mesh, rays=1, resolution=8, padding=1)
    for result, option, other in ((dense, "--texel-density", "--resolution"),
                                  (sized, "--resolution", "--texel-density")):
        advice = [w for w in result.report["warnings"] if "or lower --padding" in w]
        assert advice and option in advice[0] and other not in advice[0]
