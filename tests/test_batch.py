"""``aobake batch``: assets from folders, globs and manifests; one bad asset never stops the
others; outputs only inside --out-dir; resuming skips what is done (and nothing else).

Runs on the threads executor (``tests/test_dask_batch.py`` runs a batch on Dask).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from aobake import batch
from aobake.cli.batch import batch_command
from aobake.errors import InputError, OutputError


def run_batch(*args):
    """``aobake batch ARGS`` through click's runner: (exit code, stderr, summary or None)."""
    args = [str(a) for a in args]
    result = CliRunner(mix_stderr=False).invoke(batch_command(), args) \
        if "mix_stderr" in CliRunner.__init__.__code__.co_varnames \
        else CliRunner().invoke(batch_command(), args)
    out_dir = Path(args[args.index("--out-dir") + 1])
    path = out_dir / batch.SUMMARY_NAME
    summary = json.loads(path.read_text()) if path.is_file() else None
    return result.exit_code, result.stderr, summary


def _library(folder: Path) -> dict:
    """Three small generated meshes (one in a sub-folder) and a corrupt OBJ."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "sub").mkdir(exist_ok=True)
    trimesh.creation.box().export(folder / "box.ply")
    trimesh.creation.icosphere(1).export(folder / "ico.obj")
    trimesh.creation.torus(1.0, 0.4, major_sections=12, minor_sections=6).export(
        folder / "sub" / "torus.stl")
    (folder / "broken.obj").write_text("v 1 2\nf 1 2 9\n")
    return {"box": folder / "box.ply", "ico": folder / "ico.obj",
            "torus": folder / "sub" / "torus.stl", "broken": folder / "broken.obj"}


def _by_mesh(summary) -> dict:
    return {Path(r["mesh"]).name: r for r in summary["assets"] if r["mesh"]}


@pytest.mark.slow
def test_a_corrupt_asset_is_reported_and_the_others_baked(tmp_path):
    _library(tmp_path / "in")
    out = tmp_path / "out"
    code, err, summary = run_batch(tmp_path / "in", "--out-dir", out, "--format", "npz",
                                   "--rays", "8")
    assert code == 1, err
    assert summary["counts"] == {"ok": 3, "skipped": 0, "failed": 1}
    records = _by_mesh(summary)
    assert records["broken.obj"]["status"] == "failed"
    assert "broken.obj" in records["broken.obj"]["error"]
    for name in ("box.ply", "ico.obj", "torus.stl"):
        assert records[name]["status"] == "ok" and records[name]["rays"] > 0
        assert records[name]["seconds"] > 0
    # one line per asset, then the total
    lines = [line for line in err.splitlines() if line.startswith("aobake: [")]
    assert len(lines) == 4 and sum("FAILED" in line for line in lines) == 1
    assert "1 failed" in err.splitlines()[-1]
    # the folder's layout is kept; each output has its report
    assert (out / "sub" / "torus.npz").is_file()
    assert (out / "sub" / ("torus.npz" + batch.REPORT_SUFFIX)).is_file()
    assert not list(out.rglob("*aobake-unfinished*"))


@pytest.mark.slow
def test_resume_skips_what_is_done_and_bakes_what_changed(tmp_path):
    meshes = _library(tmp_path / "in")
    meshes["broken"].unlink()
    out = tmp_path / "out"
    args = [tmp_path / "in", "--out-dir", out, "--format", "ply", "--rays", "8"]
    assert run_batch(*args)[0] == 0
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*.ply")}

    code, err, summary = run_batch(*args)
    assert code == 0 and summary["counts"] == {"ok": 0, "skipped": 3, "failed": 0}, err
    assert before == {p: p.stat().st_mtime_ns for p in out.rglob("*.ply")}

    # a changed mesh, a missing output: those two are baked again
    trimesh.creation.icosphere(2).export(meshes["ico"])
    (out / "box.ply").unlink()
    code, _, summary = run_batch(*args)
    status = {name: r["status"] for name, r in _by_mesh(summary).items()}
    assert status == {"box.ply": "ok", "ico.obj": "ok", "torus.stl": "skipped"}

    # another configuration: everything again; --force: everything again
    assert run_batch(*args[:-1], "16")[2]["counts"]["ok"] == 3
    assert run_batch(*args[:-1], "16", "--force")[2]["counts"]["ok"] == 3
    report = json.loads((out / ("box.ply" + batch.REPORT_SUFFIX)).read_text())
    assert report["config"]["rays"] == 16
    assert report["input"]["sha256"] == batch.digest(meshes["box"])["sha256"]


@pytest.mark.slow
def test_manifests_name_outputs_and_settings_per_asset(tmp_path):
    meshes = _library(tmp_path / "in")
    (tmp_path / "lib.csv").write_text(
        "mesh,output,rays,max-distance,quantities\n"
        "in/box.ply,boxes/box_a.npz,8,,\n"
        "in/box.ply,boxes/box_b.ply,16,50%,ao;obscurance\n")
    (tmp_path / "lib.jsonl").write_text(
        json.dumps({"mesh": "in/ico.obj", "rays": 4, "options": {"seed": 7}}) + "\n\n" +
        json.dumps({"mesh": str(meshes["torus"]), "output": "t.npz",
                    "quantities": ["ao", "bent_normal"]}) + "\n")
    out = tmp_path / "out"
    code, err, summary = run_batch(tmp_path / "lib.csv", tmp_path / "lib.jsonl", "--out-dir",
                                   out, "--format", "npz", "--rays", "32")
    assert code == 0, err
    assert summary["counts"]["ok"] == 4

    def config(name):
        return json.loads((out / (name + batch.REPORT_SUFFIX)).read_text())["config"]

    assert config("boxes/box_a.npz")["rays"] == 8
    b = config("boxes/box_b.ply")
    assert (b["rays"], b["max_distance"], b["quantities"]) == (16, "50%", ["ao", "obscurance"])
    ico = config("ico.npz")  # no output named: the mesh's name with --format
    assert (ico["rays"], ico["seed"]) == (4, 7)
    assert config("t.npz")["quantities"] == ["ao", "bent_normal"]
    assert config("t.npz")["rays"] == 32  # the command's setting where the row gives none


@pytest.mark.slow
def test_manifest_outputs_cannot_leave_the_out_dir(tmp_path):
    _library(tmp_path / "in")
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (out / "link").symlink_to(elsewhere, target_is_directory=True)
    (elsewhere / "victim.ply").write_text("precious")
    (out / "trap.ply").symlink_to(elsewhere / "victim.ply")
    rows = [("absolute", str(tmp_path / "abs.ply")), ("dotdot", "../escaped.ply"),
            ("deep", "a/../../escaped2.ply"), ("linked folder", "link/x.ply"),
            ("linked file", "trap.ply"), ("fine", "deep/ok.ply")]
    (tmp_path / "evil.jsonl").write_text("".join(
        json.dumps({"mesh": "in/box.ply", "output": output}) + "\n" for _, output in rows))
    code, err, summary = run_batch(tmp_path / "evil.jsonl", "--out-dir", out, "--rays", "4")
    assert code == 1
    status = [(r["output"], r["status"]) for r in summary["assets"]]
    assert status == [(output, "failed") for _, output in rows[:-1]] + [("deep/ok.ply", "ok")]
    messages = [r["error"] for r in summary["assets"][:-1]]
    assert "absolute" in messages[0] and "'..'" in messages[1] and "'..'" in messages[2]
    assert all("symbolic link" in m for m in messages[3:])
    # nothing was written outside the output folder, the file behind the link untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["elsewhere", "evil.jsonl", "in",
                                                          "out"]
    assert sorted(p.name for p in elsewhere.iterdir()) == ["victim.ply"]
    assert (elsewhere / "victim.ply").read_text() == "precious"


def test_output_path_refuses_what_leaves_the_folder(tmp_path):
    assert batch.output_path(tmp_path, "a/b/c.ply") == tmp_path / "a" / "b" / "c.ply"
    assert (tmp_path / "a" / "b").is_dir()
    for bad in ("/etc/passwd", "..", "../x.ply", "a/../../x.ply", "a\\..\\..\\x.ply",
                "C:\\x.ply", "", "  "):
        with pytest.raises(OutputError):
            batch.output_path(tmp_path, bad)


@pytest.mark.slow
def test_bad_manifest_rows_fail_alone(tmp_path):
    _library(tmp_path / "in")
    (tmp_path / "rows.jsonl").write_text("\n".join([
        json.dumps({"mesh": "in/box.ply", "rays": 4}),
        json.dumps({"mesh": "in/box.ply", "output": "u.ply", "colour": "red"}),
        json.dumps({"mesh": "in/box.ply", "output": "v.ply", "rays": "many"}),
        json.dumps({"output": "w.ply"}),
        "{not json",
        json.dumps(["a", "list"]),
        json.dumps({"mesh": "in/missing.obj", "output": "m.ply"}),
        json.dumps({"mesh": "in/box.ply", "output": "x.ply", "target": "view"}),
        json.dumps({"mesh": "in/box.ply", "output": "noext"}),
    ]) + "\n")
    code, err, summary = run_batch(tmp_path / "rows.jsonl", "--out-dir", tmp_path / "out",
                                   "--format", "ply")
    assert code == 1
    records = summary["assets"]
    assert [r["status"] for r in records] == ["ok"] + ["failed"] * 8
    errors = [r["error"] for r in records[1:]]
    for expected, error in zip(["unknown setting 'colour'", "rays", "no 'mesh'", "not JSON",
                                "not a JSON object", "no such file", "target must be",
                                "needs an extension"], errors):
        assert expected in error, error
    assert all("line" in error for error in errors if "missing" not in error)


def test_csv_manifest_needs_a_mesh_column(tmp_path):
    (tmp_path / "m.csv").write_text("path,output\nx.obj,x.ply\n")
    code, _, summary = run_batch(tmp_path / "m.csv", "--out-dir", tmp_path / "out")
    assert code == 1 and "'mesh' column" in summary["assets"][0]["error"]


def test_globs_files_and_shared_output_names(tmp_path):
    meshes = _library(tmp_path / "in")
    trimesh.creation.box().export(tmp_path / "in" / "sub" / "box.obj")
    out = tmp_path / "out"
    code, err, summary = run_batch(str(tmp_path / "in" / "**" / "*.obj"), meshes["box"],
                                   str(tmp_path / "nothing*.ply"), "--out-dir", out,
                                   "--format", "npz", "--rays", "4")
    records = summary["assets"]
    names = [(Path(r["mesh"]).name if r["mesh"] else r["source"], r["status"])
             for r in records]
    # the glob: broken.obj (fails), ico.obj, sub/box.obj (box.npz); then box.ply also wants
    # box.npz: refused; then the pattern that matched nothing
    assert names == [("broken.obj", "failed"), ("ico.obj", "ok"), ("box.obj", "ok"),
                     ("box.ply", "failed"), (str(tmp_path / "nothing*.ply"), "failed")]
    assert "as " in records[3]["error"] and "box.obj" in records[3]["error"]
    assert "matched no mesh" in records[4]["error"]


def test_lightmaps_sharing_an_atlas_mesh_name_and_the_summary_name(tmp_path):
    (tmp_path / "m.jsonl").write_text("".join(json.dumps(row) + "\n" for row in [
        {"mesh": "t.obj", "output": "a.exr"}, {"mesh": "t.obj", "output": "a.png"},
        {"mesh": "t.obj", "output": "batch-summary.json"}, {"mesh": "t.obj",
                                                             "output": "b.ply"}]))
    assets = batch.find_assets([tmp_path / "m.jsonl"], tmp_path / "out")
    assert [a.error is None for a in assets] == [True, False, False, True]
    assert "a.obj" in assets[1].error and "summary" in assets[2].error


@pytest.mark.slow
def test_outputs_inside_the_input_folder_are_not_inputs(tmp_path):
    _library(tmp_path / "in")
    (tmp_path / "in" / "broken.obj").unlink()
    args = [tmp_path / "in", "--out-dir", tmp_path / "in" / "baked", "--format", "ply",
            "--rays", "4"]
    assert run_batch(*args)[2]["counts"] == {"ok": 3, "skipped": 0, "failed": 0}
    assert run_batch(*args)[2]["counts"] == {"ok": 0, "skipped": 3, "failed": 0}


@pytest.mark.slow
def test_processes_executor_bakes_the_same_bits(tmp_path):
    meshes = _library(tmp_path / "in")
    a, b = tmp_path / "a", tmp_path / "b"
    assert run_batch(meshes["torus"], "--out-dir", a, "--format", "npz", "--rays", "8")[0] == 0
    code, err, summary = run_batch(meshes["torus"], "--out-dir", b, "--format", "npz",
                                   "--rays", "8", "--executor", "processes", "--workers", "2",
                                   "--chunk-points", "50")
    assert code == 0, err
    assert summary["executor"]["name"] == "processes"
    with np.load(a / "torus.npz") as x, np.load(b / "torus.npz") as y:
        for key in ("ao", "ao_stderr", "rays"):
            np.testing.assert_array_equal(x[key], y[key])


def test_a_lightmap_asset_writes_its_mesh_inside_the_folder(tmp_path):
    mesh = Path(__file__).resolve().parents[1] / "assets" / "torus_uv.obj"
    code, err, summary = run_batch(mesh, "--out-dir", tmp_path / "out", "--format", "exr",
                                   "--rays", "4", "--resolution", "16")
    assert code == 0, err
    written = {Path(p).name for p in summary["assets"][0]["outputs"]}
    assert "torus_uv.exr" in written
    assert all((tmp_path / "out" / name).is_file() for name in written)


def test_usage_errors(tmp_path):
    code, err, _ = run_batch(tmp_path, "--out-dir", tmp_path / "o", "--scheduler",
                             "tcp://127.0.0.1:1")
    assert code == 2 and "--scheduler goes with --executor dask" in err
    result = CliRunner().invoke(batch_command(), ["--out-dir", str(tmp_path / "o")])
    assert result.exit_code == 2  # no INPUTS


def test_parse_setting_reads_cells_with_the_cli_types():
    assert batch.parse_setting("rays", "64") == ("rays", 64)
    assert batch.parse_setting("max-distance", "10%") == ("max_distance", "10%")
    assert batch.parse_setting("quantities", "ao; bent-normal") == \
        ("quantities", ("ao", "bent_normal"))
    assert batch.parse_setting("rays", 8) == ("rays", 8)
    assert batch.parse_setting("from", "high.ply")[0] == "source"
    with pytest.raises(InputError, match="unknown setting"):
        batch.parse_setting("colour", "red")
    with pytest.raises(InputError, match="rays"):
        batch.parse_setting("rays", "lots")


def test_batch_is_a_subcommand_of_aobake(tmp_path):
    from aobake.cli import SUBCOMMANDS

    if "batch" not in SUBCOMMANDS:
        pytest.skip("aobake.cli.SUBCOMMANDS has no 'batch' yet")
    from conftest import run_cli

    _library(tmp_path / "in")
    result = run_cli("batch", tmp_path / "in" / "box.ply", "--out-dir", tmp_path / "out",
                     "--format", "ply", "--rays", "4")
    assert result.exit_code == 0, result.output
    assert (tmp_path / "out" / "box.ply").is_file()


def test_report_config_round_trips_for_resume(tmp_path):
    """What ``finished`` compares: the config of a written report equals the config's
    strict-JSON form, whatever the settings (a float distance, inf, a tuple)."""
    import aobake

    config = aobake.BakeConfig(rays=4, max_distance=2.5, quantities=("ao", "obscurance"))
    mesh = tmp_path / "box.ply"
    trimesh.creation.box().export(mesh)
    out = tmp_path / "box.npz"
    result = aobake.bake(str(mesh), config)
    result.report["input"] = batch.digest(mesh)
    aobake.write(result, out, mesh=mesh, report=batch.report_path(out))
    assert batch.finished(out, config, "vertices", "rays", batch.digest(mesh))
    assert not batch.finished(out, aobake.BakeConfig(rays=4), "vertices", "rays",
                              batch.digest(mesh))
    assert not batch.finished(out, config, "texels", "rays", batch.digest(mesh))
    os.remove(out)
    assert not batch.finished(out, config, "vertices", "rays", batch.digest(mesh))


def test_executor_dask_without_dask_is_a_clear_error(tmp_path, monkeypatch):
    """Where Dask is not installed, --executor dask says what to install (one asset's
    failure in a batch; an InputError from the library)."""
    import sys

    import aobake

    monkeypatch.setitem(sys.modules, "distributed", None)  # `import distributed` fails
    mesh = trimesh.creation.torus(1.0, 0.4, major_sections=12, minor_sections=6)
    with pytest.raises(InputError, match=r"needs Dask: pip install 'aobake\[dask\]'"):
        aobake.bake(mesh, rays=4, executor="dask", chunk_points=10)
    path = tmp_path / "t.ply"
    mesh.export(path)
    code, err, summary = run_batch(path, "--out-dir", tmp_path / "out", "--format", "ply",
                                   "--rays", "4", "--executor", "dask")
    assert code == 1 and "needs Dask" in err


@pytest.mark.slow
def test_high_to_low_rows_resume_on_their_source(tmp_path):
    """A manifest row with ``from`` (the high-poly source, relative to the manifest) bakes
    high-to-low; its report hashes the source too, so a changed source re-bakes it."""
    trimesh.creation.icosphere(1).export(tmp_path / "low.ply")
    trimesh.creation.icosphere(3).export(tmp_path / "high.ply")
    (tmp_path / "m.jsonl").write_text(json.dumps(
        {"mesh": "low.ply", "from": "high.ply", "output": "low_ao.npz"}) + "\n")
    args = [tmp_path / "m.jsonl", "--out-dir", tmp_path / "out", "--rays", "4"]
    code, err, summary = run_batch(*args)
    assert code == 0, err
    report = json.loads((tmp_path / "out" / ("low_ao.npz" + batch.REPORT_SUFFIX)).read_text())
    assert report["config"]["source"] == str(tmp_path / "high.ply")
    assert report["input"]["source"]["sha256"] == batch.digest(tmp_path / "high.ply")["sha256"]
    assert run_batch(*args)[2]["counts"]["skipped"] == 1
    trimesh.creation.icosphere(2).export(tmp_path / "high.ply")
    assert run_batch(*args)[2]["counts"]["ok"] == 1
