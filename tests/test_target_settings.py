"""A setting only another target reads is refused, not ignored (a new user's README run):
``--resolution``, ``--uv-set``, ``--half``, ``--bit-depth``, ``--r-only`` and ``--orm`` on a
per-vertex output, a lightmap setting in a view, a view's in a lightmap, through the command
line, the library, ``aobake.write`` and a batch (its own settings against ``--format``, a
manifest row's against its output). All are usage errors (exit 2), refused before any
work. A whole ``BakeConfig`` handed over as one record is not refused: it carries every
section and a bake reads its own. A batch's summary in a missing folder and a batch with no
output format are refused before the first asset, with nothing made."""

from __future__ import annotations

import json

import pytest

import aobake
from aobake.errors import UsageError

from conftest import run_cli

PER_VERTEX_REFUSED = [
    ("x.ply", ["--resolution", "64"], "--resolution is a setting of a lightmap"),
    ("x.npz", ["--texel-density", "8"], "--texel-density is a setting of a lightmap"),
    ("x.ply", ["--uv-set", "1"], "--uv-set 1 picks the UV set a lightmap bakes into"),
    ("x.ply", ["--half"], "--half stores an EXR image's channels"),
    ("x.npz", ["--bit-depth", "16"], "--bit-depth is a PNG or TIFF image's"),
    ("x.exr", ["--r-only"], "--r-only stores a PNG or TIFF lightmap's AO in R only"),
    ("x.ply", ["--orm"], "--orm packs a lightmap"),
]


@pytest.mark.parametrize("name, flags, message", PER_VERTEX_REFUSED)
def test_the_command_refuses_a_setting_its_output_does_not_read(box_ply, tmp_path, name,
                                                                flags, message):
    out = tmp_path / name
    result = run_cli(box_ply, "--out", out, "--rays", 4, *flags)
    assert result.exit_code == 2, result.output
    assert message in result.output and "Traceback" not in result.output
    assert "rays in" not in result.output and not list(tmp_path.glob("x.*"))


@pytest.mark.slow
def test_a_lightmap_setting_is_read_by_a_lightmap(box_ply, tmp_path):
    """The same flags where they apply: the refusal is about the target, not the flag."""
    out = tmp_path / "x.exr"
    result = run_cli(box_ply, "--out", out, "--rays", 4, "--resolution", 32, "--half")
    assert result.exit_code == 0, result.output
    assert out.exists()


def test_the_library_refuses_a_keyword_only_another_target_reads(box_ply):
    with pytest.raises(UsageError, match="--resolution is a setting of a lightmap"):
        aobake.bake(str(box_ply), rays=4, resolution=64)
    with pytest.raises(UsageError, match="--uv-set 1 picks the UV set"):
        aobake.bake(str(box_ply), rays=4, uv_set=1)
    with pytest.raises(UsageError, match="--pixel-filter is a setting of aobake view"):
        aobake.bake_texels(str(box_ply), rays=4, resolution=32, pixel_filter="box")
    with pytest.raises(UsageError, match="--resolution is a setting of a lightmap"):
        aobake.bake_view(str(box_ply), rays=4, size=(8, 6), resolution=64)
    with pytest.raises(UsageError, match="--resolution is a setting of a lightmap"):
        aobake.bake_file(str(box_ply), "never.ply", {"rays": 4, "resolution": 64})


@pytest.mark.slow
def test_a_whole_config_is_a_record_and_is_not_refused(box_ply):
    """One BakeConfig for a pipeline's vertex and lightmap bakes: each reads its sections,
    and the vertex bake equals one made without the lightmap's settings, bit for bit."""
    config = aobake.BakeConfig(rays=4, resolution=64, pixel_filter="box")
    shared = aobake.bake(str(box_ply), config)
    plain = aobake.bake(str(box_ply), aobake.BakeConfig(rays=4))
    assert shared.ao.tobytes() == plain.ao.tobytes()
    assert "resolution" not in shared.report["config"]


def test_write_refuses_an_image_option_for_a_vertex_result(box_ply, tmp_path):
    result = aobake.bake(str(box_ply), rays=4)
    for options, message in (({"half": True}, "--half"), ({"bit_depth": 16}, "--bit-depth"),
                             ({"r_only": True}, "--r-only")):
        with pytest.raises(UsageError, match=message):
            aobake.write(result, tmp_path / "x.ply", **options)
    assert not (tmp_path / "x.ply").exists()


@pytest.mark.slow
def test_batch_refuses_its_settings_against_its_format_before_anything(box_ply, tmp_path):
    out_dir = tmp_path / "out"
    result = run_cli("batch", box_ply, "--out-dir", out_dir, "--format", "ply",
                     "--rays", 4, "--resolution", 64)
    assert result.exit_code == 2 and "--resolution is a setting of a lightmap" in result.output
    assert not out_dir.exists()
    ok = run_cli("batch", box_ply, "--out-dir", out_dir, "--format", "exr", "--rays", 4,
                 "--resolution", 16)
    assert ok.exit_code == 0, ok.output


@pytest.mark.slow
def test_batch_holds_a_manifest_row_to_its_own_output(box_ply, tmp_path):
    """A row's own lightmap setting on a per-vertex output fails that row; the batch's
    settings reach every row whatever its output."""
    manifest = tmp_path / "m.jsonl"
    rows = [{"mesh": str(box_ply), "output": "a.ply", "options": {"resolution": 64}},
            {"mesh": str(box_ply), "output": "b.ply"}]
    manifest.write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    out_dir = tmp_path / "out"
    result = run_cli("batch", manifest, "--out-dir", out_dir, "--rays", 4)
    assert result.exit_code == 1, result.output
    records = {r["output"]: r for r in json.loads(
        (out_dir / "batch-summary.json").read_text())["assets"]}
    assert records["a.ply"]["status"] == "failed"
    assert "--resolution is a setting of a lightmap" in records["a.ply"]["error"]
    assert records["b.ply"]["status"] == "ok" and (out_dir / "b.ply").exists()
    assert not (out_dir / "a.ply").exists()


def test_batch_summary_in_a_missing_folder_is_refused_before_the_first_asset(box_ply,
                                                                             tmp_path):
    out_dir = tmp_path / "out"
    result = run_cli("batch", box_ply, "--out-dir", out_dir, "--format", "ply", "--rays", 4,
                     "--summary", tmp_path / "nowhere" / "s.json")
    assert result.exit_code == 1 and "does not exist" in result.output
    assert "Traceback" not in result.output and not out_dir.exists()


def test_batch_without_any_output_format_is_a_usage_error(box_ply, tmp_path):
    out_dir = tmp_path / "out"
    result = run_cli("batch", box_ply, "--out-dir", out_dir, "--rays", 4)
    assert result.exit_code == 2 and "give --format" in result.output
    assert not out_dir.exists()
