"""Baking into a chosen UV set (``--uv-set``) and what overlapping own UVs get (``--uv-overlap``).

The scene (made here): two unit squares on the floor, A in the open and B under a ceiling C,
so their AO differs.  UV set 0 stacks A and B on one island (B mirrored: its u runs the other
way), the failure of shipped assets whose mirrored halves share a shell; UV set 1 gives every
square its own place, the clean layout a lightmap set has.
"""

import json
from statistics import NormalDist

import numpy as np
import pytest
from conftest import run_cli
from readers import read_accessor, read_glb, read_image

import aobake
from aobake.outputs import glb, image

#: two-sided false-alarm probability of each error-bar comparison below
ALPHA = 1e-4
K = NormalDist().inv_cdf(1 - ALPHA / 2)  # ~3.9 standard errors

# positions (12, 3): A = 0..3, B = 4..7, C = 8..11 (C faces down, over B)
POSITIONS = np.array([
    [0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
    [5, 0, 0], [6, 0, 0], [6, 1, 0], [5, 1, 0],
    [4.5, -0.5, 0.5], [6.5, -0.5, 0.5], [6.5, 1.5, 0.5], [4.5, 1.5, 0.5],
], dtype=np.float64)
FACES = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7], [8, 10, 9], [8, 11, 10]])
SQUARE = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)


def _place(lo, hi, mirror=False):
    corners = SQUARE.copy()
    if mirror:
        corners[:, 0] = 1.0 - corners[:, 0]
    return lo + corners * (np.asarray(hi) - np.asarray(lo))


#: set 0: A and B on one island (B mirrored), C beside them
SET0 = np.concatenate([_place((0.05, 0.05), (0.45, 0.45)),
                       _place((0.05, 0.05), (0.45, 0.45), mirror=True),
                       _place((0.55, 0.55), (0.95, 0.95))])
#: set 1: every square in its own place
SET1 = np.concatenate([_place((0.05, 0.05), (0.45, 0.45)), _place((0.55, 0.05), (0.95, 0.45)),
                       _place((0.05, 0.55), (0.95, 0.95))])


@pytest.fixture
def two_sets(tmp_path):
    """A GLB with TEXCOORD_0 = SET0 and TEXCOORD_1 = SET1 (written by aobake's own writer)."""
    path = tmp_path / "two_sets.glb"
    png = image.png_bytes(np.ones((2, 2)), np.ones((2, 2)))
    glb.write_textured(path, POSITIONS, FACES, None, SET1, png, {}, base_uv=SET0)
    return path


def _obj(path, uv):
    # positions as the GLB stores them (float32), every digit kept
    lines = ["v %.17g %.17g %.17g\n" % tuple(p) for p in POSITIONS.astype(np.float32)]
    lines += ["vt %.17g %.17g\n" % tuple(t) for t in uv]
    lines += ["f " + " ".join(f"{i + 1}/{i + 1}" for i in face) + "\n" for face in FACES]
    path.write_text("".join(lines))
    return path


def _gltf_uv(path, k):
    gltf, binary = read_glb(path)
    uv = read_accessor(gltf, binary, gltf["meshes"][0]["primitives"][0]["attributes"][
        f"TEXCOORD_{k}"])
    return np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])  # OBJ convention


@pytest.mark.slow
def test_uv_set_1_bakes_into_texcoord_1_and_writes_it_back(two_sets, tmp_path):
    common = ["--resolution", 16, "--rays", 64, "--normals", "angle", "--texel-samples", 1]
    out = tmp_path / "baked.glb"
    result = run_cli(two_sets, "--out", out, "--uv-set", 1, "--target", "texels",
                     "--report", tmp_path / "r.json", *common)
    assert result.exit_code == 0, result.output
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["texture"]["uv_set"] == 1 and report["config"]["uv_set"] == 1
    assert report["texture"]["atlas"] == "mesh UVs"  # set 1 is clean: baked as it is
    gltf, _ = read_glb(out)
    material = gltf["materials"][0]
    assert material["occlusionTexture"]["texCoord"] == 1
    # both sets written back as the input had them (float32 both ways)
    np.testing.assert_array_equal(_gltf_uv(out, 1), _gltf_uv(two_sets, 1))
    np.testing.assert_array_equal(_gltf_uv(out, 0), _gltf_uv(two_sets, 0))
    assert gltf["asset"]["extras"]["texture"]["uv_set"] == 1

    # The texels are those of the same mesh with TEXCOORD_1 as its only UVs (an OBJ): the
    # same layout, points and sample streams, so the same bits.
    via_set1 = aobake.bake_texels(_obj(tmp_path / "set1.obj", _gltf_uv(two_sets, 1)),
                                  resolution=16, rays=64, normals="angle", texel_samples=1)
    via_gltf = aobake.bake_texels(two_sets, resolution=16, rays=64, normals="angle",
                                  texel_samples=1, uv_set=1)
    np.testing.assert_array_equal(via_gltf.channels["ao"], via_set1.channels["ao"])
    # ... and not those of set 0 (which overlaps: the default makes a new atlas)
    via_set0 = aobake.bake_texels(two_sets, resolution=16, rays=64, normals="angle",
                                  texel_samples=1)
    assert via_set0.report["texture"]["atlas"] == "xatlas"
    assert not np.array_equal(via_set0.channels["coverage"], via_gltf.channels["coverage"])


@pytest.mark.slow
def test_uv_set_of_a_gltf_with_an_external_buffer(two_sets, tmp_path):
    # the same file as .gltf JSON + .bin: the same bits as the GLB
    gltf, binary = read_glb(two_sets)
    (tmp_path / "scene.bin").write_bytes(binary)
    gltf["buffers"] = [{"byteLength": len(binary), "uri": "scene.bin"}]
    (tmp_path / "scene.gltf").write_text(json.dumps(gltf))
    options = dict(resolution=16, rays=16, normals="angle", uv_set=1)
    text = aobake.bake_texels(tmp_path / "scene.gltf", **options)
    binary = aobake.bake_texels(two_sets, **options)
    np.testing.assert_array_equal(text.channels["ao"], binary.channels["ao"])
    assert text.report["texture"]["uv_set"] == 1


def test_missing_uv_set_and_obj_are_refused_clearly(two_sets, tmp_path):
    result = run_cli(two_sets, "--out", tmp_path / "a.exr", "--uv-set", 2)
    assert result.exit_code == 1
    assert "two_sets.glb" in result.output and "TEXCOORD_2" in result.output
    assert "TEXCOORD_0, TEXCOORD_1" in result.output and "Traceback" not in result.output
    obj = _obj(tmp_path / "m.obj", SET1)
    result = run_cli(obj, "--out", tmp_path / "b.exr", "--uv-set", 1)
    assert result.exit_code == 1 and "m.obj" in result.output
    assert "one UV set" in result.output
    assert not (tmp_path / "a.exr").exists() and not (tmp_path / "b.exr").exists()
    result = run_cli(obj, "--out", tmp_path / "b.exr", "--uv-set", -1)
    assert result.exit_code == 2


def _texel_point(uv, faces_uv, face_ids, target):
    """The surface point of the face (of ``face_ids``) whose UV triangle holds ``target``."""
    for f in face_ids:
        t = uv[faces_uv[f]]
        m = np.column_stack([t[1] - t[0], t[2] - t[0]])
        b12 = np.linalg.solve(m, target - t[0])
        bary = np.array([1 - b12.sum(), *b12])
        if (bary >= -1e-12).all():
            return bary @ POSITIONS[FACES[f]]
    raise AssertionError(f"no face holds {target}")


@pytest.mark.slow
def test_overlapping_uvs_detected_refused_with_the_overlap_shown(tmp_path):
    obj = _obj(tmp_path / "stacked.obj", SET0)
    out, mask = tmp_path / "ao.exr", tmp_path / "overlap.png"
    result = run_cli(obj, "--out", out, "--resolution", 16, "--rays", 8,
                     "--uv-overlap", "refuse", "--overlap-mask", mask)
    assert result.exit_code == 1, result.output
    text = result.output
    assert "stacked.obj" in text and "overlap" in text and "Traceback" not in text
    # A's two triangles lie on B's (mirrored) two: 4 faces overlap, 2 of them mirrored
    assert "4 faces overlap (2 of them mirrored" in text
    assert "0&2" in text or "0&3" in text
    assert not out.exists() and not out.with_suffix(".obj").exists()  # nothing written
    pixels, _, _ = read_image(mask)
    red = (pixels[..., 0] == 1) & (pixels[..., 1] == 0)
    # the stacked island is 0.4 x 0.4 of 16 x 16: the texel centres inside it, 6 x 6
    centres = (np.arange(16) + 0.5) / 16
    inside = (centres > 0.05) & (centres < 0.45)
    assert red.sum() == inside.sum() ** 2
    assert f"{inside.sum() ** 2} of 16x16 texels" in text
    # the default (atlas) bakes a new atlas instead, with the check in the report
    done = aobake.bake_texels(obj, resolution=16, rays=8)
    check = done.report["texture"]["uv_check"]
    assert done.report["texture"]["atlas"] == "xatlas"
    assert check["overlapping_texels"] == inside.sum() ** 2 and check["mirrored_faces"] == 2


def test_average_bakes_the_mean_of_the_stacked_surfaces(tmp_path):
    obj = _obj(tmp_path / "stacked.obj", SET0)
    rays, n = 256, 16
    result = aobake.bake_texels(obj, resolution=n, rays=rays, texel_samples=1, padding=0,
                                seams="off", uv_overlap="average", normals="angle")
    assert result.report["texture"]["atlas"] == "mesh UVs"
    assert any("--uv-overlap average" in w for w in result.report["warnings"])
    # A few texels of the shared island: each holds A's and B's surface points at its
    # centre (K = 1), so its value is their mean.
    rows, cols = np.array([1, 3, 5, 6]), np.array([2, 4, 6, 1])  # island: texels 1..6
    rows = n - 1 - rows  # image row 0 is the top (v = 1)
    targets = np.column_stack([(cols + 0.5) / n, 1 - (rows + 0.5) / n])
    a = np.array([_texel_point(SET0, FACES, (0, 1), t) for t in targets])
    b = np.array([_texel_point(SET0, FACES, (2, 3), t) for t in targets])
    up = np.tile([0.0, 0.0, 1.0], (len(targets), 1))
    oracle = aobake.bake_points(obj, np.concatenate([a, b]), np.concatenate([up, up]),
                                rays=64 * rays, seed=7)
    ao_a, ao_b = np.split(oracle.ao, 2)
    se_a, se_b = np.split(oracle.ao_stderr, 2)
    assert np.all(ao_b + K * se_b < ao_a - K * se_a)  # the ceiling darkens B: they differ
    texel = result.channels["ao"][rows, cols]
    texel_se = result.channels["ao_stderr"][rows, cols]
    # the mean of two independent estimates: stderr sqrt(se_a^2 + se_b^2) / 2
    mean, mean_se = (ao_a + ao_b) / 2, np.sqrt(se_a ** 2 + se_b ** 2) / 2
    assert np.all(np.abs(texel - mean) <= K * np.hypot(texel_se, mean_se)), (texel, mean)
    # neither surface alone
    assert np.all(np.abs(texel - ao_a) > K * np.hypot(texel_se, se_a))


@pytest.mark.parametrize("text, problem", [
    ('[1, 2]', "glTF JSON must be an object"),
    ('{"asset": {"version": "2.0"}, "meshes": 5}', "'meshes' must be a list"),
    ('{"asset": {"version": "2.0"}, "meshes": [{"primitives": 3}]}', "no list of primitives"),
    ('{"asset": {"version": "2.0"}, "meshes": [{"primitives": [{"attributes": []}]}]}',
     "attributes must be an object"),
])
def test_a_hand_edited_gltf_of_the_wrong_json_types_is_refused_naming_it(tmp_path, text,
                                                                          problem):
    path = tmp_path / "edited.gltf"
    path.write_text(text)
    res = run_cli(path, "--out", tmp_path / "ao.exr", "--uv-set", "1")
    assert res.exit_code == 1, res.output
    assert f"aobake: error: {path}: " in res.output and problem in res.output
    assert "Traceback" not in res.output and not (tmp_path / "ao.exr").exists()


@pytest.fixture
def no_material(two_sets, tmp_path):
    """``two_sets`` with its material taken away and its sets swapped: TEXCOORD_0 = SET1 (a
    layout a lightmap bakes into as it is), TEXCOORD_1 = SET0, on a primitive with no
    material, which trimesh loads without UVs."""
    from aobake.outputs.gltf import read_gltf, write_glb

    header, binary = read_gltf(two_sets)
    for mesh in header["meshes"]:
        for primitive in mesh["primitives"]:
            primitive.pop("material", None)
            names = primitive["attributes"]
            names["TEXCOORD_0"], names["TEXCOORD_1"] = names["TEXCOORD_1"], names["TEXCOORD_0"]
    for key in ("materials", "textures", "images", "samplers"):
        header.pop(key, None)
    path = tmp_path / "no_material.glb"
    with open(path, "wb") as handle:
        write_glb(handle, header, binary)
    return path


def test_a_glb_without_a_material_keeps_its_uvs(no_material):
    """Set 0 is the file's, not dropped: its float32 values, v flipped in float64 (as every
    set --uv-set N reads)."""
    scene = aobake.load_scene(no_material)
    assert scene.uv is not None
    gltf, binary = read_glb(no_material)
    stored = read_accessor(gltf, binary, gltf["meshes"][0]["primitives"][0]["attributes"][
        "TEXCOORD_0"]).astype(np.float64)
    np.testing.assert_array_equal(scene.uv, np.column_stack([stored[:, 0], 1.0 - stored[:, 1]]))
    np.testing.assert_allclose(scene.uv, SET1, rtol=0, atol=2.0 ** -24)
    assert [m["name"] for m in scene.materials] == ["default"]  # glTF's default material
    again = aobake.load_scene(no_material, uv_set=1)  # --uv-set N read it already
    np.testing.assert_array_equal(again.uv_sets[0], scene.uv)


@pytest.mark.slow
def test_a_glb_without_a_material_bakes_and_looks_up_its_own_uvs(no_material, tmp_path):
    """Its lightmap is baked into its own UVs (no new atlas: --no-unwrap runs), and a view
    looks that lightmap up through them, from the library and the command line."""
    lightmap = aobake.bake_texels(no_material, resolution=16, rays=4)
    assert lightmap.report["texture"]["atlas"] != "xatlas", lightmap.report["texture"]
    assert lightmap.report["texture"]["uv_check"]["valid"]
    out = tmp_path / "lm.exr"
    result = run_cli(no_material, "--out", out, "--resolution", "16", "--rays", "4",
                     "--no-unwrap")
    assert result.exit_code == 0, result.output
    look = run_cli("view", no_material, "--ao-from", out, "--out", tmp_path / "look.png",
                   "--size", "16x12")
    assert look.exit_code == 0, look.output
    assert "no UVs" not in look.output
    view = aobake.bake_view(no_material, ao_from=str(out), size=(16, 12))
    assert view.covered.any() and view.report["parameters"]["method"] == "file"
