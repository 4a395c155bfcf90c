"""``aobake compare`` of a render whose AO is multiplied by its coverage (associated alpha:
a renderer's film, OpenEXR's convention) against aobake's box-filtered view, whose value
is the mean over the part of the pixel that sees the scene (unassociated).

The oracle: a candidate made from the reference itself, its AO times its coverage with the
coverage as alpha.  Divided back, it is the reference to float32 rounding: two roundings of
values at most 1 (writing AO x coverage, and the division), each at most 2^-24 relative,
amplified by at most 1 / (the smallest coverage) where the division undoes the product.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import aobake
from aobake.compare import compare
from aobake.errors import InputError
from aobake.outputs.image import write_exr, write_rgb
from conftest import run_cli


@pytest.fixture(scope="module")
def view(tmp_path_factory):
    """A box-filtered view of two boxes in part of the frame: (view.exr, ao, coverage)."""
    folder = tmp_path_factory.mktemp("alpha")
    box = trimesh.creation.box(extents=[1.0, 0.6, 0.8])
    other = trimesh.creation.box(extents=[0.3, 0.3, 0.3])
    other.apply_translation([0.9, 0.6, 0.2])
    mesh = folder / "m.ply"
    trimesh.util.concatenate([box, other]).export(mesh)
    path = folder / "view.exr"
    result = aobake.bake_view(str(mesh), size=(40, 24), rays=64, pixel_filter="box", seed=2)
    aobake.write(result, str(path))
    ao = np.asarray(result.channels["ao"], dtype=np.float32)
    coverage = np.asarray(result.channels["coverage"], dtype=np.float32)
    assert ((coverage > 0) & (coverage < 1)).sum() > 20  # silhouettes partly covered
    return path, ao, coverage


def _bound(coverage) -> float:
    return 4 * 2.0 ** -24 / float(coverage[coverage > 0].min())


def test_a_render_times_its_coverage_is_divided_by_its_alpha(tmp_path, view):
    path, ao, coverage = view
    render = tmp_path / "render.exr"
    premultiplied = (ao * coverage).astype(np.float32)
    write_exr(render, {"R": premultiplied, "G": premultiplied, "B": premultiplied, "A": coverage})
    got = compare(path, render)
    assert got["candidate_alpha"] == "associated"
    assert got["max_error"] <= _bound(coverage)
    assert any("associated with the alpha 'A'" in note for note in got["notes"])
    straight = compare(path, render, candidate_alpha="straight")
    assert straight["candidate_alpha"] == "straight"
    partly = (coverage > 0) & (coverage < 1)
    want_bias = float(np.mean((ao * coverage - ao)[coverage > 0]))
    assert straight["bias"] == pytest.approx(want_bias, abs=_bound(coverage))
    assert straight["bias"] < 0
    assert any(f"at the {int(partly.sum())} pixels the reference covers partly" in note
               for note in straight["notes"])


def test_a_blender_pass_takes_the_combined_pass_alpha(tmp_path, view):
    """Blender's AO pass has no alpha of its own: its view layer's Combined.A is the film's."""
    path, ao, coverage = view
    render = tmp_path / "blender.exr"
    premultiplied = (ao * coverage).astype(np.float32)
    channels = {f"ViewLayer.Combined.{c}": np.ones_like(ao) for c in "RGB"}
    channels["ViewLayer.Combined.A"] = coverage
    channels.update({f"ViewLayer.Ambient Occlusion.{c}": premultiplied for c in "RGB"})
    write_exr(render, channels)
    got = compare(path, render)
    assert got["candidate_key"] == "ViewLayer.Ambient Occlusion.R"
    assert got["max_error"] <= _bound(coverage)
    assert any("'ViewLayer.Combined.A'" in note for note in got["notes"])


def test_the_candidate_stderr_file_is_divided_as_its_values(tmp_path, view):
    path, ao, coverage = view
    render, errors = tmp_path / "render.exr", tmp_path / "se.exr"
    write_exr(render, {"Y": (ao * coverage).astype(np.float32), "A": coverage})
    se = np.full_like(ao, 0.01) * coverage
    write_exr(errors, {"Y": se.astype(np.float32)})
    got = compare(path, render, candidate_stderr=errors)
    seen = coverage > 0
    assert got["candidate_noise_rms"] == pytest.approx(0.01, rel=1e-6)
    assert got["n"] == int(seen.sum())


def test_png_and_aobake_files_are_straight(tmp_path, view):
    """PNG's alpha is unassociated by its convention (the reader asks for it so), and
    aobake's own files hold unassociated values: auto divides neither."""
    path, ao, coverage = view
    png = tmp_path / "render.png"
    rgb = np.repeat(ao[..., None], 3, axis=2)
    write_rgb(png, rgb, alpha=coverage, bit_depth=16)
    got = compare(path, png, candidate_transfer="linear")
    assert got["candidate_alpha"] == "straight"
    assert got["max_error"] <= 2.0 ** -16  # the 16-bit quantisation, not a division
    assert compare(path, path)["candidate_alpha"] == "straight"


def test_impossible_alpha_requests_are_refused(tmp_path, view):
    path, ao, coverage = view
    with pytest.raises(InputError, match="aobake output, whose values are not multiplied"):
        compare(path, path, candidate_alpha="associated")
    lone = tmp_path / "lone.exr"
    write_exr(lone, {"Y": ao})
    with pytest.raises(InputError, match="no alpha channel beside 'Y'.*--candidate-alpha-key"):
        compare(path, lone, candidate_alpha="associated")
    with pytest.raises(InputError, match="no alpha channel 'Q'"):
        compare(path, lone, candidate_alpha_key="Q")
    wild = tmp_path / "wild.exr"
    write_exr(wild, {"Y": ao, "A": coverage * 3})
    with pytest.raises(InputError, match=r"not in \[0, 1\]"):
        compare(path, wild)
    with pytest.raises(InputError, match="alpha must be one of"):
        compare(path, lone, candidate_alpha="premultiplied")


def test_the_command_line_reaches_the_same_settings(tmp_path, view):
    path, ao, coverage = view
    render = tmp_path / "render.exr"
    write_exr(render, {"Y": (ao * coverage).astype(np.float32), "mask": coverage})
    res = run_cli("compare", path, render, "--candidate-key", "Y", "--candidate-alpha-key", "mask",
                  "--json")
    assert res.exit_code == 0, res.output
    import json

    got = json.loads(res.output.splitlines()[-1])
    assert got["candidate_alpha"] == "associated" and got["max_error"] <= _bound(coverage)
    res = run_cli("compare", path, render, "--candidate-key", "Y", "--candidate-alpha", "associated")
    assert res.exit_code == 1 and res.output.startswith("aobake: error: ") \
        and "--candidate-alpha-key" in res.output
    res = run_cli("compare", path, render, "--candidate-alpha", "sideways")
    assert res.exit_code == 2 and res.output.startswith("aobake: error: ")
