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


@pytest.mark.slow
def test_ao_from_implies_the_file_method_in_the_library(plane, tmp_path):
    """``ao_from`` given and no method named reads the bake (as ``--ao-from`` does), through
    keywords, a BakeConfig and ``bake_file``; another method named with it is the CLI's usage
    error, not a ray-traced view that ignores the file."""
    path, bake = plane
    for view in (aobake.bake_view(path, ao_from=str(bake), size=(8, 6)),
                 aobake.bake_view(path, aobake.BakeConfig(ao_from=str(bake)), size=(8, 6))):
        assert view.report["parameters"]["method"] == "file"
        assert view.report["parameters"]["ao_from"] == str(bake)
        assert "rays_cast" not in view.report
    result, _ = aobake.bake_file(path, tmp_path / "look.exr", {"ao_from": str(bake)},
                                 view={"size": (8, 6)})
    assert result.report["parameters"]["method"] == "file"
    with pytest.raises(aobake.UsageError, match="it goes with --method file, not --method rays"):
        aobake.bake_view(path, ao_from=str(bake), method="rays", size=(8, 6))
    with pytest.raises(aobake.UsageError, match="--method file, not --method rays"):
        aobake.bake_file(path, tmp_path / "x.exr", {"ao_from": str(bake)}, method="rays",
                         view={"size": (8, 6)})
    # a per-vertex bake: the file method's own refusal, as on the command line
    # (test_vertices_have_no_triangle_to_interpolate_on), not rays that ignore the file
    with pytest.raises(aobake.UsageError, match="per-vertex bake \\(vertices\\) has none"):
        aobake.bake(path, ao_from=str(bake))


@pytest.mark.slow
def test_a_manifest_row_with_ao_from_reads_the_bake(plane, tmp_path):
    """A batch manifest's ``ao_from`` picks the file method as ``--ao-from`` does; with
    ``--method rays`` named, that asset fails with the usage error (the others bake)."""
    import json

    from aobake import batch
    from aobake.cli.batch import batch_command
    from click.testing import CliRunner

    path, bake = plane
    manifest = tmp_path / "m.jsonl"
    manifest.write_text(json.dumps({"mesh": str(path), "output": "look.exr",
                                    "ao_from": str(bake)}) + "\n")
    for named, status in (((), "ok"), (("--method", "rays"), "failed")):
        out = tmp_path / f"out{len(named)}"
        args = [str(manifest), "--out-dir", str(out), "--resolution", "8", *named]
        result = CliRunner().invoke(batch_command(), args)
        summary = json.loads((out / batch.SUMMARY_NAME).read_text())
        record, = summary["assets"]
        assert record["status"] == status, (result.output, record)
    report = json.loads((tmp_path / "out0" / ("look.exr" + batch.REPORT_SUFFIX)).read_text())
    assert report["parameters"]["method"] == "file"
    assert "--method file, not --method rays" in record["error"]
