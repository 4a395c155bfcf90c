"""``--method file --ao-from BAKE``: a per-vertex bake's values interpolated on the surface
(how a user looks at a bake with ``aobake view``)."""

from __future__ import annotations

import numpy as np
import pytest

import aobake
from aobake import camera as cameras
from aobake.outputs import write_vertices

from analytic import quad
from conftest import run_cli

#: float32 storage of P and of the values, and a few float64 roundings
F32 = 8 * 2.0 ** -24


def _linear(points):
    """A per-vertex field that barycentric interpolation reproduces exactly: affine in x, y."""
    return 0.25 + 0.1 * points[:, 0] + 0.05 * points[:, 1]


@pytest.fixture
def plane(tmp_path):
    mesh = quad([0.0, 0.0, 0.0], 2.0, 1.5)
    path = tmp_path / "plane.ply"
    mesh.export(path)
    scene = aobake.load_scene(path)
    bake = tmp_path / "bake.npz"
    write_vertices(bake, scene.vertices, scene.faces, {"ao": _linear(scene.vertices)}, {})
    return path, bake


@pytest.mark.slow
def test_view_interpolates_the_bake_at_every_pixel(plane):
    path, bake = plane
    cam = cameras.look_at([0.3, -0.2, 3.0], [0.1, 0.1, 0.0], [0.0, 1.0, 0.0], 60.0,
                          size=(40, 30))
    view = aobake.bake_view(path, camera=cam, method="file", ao_from=str(bake))
    ch = view.channels
    assert view.covered.any() and "ao_stderr" not in ch and "rays" not in ch
    rec = view.report["camera"]
    m = np.array(rec["world_to_view"])
    p = np.stack([ch[f"P.{a}"][view.covered] for a in "XYZ"], 1).astype(np.float64)
    world = (p - m[:3, 3]) @ m[:3, :3]
    np.testing.assert_allclose(ch["ao"][view.covered], _linear(world), rtol=F32, atol=F32)
    assert view.report["parameters"]["method"] == "file"
    assert "rays_cast" not in view.report and view.report["error"] == {}


@pytest.mark.slow
def test_a_bake_of_another_mesh_is_refused(plane, tmp_path):
    path, _ = plane
    other = tmp_path / "other.npz"
    write_vertices(other, np.zeros((5, 3)), np.array([[0, 1, 2]]), {"ao": np.ones(5)}, {})
    with pytest.raises(aobake.InputError, match="other.npz: 5 vertices"):
        aobake.bake_view(path, method="file", ao_from=str(other), size=(8, 6))


@pytest.mark.slow
def test_cli_ao_from_picks_the_file_method(plane, tmp_path):
    path, bake = plane
    out = tmp_path / "look.png"
    result = run_cli("view", path, "--ao-from", bake, "--out", out, "--size", "16x12")
    assert result.exit_code == 0, result.output
    assert out.exists() and "method file, no rays" in result.output
    clash = run_cli("view", path, "--ao-from", bake, "--method", "rays", "--out",
                    tmp_path / "x.png")
    assert clash.exit_code == 2 and "--method file" in clash.output


@pytest.mark.slow
def test_vertices_have_no_triangle_to_interpolate_on(plane, tmp_path):
    path, bake = plane
    result = run_cli(path, "--ao-from", bake, "--out", tmp_path / "again.npz")
    # refused before anything is read: the method's need against what the target provides
    assert result.exit_code == 2
    assert "aobake: error:" in result.output and "a lightmap or a view" in result.output
    assert "per-vertex bake (vertices) has none" in result.output
