"""``aobake compare`` of camera views: per covered pixel, with the screen-space scores
(interior / depth-edge band, SSIM, stderr units, raw and after the best gain) of
``aobake.screen.score`` computed from the reference view's own G-buffer and camera."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import aobake
from aobake.api import UNBOUNDED
from aobake.compare import compare
from aobake.compare.screen import camera_of
from aobake.errors import InputError
from aobake.outputs import Values
from aobake.outputs.image import write_ldr
from aobake.screen import score
from aobake.screen.gbuffer import GBuffer
from tests.conftest import run_cli

STILL_LIFE = Path(__file__).resolve().parents[1] / "assets" / "still_life.obj"
SIZE = (64, 48)
RADIUS = 0.5


@pytest.fixture(scope="module")
def views(tmp_path_factory):
    """A bounded ray-traced truth and GTAO of one camera view of the still life, as EXRs."""
    tmp = tmp_path_factory.mktemp("views")
    mesh = STILL_LIFE
    truth = aobake.bake_view(mesh, size=SIZE, rays=32, max_distance=RADIUS, seed=3)
    gtao = aobake.bake_view(mesh, size=SIZE, method="gtao", ssao_radius=RADIUS)
    aobake.write(truth, tmp / "truth.exr")
    aobake.write(gtao, tmp / "gtao.exr")
    return truth, gtao, tmp


@pytest.mark.slow
def test_view_scores_equal_the_screen_score_of_the_views_own_g_buffer(views):
    truth, gtao, tmp = views
    m = compare(tmp / "truth.exr", tmp / "gtao.exr")
    assert m["matched_by"] == "pixel" and m["n"] == truth.covered.sum()
    covered = truth.covered
    edges = score.depth_edges(GBuffer.from_view(truth).frame())
    expected = score.score(truth.channels["ao"], gtao.channels["ao"], covered, edges=edges,
                           stderr=truth.channels["ao_stderr"])
    screen = m["screen"]
    assert screen["gain"] == expected["gain"]
    assert screen["edge_pixels"] == int(edges.sum()) > 0
    for region in score.REGIONS:
        for kind in ("raw", "gained"):
            assert screen["regions"][region][kind] == expected["regions"][region][kind]
    # the per-texel metrics and the screen's "all" region are one computation's two views
    assert screen["regions"]["all"]["raw"]["rmse"] == pytest.approx(m["rmse"], rel=1e-12)
    assert screen["regions"]["all"]["raw"]["z_rms"] is not None
    assert screen["regions"]["interior"]["raw"]["pixels"] + \
        screen["regions"]["edges"]["raw"]["pixels"] == m["n"]


@pytest.mark.slow
def test_another_tools_png_of_the_same_pixels_is_scored(views, tmp_path):
    truth, gtao, tmp = views
    # a shader's output: 16-bit grey, no metadata, every pixel written (alpha 1)
    write_ldr(tmp_path / "shader.png", gtao.channels["ao"], np.ones(truth.covered.shape),
              bit_depth=16)
    m = compare(tmp / "truth.exr", tmp_path / "shader.png")
    exact = compare(tmp / "truth.exr", tmp / "gtao.exr")
    assert m["n"] == exact["n"] and m["screen"] is not None
    step = 0.5 / 65535  # 16 bits round to the nearest of 65535 steps
    for region in score.REGIONS:
        a, b = m["screen"]["regions"][region]["raw"], exact["screen"]["regions"][region]["raw"]
        assert abs(a["rmse"] - b["rmse"]) <= step + 1e-7
        assert abs(a["bias"] - b["bias"]) <= step + 1e-7
    # an occlusion image (1 = occluded) read with --candidate-convention occlusion
    write_ldr(tmp_path / "occlusion.png", 1.0 - gtao.channels["ao"],
              np.ones(truth.covered.shape), bit_depth=16)
    occ = compare(tmp / "truth.exr", tmp_path / "occlusion.png", candidate_convention="occlusion")
    assert abs(occ["screen"]["gain"] - exact["screen"]["gain"]) < 1e-3


def test_a_method_without_noise_as_reference_has_no_stderr_units(views):
    _, _, tmp = views
    m = compare(tmp / "gtao.exr", tmp / "truth.exr")
    assert m["screen"]["regions"]["all"]["raw"]["z_rms"] is None
    assert m["screen"]["regions"]["all"]["raw"]["rmse"] > 0


def test_identical_views_score_perfectly_and_stay_strict_json(views):
    _, _, tmp = views
    res = run_cli("compare", tmp / "gtao.exr", tmp / "gtao.exr", "--json")
    assert res.exit_code == 0, res.output
    record = json.loads(res.stdout)
    raw = record["screen"]["regions"]["all"]["raw"]
    assert raw["rmse"] == 0 and raw["psnr"] is None and raw["ssim"] == pytest.approx(1.0)
    assert record["screen"]["gain"] == 1.0


def test_cli_prints_the_regions_and_the_gain(views):
    _, _, tmp = views
    res = run_cli("compare", tmp / "truth.exr", tmp / "gtao.exr")
    assert res.exit_code == 0, res.output
    assert "covered pixels of a camera view" in res.stdout
    assert "best gain of the occlusion" in res.stdout
    for region in score.REGIONS:
        assert f"\n    {region} " in res.stdout


@pytest.mark.slow
def test_views_of_different_cameras_are_refused(views, tmp_path):
    truth, _, tmp = views
    cam = truth.camera
    other = aobake.bake_view(STILL_LIFE, look={
        "look_from": tuple(np.asarray(cam.eye) * 1.1), "look_at": tuple(cam.target),
        "fov": 40.0}, size=SIZE, method="gtao", ssao_radius=RADIUS)
    aobake.write(other, tmp_path / "other.exr")
    res = run_cli("compare", tmp / "truth.exr", tmp_path / "other.exr")
    assert res.exit_code == 1
    assert "is another view than the reference" in res.output
    assert "Traceback" not in res.output


@pytest.mark.slow
def test_views_of_the_same_rays_are_compared(views, tmp_path):
    """A view whose record differs only where the rays do not (its target elsewhere on the
    same line of sight, its eye moved by float noise: a camera written and read back) is the
    same pixels; a turn of a hundredth of a pixel is not."""
    truth, _, tmp = views
    cam = truth.camera
    eye, target = np.asarray(cam.eye), np.asarray(cam.target)
    pixel = 2.0 * cam.tan_half_fov / cam.height
    for name, look_from, look_at, same in (
            ("farther", eye, target + 3.0 * (target - eye), True),
            ("noise", eye + 7.5e-9, target, True),
            ("turned", eye, target + 0.01 * pixel * np.linalg.norm(target - eye)
             * np.asarray(cam.right), False)):
        other = aobake.bake_view(STILL_LIFE, look={
            "look_from": tuple(look_from), "look_at": tuple(look_at), "up": tuple(cam.up),
            "fov": cam.fov_y}, size=SIZE, method="gtao", ssao_radius=RADIUS)
        aobake.write(other, tmp_path / f"{name}.exr")
        res = run_cli("compare", tmp / "truth.exr", tmp_path / f"{name}.exr")
        if same:
            assert res.exit_code == 0, (name, res.output)
        else:
            assert res.exit_code == 1 and "view direction moves the rays by" in res.output


@pytest.mark.parametrize("record, problem", [
    ({"eye": [0, 0, 5]}, "no 'target'"),
    ({"eye": "far away", "target": [0, 0, 0], "up": [0, 1, 0], "fov_y_deg": 40, "width": 4,
      "height": 3, "near": 0.1, "far": 10}, "3 numbers"),
    ({"eye": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0], "fov_y_deg": 40, "width": 8,
      "height": 3, "near": 0.1, "far": 10}, "8x3 pixels, its image 4x3"),
])
def test_a_hand_edited_camera_record_is_refused_naming_the_file(tmp_path, record, problem):
    values = Values(tmp_path / "view.exr", "texels", np.zeros((3, 4)),
                    metadata={"camera": record})
    with pytest.raises(InputError) as info:
        camera_of(values)
    assert str(info.value).startswith(f"{tmp_path / 'view.exr'}: ")
    assert problem in str(info.value)


# -- aobake view --truths: the G-buffer, both truths and the camera in one run ----------------

@pytest.mark.slow
def test_view_truths_are_the_bounded_and_unbounded_views_bit_for_bit():
    truths = aobake.bake_view_truths(STILL_LIFE, size=SIZE, rays=16, ssao_radius=RADIUS, seed=5)
    bounded = aobake.bake_view(STILL_LIFE, size=SIZE, rays=16, max_distance=RADIUS, seed=5)
    unbounded = aobake.bake_view(STILL_LIFE, camera=truths.camera, size=SIZE, rays=16, seed=5)
    for name, image in bounded.channels.items():
        assert np.array_equal(truths.channels[name], image), name
    for name, renamed in UNBOUNDED.items():
        assert np.array_equal(truths.channels[renamed], unbounded.channels[name]), name
    covered = truths.covered
    # the same rays per pixel: a hit nearer than R is a hit, so bounded AO is never darker
    assert (truths.channels["ao"][covered] >= truths.channels["ao_unbounded"][covered]).all()
    assert (truths.channels["ao"][covered] > truths.channels["ao_unbounded"][covered]).any()
    record = truths.report["truths"]
    assert record["bounded"]["max_distance"] == RADIUS
    assert record["unbounded"]["channels"][0] == "ao_unbounded"


@pytest.mark.slow
def test_view_truths_from_the_cli_score_a_shader_against_either_truth(tmp_path):
    out = tmp_path / "view.exr"
    res = run_cli("view", STILL_LIFE, "--out", out, "--size", "48x36", "--rays", "16",
                  "--ssao-radius", RADIUS, "--truths")
    assert res.exit_code == 0, res.output
    assert (tmp_path / "view.camera.json").exists()
    shader = aobake.bake_view(STILL_LIFE, size=(48, 36), method="crytek", ssao_radius=RADIUS)
    write_ldr(tmp_path / "shader.png", shader.channels["ao"], np.ones((36, 48)), bit_depth=16)
    bounded = compare(out, tmp_path / "shader.png")
    unbounded = compare(out, tmp_path / "shader.png", reference_key="ao_unbounded")
    assert unbounded["reference_key"] == "ao_unbounded"
    # each against its own truth's stderr
    assert unbounded["reference_noise_rms"] != bounded["reference_noise_rms"]
    assert unbounded["screen"]["regions"]["all"]["raw"]["z_rms"] is not None
    # the unbounded truth is darker: the screen method, which sees R, is too light against it
    assert unbounded["bias"] > bounded["bias"]


@pytest.mark.parametrize("args, message", [
    (("--out", "v.png"), "must be .exr"),
    (("--out", "v.exr", "--max-distance", "1"), "not --max-distance"),
    (("--out", "v.exr", "--method", "gtao"), "not with --method gtao"),
    (("--out", "v.exr", "-q", "ao", "-q", "obscurance"), "ao only"),
])
def test_view_truths_usage_errors(tmp_path, args, message):
    args = [a if not a.startswith("v.") else tmp_path / a for a in args]
    res = run_cli("view", STILL_LIFE, "--truths", "--size", "8x6", *args)
    assert res.exit_code == 2 and message in res.output
    assert not list(tmp_path.iterdir())
