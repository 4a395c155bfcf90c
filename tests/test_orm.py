"""ORM-packed lightmaps (``--orm``, ``--orm-from``): R = the AO map, G/B = roughness/metalness
copied from their source, and the GLB that wires one image to both occlusion and
metallic-roughness, checked by the Khronos glTF validator and (where a Blender Python is
given) by Blender's importer.

The mesh is test_uvsets's two-set scene (made there, by the tests); the validator is
installed by ``npm install --prefix .ci/node`` (``.ci/run`` does it, so CI never skips it).
"""

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli
from readers import read_glb, read_image, read_view
from test_uvsets import FACES, POSITIONS, SET0, SET1, two_sets  # noqa: F401 (a fixture)

import aobake
from aobake.outputs import glb, image

ROOT = Path(__file__).resolve().parent.parent
NODE_TOOLS = ROOT / ".ci" / "node"
BLENDER_CHECK = ROOT / "benchmarks" / "check_blender_orm.py"
N = 16
BAKE = ["--resolution", N, "--rays", 16, "--target", "texels"]


@pytest.fixture
def roughness_metal(tmp_path):
    """An 8-bit RGB texture of the lightmap's size with random G and B: (path, pixels)."""
    rgb = np.random.default_rng(3).random((N, N, 3))
    path = tmp_path / "mr.png"
    image.write_rgb(path, rgb)
    return path, read_image(path)[0]


def _stored(pixels, bits):
    """The integers an image stores (``read_image`` gives x / (2^bits - 1))."""
    return np.rint(pixels * (2 ** bits - 1)).astype(np.int64)


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.slow
def test_orm_png_is_ao_in_r_and_the_source_in_g_b(two_sets, roughness_metal,  # noqa: F811
                                                   tmp_path, bits):
    source, mr = roughness_metal
    out = tmp_path / "orm.png"
    result = run_cli(two_sets, "--out", out, "--uv-set", 1, "--orm-from", source,
                     "--bit-depth", bits, *BAKE, "--report", tmp_path / "r.json")
    assert result.exit_code == 0, result.output
    exr = tmp_path / "all.exr"  # the same bake's float channels (same seed: the same bits)
    assert run_cli(two_sets, "--out", exr, "--uv-set", 1, "--orm-from", source,
                   *BAKE).exit_code == 0
    pixels, names, attrs = read_image(out)
    assert names == ["R", "G", "B"]
    channels, exr_names, _ = read_image(exr)
    ao = channels[..., exr_names.index("ao")]
    np.testing.assert_array_equal(_stored(pixels[..., 0], bits), image.quantize(ao, bits))
    # G/B: the 8-bit source's values, stored again at this depth (exact: k/255 -> 16 bits
    # is k * 257)
    np.testing.assert_array_equal(_stored(pixels[..., 1:], bits),
                                  image.quantize(mr[..., 1:], bits))
    for i, name in enumerate(("orm.R", "orm.G", "orm.B")):  # the EXR's packed channels
        want = ao if i == 0 else mr[..., i]
        np.testing.assert_array_equal(channels[..., exr_names.index(name)], want)
    meta = json.loads(attrs["aobake:metadata"])
    assert meta["orm"]["G_B_from"] == str(source) and meta["map"] == "orm"


@pytest.mark.slow
def test_empty_orm_is_roughness_1_metalness_0(two_sets, tmp_path):  # noqa: F811
    out = tmp_path / "orm.png"
    assert run_cli(two_sets, "--out", out, "--uv-set", 1, "--orm", *BAKE).exit_code == 0
    pixels, _, _ = read_image(out)
    assert (pixels[..., 1] == 1).all() and (pixels[..., 2] == 0).all()
    assert pixels[..., 0].min() < pixels[..., 0].max()  # R is the map: it varies (the ceiling)


def test_orm_takes_the_inputs_own_metallic_roughness_texture(tmp_path):
    # a glTF whose material has a metallicRoughnessTexture laid out on its TEXCOORD_0
    rgb = np.random.default_rng(5).random((N, N, 3))
    source = tmp_path / "with_mr.glb"
    glb.write_textured(source, POSITIONS, FACES, None, SET1, image.rgb_png_bytes(rgb), {},
                       packed_orm=True)
    out = tmp_path / "orm.png"
    result = run_cli(source, "--out", out, "--orm", *BAKE)
    assert result.exit_code == 0, result.output
    pixels, _, attrs = read_image(out)
    np.testing.assert_array_equal(_stored(pixels[..., 1:], 8), image.quantize(rgb[..., 1:], 8))
    assert "metallicRoughnessTexture" in json.loads(attrs["aobake:metadata"])["orm"]["G_B_from"]


@pytest.mark.slow
def test_orm_glb_keeps_the_inputs_roughness_and_metallic_factors(tmp_path, caplog):
    """glTF multiplies the metallicRoughnessTexture's G and B by the material's factors: a
    GLB whose ORM image holds the input's own G and B renders as the input only with the
    input's factors on it (not 1, which would make a material with factor 0.5 twice as
    rough).  Two materials sharing the texture, with their own factors; a material without
    factors gets glTF's default, 1; a factor that is not a number in [0, 1] is refused by
    the writer."""
    rgb = np.random.default_rng(6).random((N, N, 3))
    png = image.rgb_png_bytes(rgb)
    source = tmp_path / "factors.glb"
    halves = np.repeat([0, 1], len(FACES) // 2 + 1)[:len(FACES)]
    materials = [{"name": "half", "base_color_png": None, "base_color_factor": None,
                  "roughness_factor": 0.5, "metallic_factor": 0.25},
                 {"name": "plain", "base_color_png": None, "base_color_factor": None}]
    glb.write_textured(source, POSITIONS, FACES, None, SET1, png, {}, materials=materials,
                       face_material=halves, packed_orm=True)
    out = tmp_path / "orm.glb"
    result = run_cli(source, "--out", out, "--orm", *BAKE)
    assert result.exit_code == 0, result.output
    gltf, binary = read_glb(out)
    factors = {m["name"]: (m["pbrMetallicRoughness"]["roughnessFactor"],
                           m["pbrMetallicRoughness"]["metallicFactor"])
               for m in gltf["materials"]}
    assert factors == {"half": (0.5, 0.25), "plain": (1.0, 1.0)}
    embedded = tmp_path / "embedded.png"
    embedded.write_bytes(read_view(gltf, binary, gltf["images"][0]["bufferView"]))
    np.testing.assert_array_equal(_stored(read_image(embedded)[0][..., 1:], 8),
                                  image.quantize(rgb[..., 1:], 8))  # G/B copied as they were
    # hand-edited: a factor beyond [0, 1] is glTF's default 1 in the output, with a warning
    from test_contract_compare import glb_bytes, glb_parts

    document, rest = glb_parts(source.read_bytes())
    document["materials"][0]["pbrMetallicRoughness"]["roughnessFactor"] = 2.0
    edited = tmp_path / "edited.glb"
    edited.write_bytes(glb_bytes(json.dumps(document).encode(), rest))
    result = run_cli(edited, "--out", out, "--orm", *BAKE)
    assert result.exit_code == 0, result.output
    assert "roughnessFactor 2.0 of material 'half' is not a number in [0, 1]" in caplog.text
    pbr = read_glb(out)[0]["materials"][0]["pbrMetallicRoughness"]
    assert (pbr["roughnessFactor"], pbr["metallicFactor"]) == (1.0, 0.25)
    for bad in (1.5, float("nan"), "rough"):
        with pytest.raises(ValueError, match="roughness_factor"):
            glb.write_textured(tmp_path / "bad.glb", POSITIONS, FACES, None, SET1, png, {},
                               materials=[dict(materials[0], roughness_factor=bad)],
                               packed_orm=True)


def test_orm_source_of_another_size_is_refused(two_sets, tmp_path):  # noqa: F811
    small = tmp_path / "small.png"
    image.write_rgb(small, np.zeros((N // 2, N // 2, 3)))
    out = tmp_path / "orm.png"
    result = run_cli(two_sets, "--out", out, "--uv-set", 1, "--orm-from", small, *BAKE)
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert f"is {N // 2}x{N // 2}, the lightmap {N}x{N}" in result.output
    assert not out.exists() and "rays in" not in result.output  # refused before baking
    from aobake.outputs import write  # the library's writer checks it after a bake too
    from aobake.errors import OutputError

    baked = aobake.bake_texels(two_sets, resolution=N, rays=4, uv_set=1)
    with pytest.raises(OutputError, match=f"the lightmap {N}x{N}"):
        write(baked, out, orm_from=small)
    assert not out.exists()
    result = run_cli(two_sets, "--out", tmp_path / "v.ply", "--orm")
    # a usage mistake (as --orm on a per-vertex .glb): exit 2, like every lightmap-only option
    assert result.exit_code == 2 and "--orm packs a lightmap" in result.output


def _orm_glb(two_sets, roughness_metal, tmp_path):  # noqa: F811
    out = tmp_path / "orm.glb"
    result = run_cli(two_sets, "--out", out, "--uv-set", 1, "--orm-from", roughness_metal[0],
                     *BAKE)
    assert result.exit_code == 0, result.output
    return out


@pytest.mark.slow
def test_orm_glb_wires_one_image_to_occlusion_and_metallic_roughness(  # noqa: F811
        two_sets, roughness_metal, tmp_path):
    out = _orm_glb(two_sets, roughness_metal, tmp_path)
    gltf, binary = read_glb(out)
    material = gltf["materials"][0]
    pbr = material["pbrMetallicRoughness"]
    assert material["occlusionTexture"] == pbr["metallicRoughnessTexture"] == \
        {"index": 0, "texCoord": 1}
    assert pbr["metallicFactor"] == pbr["roughnessFactor"] == 1.0  # the texture's values
    png = read_view(gltf, binary, gltf["images"][0]["bufferView"])
    path = tmp_path / "embedded.png"
    path.write_bytes(png)
    embedded, _, _ = read_image(path)
    np.testing.assert_array_equal(_stored(embedded[..., 1:], 8),
                                  _stored(roughness_metal[1][..., 1:], 8))


def _validator():
    node = shutil.which("node")
    script = NODE_TOOLS / "validate.js"
    if node is None or not (NODE_TOOLS / "node_modules" / "gltf-validator").is_dir():
        pytest.skip("the Khronos glTF validator is not installed (npm install --prefix "
                    ".ci/node; .ci/run does)")
    return [node, str(script)]


@pytest.mark.parametrize("orm", [True, False])
def test_khronos_validator_finds_no_errors(two_sets, roughness_metal, tmp_path, orm):  # noqa: F811
    command = _validator()
    if orm:
        out = _orm_glb(two_sets, roughness_metal, tmp_path)
    else:
        out = tmp_path / "plain.glb"
        assert run_cli(two_sets, "--out", out, "--uv-set", 1, *BAKE).exit_code == 0
    done = subprocess.run(command + [str(out)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    errors = [m for m in report["issues"]["messages"] if m["severity"] == 0]
    assert report["issues"]["numErrors"] == 0, errors
    assert report["issues"]["numWarnings"] == 0, report["issues"]["messages"]
    # ... and it can fail: a GLB with a broken accessor is reported
    gltf, binary = read_glb(out)
    gltf["accessors"][0]["count"] += 10 ** 6
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    import struct

    broken = tmp_path / "broken.glb"
    broken.write_bytes(struct.pack("<4sII", b"glTF", 2, 28 + len(text) + len(binary))
                       + struct.pack("<II", len(text), 0x4E4F534A) + text
                       + struct.pack("<II", len(binary), 0x004E4942) + binary)
    bad = json.loads(subprocess.run(command + [str(broken)], capture_output=True, text=True,
                                    timeout=120).stdout)
    assert bad["issues"]["numErrors"] > 0


@pytest.mark.skipif(not os.environ.get("AOBAKE_BLENDER_PYTHON"),
                    reason="AOBAKE_BLENDER_PYTHON (a Python with bpy) not set")
def test_blender_wires_the_orm_to_occlusion(two_sets, roughness_metal, tmp_path):  # noqa: F811
    out = _orm_glb(two_sets, roughness_metal, tmp_path)
    done = subprocess.run([os.environ["AOBAKE_BLENDER_PYTHON"], str(BLENDER_CHECK), str(out)],
                          capture_output=True, text=True, timeout=600)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert done.returncode == 0 and result["ok"], result
    assert result["occlusion_tex_coord"] == 1
