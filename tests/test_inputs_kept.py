"""Nothing a run reads is overwritten by what it writes (issue 35): every file a bake reads
(the mesh, --from, --cage, --ao-from, --orm-from) is refused as any of its outputs, through
the command line and the library, before any work, and the file is left byte for byte; a
batch's --summary may replace neither an input nor an asset's own output; a manifest or a
resumed report nested past the parser's depth is a clear error, not a RecursionError."""

from __future__ import annotations

import json

import pytest
import trimesh

import aobake
from aobake.errors import OutputError

from conftest import run_cli


@pytest.fixture
def baked(tmp_path):
    """A floor-and-box mesh and per-vertex bakes of it (.npz, .glb)."""
    mesh = tmp_path / "scene.ply"
    floor = trimesh.creation.box((3.0, 0.1, 3.0))
    box = trimesh.creation.box((0.6, 0.6, 0.6))
    box.apply_translation((0, 0.35, 0))
    trimesh.util.concatenate([floor, box]).export(mesh)
    result = aobake.bake(str(mesh), rays=4)
    files = {"mesh": mesh}
    for suffix in (".npz", ".glb"):
        files[suffix] = tmp_path / f"bake{suffix}"
        aobake.write(result, files[suffix])
    return files


def _snapshot(paths):
    return {p: p.read_bytes() for p in paths}


@pytest.mark.parametrize("role", ["--report", "--mesh-out"])
def test_an_ao_from_file_is_never_an_output_of_the_same_run(baked, tmp_path, role):
    source = baked[".glb"] if role == "--mesh-out" else baked[".npz"]
    before = _snapshot([source, baked["mesh"]])
    args = [baked["mesh"], "--ao-from", source, "--out", tmp_path / "look.exr",
            "--resolution", 32, role, source]
    result = run_cli(*args)
    assert result.exit_code == 1, result.output
    assert "refusing to overwrite the input --ao-from" in result.output
    assert _snapshot(before) == before
    assert not (tmp_path / "look.exr").exists()


def test_a_view_may_not_write_its_report_over_the_bake_it_reads(baked, tmp_path):
    source = baked[".npz"]
    before = _snapshot([source])
    result = run_cli("view", baked["mesh"], "--ao-from", source, "--out", tmp_path / "v.png",
                     "--size", "8x8", "--report", source)
    assert result.exit_code == 1 and "refusing to overwrite the input --ao-from" in \
        result.output
    assert _snapshot(before) == before


@pytest.mark.slow
def test_the_library_keeps_every_input_too(baked, tmp_path):
    source = baked[".npz"]
    before = _snapshot([source])
    with pytest.raises(OutputError, match="refusing to overwrite the input --ao-from"):
        aobake.bake_file(str(baked["mesh"]), tmp_path / "look.exr",
                         {"ao_from": str(source), "resolution": 32}, method="file",
                         report=source)
    view = aobake.bake_view(str(baked["mesh"]), ao_from=str(source), method="file",
                            size=(8, 8))
    with pytest.raises(OutputError, match="refusing to overwrite the input --ao-from"):
        aobake.write(view, tmp_path / "v.exr", report=source)
    assert _snapshot(before) == before


def test_a_cage_and_a_source_are_inputs_as_well(tmp_path):
    low, high, cage = tmp_path / "low.obj", tmp_path / "high.obj", tmp_path / "cage.obj"
    trimesh.creation.icosphere(1, 1.0).export(low)
    trimesh.creation.icosphere(2, 1.0).export(high)
    big = trimesh.creation.icosphere(1, 1.0)
    big.vertices *= 1.05
    big.export(cage)
    before = _snapshot([high, cage])
    for flag, path in (("--from", high), ("--cage", cage)):
        result = run_cli(low, "--from", high, "--cage", cage, "--out", tmp_path / "ao.npz",
                         "--report", path)
        assert result.exit_code == 1 and f"the input {flag}" in result.output, result.output
    assert _snapshot(before) == before


@pytest.mark.parametrize("which", ["mesh", "output", "report"])
@pytest.mark.slow
def test_a_batch_summary_replaces_no_input_and_no_output(baked, tmp_path, which):
    out_dir = tmp_path / "out"
    summary = {"mesh": baked["mesh"], "output": out_dir / "scene.npz",
               "report": out_dir / "scene.npz.report.json"}[which]
    summary.parent.mkdir(exist_ok=True)
    if not summary.exists():
        summary.write_text("keep me")
    before = _snapshot([summary])
    result = run_cli("batch", baked["mesh"], "--out-dir", out_dir, "--format", "npz",
                     "--rays", 4, "--summary", summary)
    assert result.exit_code == 1, result.output
    assert "refusing to write the batch summary over" in result.output
    assert _snapshot(before) == before


@pytest.mark.slow
def test_a_manifest_nested_past_the_parser_is_a_clear_error(baked, tmp_path):
    deep = "[" * 100_000 + "]" * 100_000
    manifest = tmp_path / "assets.jsonl"
    manifest.write_text(json.dumps({"mesh": str(baked["mesh"]), "output": "a.npz",
                                    "rays": 4}) + "\n"
                        + '{"mesh": "x.ply", "options": {"rays": ' + deep + "}}\n")
    result = run_cli("batch", manifest, "--out-dir", tmp_path / "out")
    assert result.exit_code == 1, result.output
    assert "nested too deeply" in result.output
    assert "RecursionError" not in result.output and "internal error" not in result.output
    assert (tmp_path / "out" / "a.npz").is_file()  # the good row still baked


@pytest.mark.slow
def test_a_resumed_batch_with_a_report_nested_by_hand_bakes_again(baked, tmp_path):
    out_dir = tmp_path / "out"
    args = ["batch", baked["mesh"], "--out-dir", out_dir, "--format", "npz", "--rays", 4]
    assert run_cli(*args).exit_code == 0
    report = out_dir / "scene.npz.report.json"
    report.write_text('{"config": ' + "[" * 100_000 + "]" * 100_000 + "}")
    again = run_cli(*args)
    assert again.exit_code == 0, again.output
    assert json.loads((out_dir / "batch-summary.json").read_text())["counts"]["ok"] == 1


@pytest.mark.slow
@pytest.mark.parametrize("fmt", ["npz", "ply", "exr"])
def test_a_resumed_batch_bakes_a_damaged_output_again(baked, tmp_path, fmt):
    out_dir = tmp_path / "out"
    args = ["batch", baked["mesh"], "--out-dir", out_dir, "--format", fmt, "--rays", 4]
    if fmt == "exr":  # (a lightmap setting: a per-vertex format refuses it)
        args += ["--resolution", 32]
    assert run_cli(*args).exit_code == 0
    out = out_dir / f"scene.{fmt}"
    whole = out.read_bytes()
    skipped = run_cli(*args)  # untouched: skipped
    assert json.loads((out_dir / "batch-summary.json").read_text())["counts"]["skipped"] == 1
    out.write_bytes(whole[: len(whole) // 2])  # a full disk's half file
    again = run_cli(*args)
    assert again.exit_code == 0, again.output
    assert json.loads((out_dir / "batch-summary.json").read_text())["counts"]["ok"] == 1
    assert out.read_bytes() == whole  # the same seed: the same bits
    assert skipped.exit_code == 0


def test_orm_names_its_target_an_extension_does_not_change_it(baked, tmp_path):
    """A .glb is per vertex unless --target texels says otherwise, --orm included."""
    result = run_cli(baked["mesh"], "--out", tmp_path / "x.glb", "--orm", "--rays", 4)
    assert result.exit_code == 2 and "add --target texels" in result.output
    assert not (tmp_path / "x.glb").exists()
