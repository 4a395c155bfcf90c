"""``aobake view MESH --ao-from LIGHTMAP``: a lightmap looked up at each pixel's UV, as an
engine samples it (bilinear, texel centres at ((c + 0.5) / W, 1 - (r + 0.5) / H)), and
scored against the view's ray-traced truth.

Tolerances: the map is stored as float32 (relative 2^-24) and the hit point is read back from
the float32 P channels (a few ulps of the eye's distance, times the map's slope), so lookups
agree to ~1e-5 with the closed form; a bilinear read of an affine map is exact in float64
arithmetic up to rounding (1e-12).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import aobake
from aobake import camera as cameras
from aobake.methods.file import bilinear
from aobake.outputs.image import write_exr

from conftest import run_cli

#: the repository's own assets (tests/../assets)
ASSETS = __import__("pathlib").Path(__file__).resolve().parents[1] / "assets"
W, H = 8, 6
#: an affine map value = A + B u + C v, sampled at the texel centres
A, B, C = 0.2, 0.5, 0.25


def _affine_map():
    u = (np.arange(W) + 0.5) / W
    v = 1.0 - (np.arange(H) + 0.5) / H
    return A + B * u[None, :] + C * v[:, None]


def _affine(uv):
    """What a bilinear read of ``_affine_map`` gives: affine between the outer texel centres,
    constant beyond them (clamp to the edge)."""
    u = np.clip(uv[:, 0], 0.5 / W, 1 - 0.5 / W)
    v = np.clip(uv[:, 1], 0.5 / H, 1 - 0.5 / H)
    return A + B * u + C * v


def test_bilinear_reads_texel_centres_and_blends_between_them():
    rng = np.random.default_rng(3)
    image = rng.uniform(size=(H, W))
    r, c = np.divmod(np.arange(W * H), W)
    centres = np.stack([(c + 0.5) / W, 1 - (r + 0.5) / H], axis=1)
    np.testing.assert_allclose(bilinear(image, centres), image[r, c], atol=1e-12)
    # half way between texel (0, 0) and (0, 1): their mean; between four: the four's mean
    np.testing.assert_allclose(bilinear(image, np.array([[1.0 / W, 1 - 0.5 / H]])),
                               (image[0, 0] + image[0, 1]) / 2, atol=1e-12)
    np.testing.assert_allclose(bilinear(image, np.array([[1.0 / W, 1 - 1.0 / H]])),
                               image[:2, :2].mean(), atol=1e-12)
    # at u = 0 the edge: clamp reads the first column, repeat blends it with the last
    edge = np.array([[0.0, 1 - 0.5 / H]])
    np.testing.assert_allclose(bilinear(image, edge, "clamp"), image[0, 0], atol=1e-12)
    np.testing.assert_allclose(bilinear(image, edge, "repeat"),
                               (image[0, 0] + image[0, -1]) / 2, atol=1e-12)
    np.testing.assert_allclose(bilinear(image, centres + [1.0, -2.0], "repeat"),
                               image[r, c], atol=1e-12)
    uv = rng.uniform(-0.2, 1.2, size=(500, 2))
    np.testing.assert_allclose(bilinear(_affine_map(), uv), _affine(uv), atol=1e-12)


QUAD_OBJ = """v -1 -1 0
v 1 -1 0
v 1 1 0
v -1 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
f 1/1 2/2 3/3
f 1/1 3/3 4/4
"""


@pytest.fixture
def quad_and_map(tmp_path):
    """A 2 x 2 quad at z = 0 with UVs (x + 1, y + 1) / 2, and an affine lightmap of it."""
    mesh = tmp_path / "quad.obj"
    mesh.write_text(QUAD_OBJ)
    lightmap = tmp_path / "map.exr"
    write_exr(lightmap, {"ao": _affine_map(), "coverage": np.ones((H, W))})
    return mesh, lightmap


def _world_hits(view):
    """(k, 3) float64 world points of the covered pixels, from the float32 P channels."""
    m = np.array(view.report["camera"]["world_to_view"])
    p = np.stack([view.channels[f"P.{a}"][view.covered] for a in "XYZ"], 1).astype(np.float64)
    return (p - m[:3, 3]) @ m[:3, :3]


def test_a_view_looks_the_lightmap_up_at_each_pixels_uv(quad_and_map):
    mesh, lightmap = quad_and_map
    cam = cameras.look_at([0.3, -0.2, 2.5], [0.1, 0.1, 0.0], [0.0, 1.0, 0.0], 60.0,
                          size=(40, 30))
    view = aobake.bake_view(mesh, camera=cam, method="file", ao_from=str(lightmap))
    world = _world_hits(view)
    uv = (world[:, :2] + 1.0) / 2.0
    np.testing.assert_allclose(view.channels["ao"][view.covered], _affine(uv), atol=2e-5)
    parameters = view.report["parameters"]
    assert parameters["lightmap"] == {"width": W, "height": H, "wrap": "clamp", "uv_set": 0}
    assert parameters["lookups_in_charts"] == 1.0
    assert "rays" not in view.channels and "ao_stderr" not in view.channels


def test_a_box_filtered_look_averages_lookups_over_the_pixel(quad_and_map):
    """Each pixel is the mean of the lookups at its positions' hits (recomputed here from
    the positions, ``Footprint.offsets``, and the rays through them)."""
    from aobake.settings import BakeConfig
    from aobake.targets.view import Footprint

    mesh, lightmap = quad_and_map
    cam = cameras.look_at([0.1, 0.0, 1.0], [0.0, 0.1, 0.0], [0.0, 1.0, 0.0], 30.0,
                          size=(16, 12))
    config = BakeConfig(pixel_filter="box", pixel_samples=16, seed=4, ao_from=str(lightmap))
    box = aobake.bake_view(mesh, config, camera=cam, method="file")
    assert box.covered.all() and (box.channels["coverage"] == 1).all()
    pixels = np.arange(16 * 12)
    offsets = Footprint.of(config).offsets(config.seed, pixels)  # (k, 16, 2)
    row, column = np.divmod(pixels, 16)
    xy = np.stack([column[:, None] + offsets[..., 0], row[:, None] + offsets[..., 1]], -1)
    d = cam.directions_through(xy.reshape(-1, 2))
    world = cam.eye + (-cam.eye[2] / d[:, 2])[:, None] * d  # on the quad's plane z = 0
    expected = _affine((world[:, :2] + 1.0) / 2.0).reshape(-1, 16).mean(axis=1)
    np.testing.assert_allclose(box.channels["ao"].ravel(), expected, atol=2e-6)
    centre = aobake.bake_view(mesh, camera=cam, method="file", ao_from=str(lightmap))
    assert 0 < np.abs(box.channels["ao"] - centre.channels["ao"]).max() < 0.01
    assert box.report["camera"]["pixel_filter"] == "box"


def test_the_command_line_looks_a_lightmap_up(quad_and_map, tmp_path):
    mesh, lightmap = quad_and_map
    out, report = tmp_path / "look.exr", tmp_path / "look.json"
    result = run_cli("view", mesh, "--ao-from", lightmap, "--out", out, "--report", report,
                     "--size", "16x12", "--look-from", "0,0,2", "--look-at", "0,0,0")
    assert result.exit_code == 0, result.output
    recorded = json.loads(report.read_text())
    assert recorded["parameters"]["method"] == "file"
    assert recorded["parameters"]["lightmap"]["width"] == W
    assert recorded["config"]["ao_from"] == str(lightmap)


def test_what_cannot_be_looked_up_is_refused_naming_the_file(quad_and_map, tmp_path):
    mesh, lightmap = quad_and_map
    bare = tmp_path / "bare.obj"
    bare.write_text("".join(line + "\n" for line in QUAD_OBJ.splitlines()
                            if line.startswith("v ")) + "f 1 2 3\nf 1 3 4\n")
    with pytest.raises(aobake.InputError, match="bare.obj: has no UVs"):
        aobake.bake_view(bare, method="file", ao_from=str(lightmap), size=(8, 6))
    # a view is not a lightmap
    view = tmp_path / "view.exr"
    aobake.write(aobake.bake_view(mesh, rays=4, size=(8, 6)), view)
    with pytest.raises(aobake.InputError, match="view.exr: is a camera view"):
        aobake.bake_view(mesh, method="file", ao_from=str(view), size=(8, 6))
    # a map baked into UV set 1 is looked up there
    other = tmp_path / "set1.exr"
    write_exr(other, {"ao": _affine_map()},  # aobake's metadata: a config and a texture
              metadata={"config": {}, "texture": {"uv_set": 1, "wrap": "clamp"}})
    with pytest.raises(aobake.InputError, match="--uv-set 1"):
        aobake.bake_view(mesh, method="file", ao_from=str(other), size=(8, 6))
    result = run_cli("view", mesh, "--ao-from", other, "--out", tmp_path / "x.exr",
                     "--size", "8x6")
    assert result.exit_code == 1 and "baked into UV set 1" in result.output


def test_uvs_off_the_maps_charts_are_a_warning(quad_and_map, tmp_path, caplog):
    mesh, _ = quad_and_map
    covered = np.zeros((H, W))
    covered[:, :2] = 1  # the map covers its two left columns only
    lightmap = tmp_path / "small.exr"
    write_exr(lightmap, {"ao": _affine_map(), "coverage": covered})
    view = aobake.bake_view(mesh, method="file", ao_from=str(lightmap), size=(16, 12),
                            look={"look_from": [0, 0, 2], "look_at": [0, 0, 0]})
    assert view.report["parameters"]["lookups_in_charts"] < 0.5
    assert "read texels the lightmap does not cover" in caplog.text


@pytest.mark.slow
def test_uv_set_1_of_a_gltf(tmp_path):
    """Square B of test_uvsets' scene: mirrored in set 0, in a place of its own in set 1; a
    map whose value is u tells which set was read."""
    from test_uvsets import FACES, POSITIONS, SET0, SET1
    from aobake.outputs import glb, image

    path = tmp_path / "two_sets.glb"
    png = image.png_bytes(np.ones((2, 2)), np.ones((2, 2)))
    glb.write_textured(path, POSITIONS, FACES, None, SET1, png, {}, base_uv=SET0)
    n = 64
    ramp = np.tile((np.arange(n) + 0.5) / n, (n, 1))  # value = u at the texel centres
    lightmap = tmp_path / "u.exr"
    write_exr(lightmap, {"ao": ramp})
    # B (x in [5, 6]) seen from below, past the ceiling C above it
    look = {"look_from": [5.5, 0.5, -2.0], "look_at": [5.5, 0.5, 0.0], "up": [0, 1, 0],
            "fov": 20.0}
    values = {}
    for uv_set in (0, 1):
        view = aobake.bake_view(path, method="file", ao_from=str(lightmap), uv_set=uv_set,
                                look=look, size=(24, 24))
        on_b = view.covered & (view.channels["object_id"] == 0)
        x = _world_hits(view)[on_b[view.covered], 0]
        values[uv_set] = (x, view.channels["ao"][on_b].astype(np.float64))
        assert view.report["parameters"]["lightmap"]["uv_set"] == uv_set
    x, ao = values[1]
    np.testing.assert_allclose(ao, 0.55 + 0.4 * (x - 5.0), atol=2e-4)
    x, ao = values[0]
    np.testing.assert_allclose(ao, 0.05 + 0.4 * (6.0 - x), atol=2e-4)
    result = run_cli("view", path, "--ao-from", lightmap, "--uv-set", 1, "--out",
                     tmp_path / "look.exr", "--size", "12x12", "--look-from", "5.5,0.5,-2",
                     "--look-at", "5.5,0.5,0", "--fov", "20")
    assert result.exit_code == 0, result.output


@pytest.mark.slow
def test_a_baked_lightmap_seen_from_a_camera_scores_against_the_views_truth(tmp_path):
    """The still life's lightmap (new atlas, written beside it as ao.obj) looked up by the
    view of ao.obj, against the view's ray-traced truth: the look is close to the truth
    and what it misses is more than the truth's noise (the map's texels and its own noise)."""
    from pathlib import Path

    from aobake.compare import compare

    still_life = Path(__file__).resolve().parents[1] / "assets" / "still_life.obj"
    lightmap = tmp_path / "ao.exr"
    assert run_cli(still_life, "--out", lightmap, "--resolution", "256", "--rays", "64",
                   "--quiet").exit_code == 0
    atlas = tmp_path / "ao.obj"
    camera = ["--size", "64x48", "--quiet"]
    truth, look = tmp_path / "truth.exr", tmp_path / "look.exr"
    assert run_cli("view", still_life, "--out", truth, "--rays", "256", *camera).exit_code == 0
    result = run_cli("view", atlas, "--ao-from", lightmap, "--out", look, *camera)
    assert result.exit_code == 0, result.output
    scored = compare(truth, look)
    assert scored["target"] == "view" and scored["n"] > 500
    # measured: rmse 0.031, bias -0.002, 3.0 times the truth's noise
    assert scored["rmse"] < 0.06 and abs(scored["bias"]) < 0.015
    assert scored["rmse_in_reference_se"] > 1.5


# --- --lightmap-filter trilinear: a mip chain read at the pixel's footprint -------------------

def test_the_mip_chain_keeps_texel_centres_so_a_linear_ramp_reads_the_same_at_every_level():
    """Each level averages 2 x 2 texels and keeps u = (c + 0.5) / W_k at its centres: a map
    linear in u and v reads back u + v at any level and any blend (away from the clamped
    border), to float64 rounding; odd sizes take their last row and column twice."""
    from aobake.methods.file import bilinear, mip_chain, trilinear

    size = 64
    c = (np.arange(size) + 0.5) / size
    ramp = c[None, :] + (1.0 - c)[:, None]  # u + v, row 0 the top (v = 1)
    levels = mip_chain(ramp)
    assert [level.shape for level in levels] == [(2 ** k, 2 ** k) for k in range(6, -1, -1)]
    rng = np.random.default_rng(0)
    uv = rng.uniform(0.25, 0.75, size=(500, 2))
    for level in (np.zeros(500), rng.uniform(0.0, 3.0, 500)):
        got = trilinear(levels, uv, level, "clamp")
        np.testing.assert_allclose(got, uv.sum(axis=1), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(trilinear(levels, uv, np.zeros(500), "clamp"),
                                  bilinear(ramp, uv, "clamp"))
    odd = mip_chain(np.arange(15.0).reshape(3, 5))
    assert [level.shape for level in odd] == [(3, 5), (2, 3), (1, 2), (1, 1)]
    np.testing.assert_array_equal(odd[1], [[3.0, 5.0, 6.5], [10.5, 12.5, 14.0]])


def test_the_footprint_of_a_pixel_on_a_plane_facing_the_camera_is_its_width_in_texels():
    """A square of side S at distance D straight ahead, its UVs spanning it, a map of W
    texels: a pixel's edge there is D 2 tan(fov / 2) / H scene units, so lambda = log2 of
    that times W / S (the centre pixel's two edges are equal)."""
    from aobake import camera as cameras
    from aobake.methods.file import footprint_levels

    distance, side, texels = 3.0, 2.0, 512
    cam = cameras.look_at([0, 0, distance], [0, 0, 0], [0, 1, 0], 40.0, size=(64, 48))
    pixel = cam.width * 24 + 32  # the pixel right of and below the image's centre point
    d = cam.directions_through(np.array([[32.5, 24.5]]))[0]
    point = cam.eye + distance / -d[2] * d
    triangle = np.array([[[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0]]])
    uvs = np.array([[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]])
    level = footprint_levels(cam, np.array([pixel]), point[None], np.array([[0.0, 0.0, 1.0]]),
                             triangle, uvs, (texels, texels))
    edge = distance * 2.0 * cam.tan_half_fov / cam.height * texels / side
    assert level[0] == pytest.approx(np.log2(edge), rel=1e-9)
    # a plane seen edge-on (holding the eye, the centre ray and the next pixel's): inf
    right = cam.directions_through(np.array([[33.5, 24.5]]))[0]
    edge_on = np.cross(d, right)
    edge_on /= np.linalg.norm(edge_on)
    grazing = footprint_levels(cam, np.array([pixel]), point[None], edge_on[None],
                               triangle, uvs, (texels, texels))
    assert np.isinf(grazing[0])


def test_trilinear_looks_through_every_door_and_is_refused_where_it_means_nothing(tmp_path):
    """The CLI and the library give the same look; its report says trilinear and the mean
    level; a box-filtered view, a per-vertex bake, another method and a lightmap target
    are refused before any work."""
    import json

    from aobake.errors import UsageError

    mesh = ASSETS / "torus_uv.obj"
    lightmap = tmp_path / "lm.exr"
    res = run_cli(mesh, "--out", lightmap, "--resolution", "128", "--rays", "4", "--quiet")
    assert res.exit_code == 0, res.output
    look = tmp_path / "look.exr"
    res = run_cli("view", mesh, "--ao-from", lightmap, "--lightmap-filter", "trilinear",
                  "--size", "48x27", "--out", look, "--report", tmp_path / "r.json")
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["config"]["lightmap_filter"] == "trilinear"
    assert report["parameters"]["lightmap_filter"] == "trilinear"
    assert report["parameters"]["mip"]["mean_level"] > 0
    result = aobake.bake_view(str(mesh), ao_from=str(lightmap), lightmap_filter="trilinear",
                              size=(48, 27))
    from aobake.outputs import read

    assert np.array_equal(read(look).value, np.asarray(result.channels["ao"], np.float64))
    plain = aobake.bake_view(str(mesh), ao_from=str(lightmap), size=(48, 27))
    assert not np.array_equal(result.channels["ao"], plain.channels["ao"])
    vertex_bake = tmp_path / "v.npz"
    aobake.write(aobake.bake(str(mesh), rays=4), vertex_bake)
    for args, words in (
            (["view", mesh, "--ao-from", lightmap, "--pixel-filter", "box"], "--pixel-filter box"),
            (["view", mesh, "--ao-from", vertex_bake], "is a per-vertex bake"),
            (["view", mesh], "not with --method rays"),
            ([mesh, "--method", "file", "--ao-from", lightmap], "No such option")):
        out = tmp_path / "x.exr"
        res = run_cli(*args, "--lightmap-filter", "trilinear", "--out", out)
        assert res.exit_code in (1, 2) and res.output.startswith("aobake: error: ") \
            and words in res.output, (args, res.output)
        assert not out.exists()
    with pytest.raises(UsageError, match="--pixel-filter box"):
        aobake.bake_view(str(mesh), ao_from=str(lightmap), lightmap_filter="trilinear",
                         pixel_filter="box")
    with pytest.raises(UsageError, match="has no pixels"):
        aobake.bake_texels(str(mesh), ao_from=str(lightmap), lightmap_filter="trilinear",
                           resolution=32)
