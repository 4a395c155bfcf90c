"""The CLI through click's CliRunner: help, bad options, end-to-end bakes, errors."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from conftest import run_cli
from readers import read_glb

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def mesh_path(tmp_path):
    mesh = trimesh.util.concatenate([trimesh.creation.icosphere(subdivisions=2),
                                     trimesh.creation.box(extents=[4, 0.2, 4])])
    path = tmp_path / "scene.obj"
    mesh.export(path)
    return path


def test_help_states_conventions():
    res = run_cli("--help")
    assert res.exit_code == 0
    assert "1 = fully open, 0 = fully occluded" in res.output
    for flag in ("--quantity", "--max-distance", "--sampler", "--weighting", "--ground-plane"):
        assert flag in res.output


@pytest.mark.parametrize("args, text", [
    (["--rays", "0"], "--rays"),
    (["--max-distance", "-1"], "max distance"),
    (["--max-distance", "abc"], "max-distance"),
    (["--tau", "-2"], "tau"),
    (["--sampler", "halton"], "sampler"),
    (["-q", "gi"], "quantity"),
])
def test_bad_options_exit_2(mesh_path, tmp_path, args, text):
    res = run_cli(mesh_path, "--out", tmp_path / "o.npz", *args)
    assert res.exit_code == 2
    assert text in res.output
    assert not (tmp_path / "o.npz").exists()


def test_end_to_end_npz_and_report(mesh_path, tmp_path):
    out, rep = tmp_path / "ao.npz", tmp_path / "report.json"
    res = run_cli(mesh_path, "--out", out, "-q", "ao", "-q", "obscurance", "-q", "bent-normal",
              "--rays", 32, "--max-distance", "25%", "--report", rep, "--quiet")
    assert res.exit_code == 0, res.output
    data = np.load(out)
    n = len(data["positions"])
    for key, shape in (("ao", (n,)), ("ao_stderr", (n,)), ("obscurance", (n,)),
                       ("bent_normal", (n, 3)), ("rays", (n,)), ("normals", (n, 3))):
        assert data[key].shape == shape
    report = json.loads(rep.read_text())
    assert report["config"]["max_distance"] == "25%"
    assert report["parameters"]["max_distance"] == pytest.approx(0.25 * report["scene"]["diagonal"])
    assert report["parameters"]["query"] == "distance"  # obscurance needs hit distances
    for key in ("rays_cast", "wall_time_s", "rays_per_second", "versions", "warnings", "error"):
        assert key in report
    assert report["error"]["ao"]["stderr_p95"] >= report["error"]["ao"]["stderr_mean"] * 0.5
    assert {"aobake", "embreex", "trimesh", "numpy"} <= set(report["versions"])


def test_ao_only_uses_occlusion_queries(mesh_path, tmp_path):
    rep = tmp_path / "r.json"
    assert run_cli(mesh_path, "--out", tmp_path / "a.ply", "--rays", 8, "--report", rep).exit_code == 0
    assert json.loads(rep.read_text())["parameters"]["query"] == "occluded"


def test_ply_and_glb_outputs_line_up(mesh_path, tmp_path):
    for ext in ("ply", "glb"):
        out = tmp_path / f"ao.{ext}"
        assert run_cli(mesh_path, "--out", out, "--rays", 8, "--quiet").exit_code == 0
    npz = tmp_path / "ao.npz"
    run_cli(mesh_path, "--out", npz, "--rays", 8, "--quiet")
    ref = np.load(npz)
    ply = trimesh.load(tmp_path / "ao.ply", process=False)
    np.testing.assert_allclose(ply.vertices, ref["positions"])
    raw = ply.metadata["_ply_raw"]["vertex"]["data"]
    np.testing.assert_allclose(raw["ao"], ref["ao"], atol=1e-7)
    gltf, _ = read_glb(tmp_path / "ao.glb")
    assert "_AO" in gltf["meshes"][0]["primitives"][0]["attributes"]


@pytest.mark.parametrize("name, content, message", [
    ("missing.obj", None, "no such file"),
    ("x.dae", b"x", "unsupported mesh format"),
    ("e.obj", b"", "empty"),
    ("n.obj", b"v 0 0 0\n", "no faces"),
    ("c.ply", b"ply\x00\xff garbage", "cannot read"),
    ("nan.obj", b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN"),
])
def test_bad_input_one_line_error_no_output(tmp_path, name, content, message):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    out = tmp_path / "out.ply"
    res = run_cli(path, "--out", out)
    assert res.exit_code == 1
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("aobake: error:")
    assert str(path) in lines[0] and message in lines[0]
    assert "Traceback" not in res.output
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if "aobake-unfinished" in p.name]


def test_refuses_to_overwrite_input(mesh_path, box_ply):
    before = mesh_path.read_bytes()
    res = run_cli(mesh_path, "--out", mesh_path)
    assert res.exit_code == 1
    assert "unsupported output format" in res.output or "overwrite" in res.output
    ply_before = box_ply.read_bytes()
    res = run_cli(box_ply, "--out", box_ply)
    assert res.exit_code == 1 and "refusing to overwrite the input" in res.output
    assert mesh_path.read_bytes() == before and box_ply.read_bytes() == ply_before


def test_unsupported_output_and_missing_directory(mesh_path, tmp_path):
    res = run_cli(mesh_path, "--out", tmp_path / "ao.txt")
    assert res.exit_code == 1 and "unsupported output format" in res.output
    res = run_cli(mesh_path, "--out", tmp_path / "nope" / "ao.ply")
    assert res.exit_code == 1 and "does not exist" in res.output


@pytest.mark.slow
@pytest.mark.parametrize("entry", [["-m", "aobake"], [str(ROOT / "cli.py")]], ids=["python-m", "shim"])
def test_python_m_and_shim(mesh_path, tmp_path, entry):
    out = tmp_path / "m.npz"
    proc = subprocess.run([sys.executable, *entry, str(mesh_path), "--out", str(out), "--rays", "4",
                           "--quiet"], capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert out.exists()


@pytest.mark.slow
@pytest.mark.parametrize("entry", [["-m", "aobake"], [str(ROOT / "cli.py")]], ids=["python-m", "shim"])
def test_process_entry_flushes_and_keeps_the_exit_status(mesh_path, tmp_path, entry):
    """The entry ends the process without the interpreter's teardown: what was printed to
    pipes still arrives, the report is complete, and the status is main's."""
    out, report = tmp_path / "m.ply", tmp_path / "m.json"
    proc = subprocess.run([sys.executable, *entry, str(mesh_path), "--out", str(out), "--rays", "4",
                           "--report", str(report)], capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.rstrip().splitlines()[-1].startswith("aobake: ") and " rays in " in proc.stderr
    assert json.loads(report.read_text())["points"] > 0
    bad = subprocess.run([sys.executable, *entry, str(tmp_path / "none.obj"), "--out", str(out)],
                         capture_output=True, text=True, cwd=ROOT)
    assert bad.returncode == 1 and bad.stderr.startswith("aobake: error: ")
    usage = subprocess.run([sys.executable, *entry], capture_output=True, text=True, cwd=ROOT)
    assert usage.returncode == 2 and "Missing argument" in usage.stderr
    shown = subprocess.run([sys.executable, *entry, "--help"], capture_output=True, text=True,
                           cwd=ROOT)
    assert shown.returncode == 0 and shown.stdout.startswith("Usage: ")


@pytest.mark.parametrize("report_name, out_name", [("x.npz", "x.npz"), ("ao.obj", "ao.exr")])
def test_outputs_must_be_distinct_files(mesh_path, tmp_path, report_name, out_name):
    """--report over --out (or over the default --mesh-out) is refused before any work."""
    out = tmp_path / out_name
    res = run_cli(mesh_path, "--out", out, "--report", tmp_path / report_name, "--rays", 4,
                  "--resolution", 32)
    assert res.exit_code == 1, res.output
    assert "every output needs its own file" in res.output and "Traceback" not in res.output
    assert list(tmp_path.iterdir()) == [mesh_path]
    # Through a symlink too.
    link = tmp_path / "link.npz"
    link.symlink_to(tmp_path / "x.npz")
    res = run_cli(mesh_path, "--out", tmp_path / "x.npz", "--report", link, "--rays", 4)
    assert res.exit_code == 1 and "every output needs its own file" in res.output


def test_failed_output_leaves_nothing_behind(mesh_path, tmp_path, monkeypatch):
    """The outputs are one transaction: a report that cannot be written takes the already
    written --out with it (and no temporary file stays)."""
    from aobake.outputs import strictjson as report

    def fail(path, data):
        from aobake.outputs.atomic import atomic_path

        with atomic_path(path) as tmp:
            tmp.write_text("{")
            raise OSError(28, "No space left on device")

    monkeypatch.setattr(report, "write_report", fail)
    res = run_cli(mesh_path, "--out", tmp_path / "x.npz", "--report", tmp_path / "r.json",
                  "--rays", 4)
    assert res.exit_code == 1 and "Traceback" not in res.output
    assert res.output.strip() == f"aobake: error: {tmp_path / 'r.json'}: no space left on device"
    assert sorted(p.name for p in tmp_path.iterdir()) == [mesh_path.name]


@pytest.mark.slow
def test_sigterm_cleans_up_and_exits_143(mesh_path, tmp_path):
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "ao.npz"
    proc = subprocess.Popen([sys.executable, "-m", "aobake", str(mesh_path), "--out", str(out),
                             "--rays", "1000000", "--threads", "1"],
                            stderr=subprocess.PIPE, text=True)
    time.sleep(3.0)  # imports (~1 s) done, handlers installed, tracing (minutes) under way
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert err.strip().splitlines()[-1] == "aobake: error: terminated (SIGTERM): no output written"
    assert sorted(p.name for p in tmp_path.iterdir()) == [mesh_path.name]


@pytest.mark.parametrize("value", ["0", "10x0", "abc", "3x4x5"])
def test_bad_resolution_is_a_usage_error(mesh_path, tmp_path, value):
    res = run_cli(mesh_path, "--out", tmp_path / "ao.exr", "--resolution", value)
    assert res.exit_code == 2 and "--resolution" in res.output
    assert not (tmp_path / "ao.exr").exists()


def test_directory_as_mesh_gets_the_one_line_error(tmp_path):
    res = run_cli(tmp_path, "--out", tmp_path / "ao.npz")
    assert res.exit_code == 1
    assert res.output.strip() == f"aobake: error: {tmp_path}: is a directory, not a mesh file"


def test_unsupported_out_lists_the_formats_of_both_targets(mesh_path, tmp_path):
    res = run_cli(mesh_path, "--out", tmp_path / "ao.xyz")
    assert res.exit_code == 1
    assert "per vertex .npz, .ply, .glb" in res.output and "lightmap .exr, .png" in res.output


def test_absurd_ray_counts_are_refused_up_front(mesh_path, tmp_path, monkeypatch):
    """A usage error naming the limit, before the mesh is even read (the audit: 41 s, then a
    crash for memory)."""
    import importlib

    import aobake

    def never(*args, **kwargs):
        raise AssertionError("the mesh was loaded")

    monkeypatch.setattr(importlib.import_module("aobake.api"), "load_scene", never)
    res = run_cli(mesh_path, "--out", tmp_path / "ao.npz", "--rays", 10**12)
    assert res.exit_code == 2 and "16777216" in res.output
    assert not (tmp_path / "ao.npz").exists()
    with pytest.raises(aobake.InputError, match="limit of 16777216"):
        aobake.BakeConfig(rays=2**24 + 1)


def test_huge_tau_gives_no_stray_warning(mesh_path, tmp_path):
    res = run_cli(mesh_path, "--out", tmp_path / "ao.npz", "-q", "obscurance", "--tau", "1e308",
                  "--rays", 8)
    assert res.exit_code == 0 and "Warning" not in res.output


@pytest.mark.parametrize("options, message", [
    (dict(rays=0), "rays must be a positive integer"),
    (dict(max_distance=-1), "max distance"),
    (dict(tau="x"), "tau must be a number"),
    (dict(seed=-1), "seed"),
    (dict(sampler="halton"), "sampler"),
    (dict(quantities=("gi",)), "quantities"),
    (dict(resolution="0"), "at least 1x1"),
    (dict(padding=-1), "padding"),
    (dict(texel_samples=0), "texel samples"),
    (dict(unwrap="sometimes"), "unwrap"),
])
def test_api_raises_input_error_for_bad_options(options, message):
    import aobake

    with pytest.raises(aobake.InputError, match=message):
        aobake.BakeConfig(**options)


@pytest.mark.parametrize("threads", [0, -1, 1.5])
def test_api_rejects_bad_thread_counts(threads):
    import trimesh

    import aobake

    with pytest.raises(aobake.InputError, match="threads"):
        aobake.bake(trimesh.creation.box(), rays=4, threads=threads)


@pytest.mark.parametrize("points", [np.zeros((2, 3), complex), np.array([["a", "b", "c"]] * 2),
                                    np.zeros((2, 4))])
def test_bake_points_rejects_bad_arrays(points):
    import trimesh

    import aobake

    with pytest.raises(aobake.InputError, match="points"):
        aobake.bake_points(trimesh.creation.box(), points, np.zeros((2, 3)), rays=4)


@pytest.fixture
def tiny_disk(tmp_path):
    """A 64 KiB tmpfs, where the test may mount one (root in a sandbox); else skipped.  A
    full disk found the writers raising raw OSError tracebacks."""
    import shutil
    import subprocess

    where = tmp_path / "tiny"
    where.mkdir()
    if shutil.which("mount") is None or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(where)],
            capture_output=True).returncode != 0:
        pytest.skip("cannot mount a small tmpfs here")
    yield where
    subprocess.run(["umount", str(where)], check=False)


@pytest.mark.slow
@pytest.mark.parametrize("ext", ["ply", "glb", "exr", "png", "tif"])
def test_full_disk_is_one_line_and_leaves_nothing(tmp_path, tiny_disk, ext):
    import trimesh

    mesh = tmp_path / "ico.ply"
    trimesh.creation.icosphere(subdivisions=4).export(mesh)
    image = ["--resolution", 512] if ext in ("exr", "png", "tif") else []  # (a lightmap's)
    res = run_cli(mesh, "--out", tiny_disk / f"ao.{ext}", "--rays", 4, *image, "--quiet")
    assert res.exit_code == 1, res.output
    (line,) = res.output.strip().splitlines()
    assert line.startswith(f"aobake: error: {tiny_disk}/ao.") and "no space left on device" in line
    assert "aobake-unfinished" not in line and "Traceback" not in res.output
    assert list(tiny_disk.iterdir()) == []


def test_output_that_is_a_directory_is_refused_before_work(mesh_path, tmp_path):
    """The CLI refuses it as usage (click, exit 2); the library's write() before writing
    anything (it used to write x.npz, then fail on the directory with a traceback)."""
    import aobake

    (tmp_path / "rep.json").mkdir()
    res = run_cli(mesh_path, "--out", tmp_path / "x.npz", "--report", tmp_path / "rep.json",
                  "--rays", 4)
    assert res.exit_code == 2 and "directory" in res.output and "Traceback" not in res.output
    result = aobake.bake(mesh_path, rays=4)
    with pytest.raises(aobake.OutputError, match=r"rep\.json: is a directory"):
        aobake.write(result, tmp_path / "x.npz", report=tmp_path / "rep.json")
    assert not (tmp_path / "x.npz").exists()


def test_commit_failure_restores_what_was_there(tmp_path, monkeypatch):
    """If a rename fails while the transaction commits, the outputs already renamed are
    undone (an overwritten file comes back) and the error names the output."""
    import os

    from aobake.errors import OutputError
    from aobake.outputs import atomic

    first, second = tmp_path / "a.txt", tmp_path / "b.txt"
    first.write_text("old")
    real = os.replace

    def flaky(src, dst):
        if str(dst) == str(second):
            raise PermissionError(13, "Permission denied")
        return real(src, dst)

    monkeypatch.setattr(atomic.os, "replace", flaky)
    with pytest.raises(OutputError, match=r"b\.txt: permission denied"):
        with atomic.transaction():
            for path in (first, second):
                with atomic.atomic_path(path) as tmp:
                    tmp.write_text("new")
    assert first.read_text() == "old" and not second.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


def test_confidence_is_capped_where_quantiles_stay_exact(mesh_path, tmp_path):
    res = run_cli(mesh_path, "--out", tmp_path / "x.npz", "--confidence", "0.9999999999999999",
                  "--rays", 3)
    assert res.exit_code == 2 and "--confidence" in res.output
    import aobake

    r = aobake.bake(mesh_path, rays=3, confidence=1 - 1e-12)
    assert np.all(r.ao_ci_low <= r.ao) and np.all(r.ao <= r.ao_ci_high)


def test_image_without_ao_is_refused_before_the_bake(mesh_path, tmp_path):
    res = run_cli(mesh_path, "--out", tmp_path / "ao.png", "-q", "bent_normal", "--rays", 4)
    assert res.exit_code == 1 and "add -q ao" in res.output
    assert list(tmp_path.iterdir()) == [mesh_path]


@pytest.mark.parametrize("args, words", [
    (["m.obj", "--bogus"], "No such option '--bogus'"),
    (["m.obj", "--rays"], "Option '--rays' requires an argument"),
    (["m.obj", "--sampler", "nope"], "'nope' is not one of"),
    (["view"], "Missing argument 'MESH'"),
    (["view", "m.obj", "--size", "--out"], "--size"),
    (["compare", "a.npz"], "Missing argument 'CANDIDATE'"),
    (["refit", "--nope"], "No such option '--nope'"),
    (["batch", "--nope"], "No such option '--nope'"),
])
def test_click_usage_errors_keep_the_error_contract(tmp_path, args, words):
    """An unknown option, a missing value or argument, a bad choice: one line
    ``aobake: error: ...``, then how to get help, status 2, and nothing written (click's own
    form, a usage block and ``Error: ...``, is what a log filter would miss)."""
    res = run_cli(*args)
    assert res.exit_code == 2, res.output
    lines = res.output.splitlines()
    assert lines[0].startswith("aobake: error: ") and words in lines[0], res.output
    command = "aobake" + ("" if args[0] == "m.obj" else f" {args[0]}")
    assert lines[1:] == [f"Try '{command} --help' for help."], res.output
    assert "Usage:" not in res.output and "Traceback" not in res.output
    assert list(tmp_path.iterdir()) == []
