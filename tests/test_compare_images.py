"""Other tools' images as they come (issue 32 point 1): multi-part EXRs (Blender 5 writes each
render pass as a part), 8/16-bit PNG and TIFF with and without colour tags, half and float
EXR; values linearised as the tags say, a display-referred file without tags refused with
what to do, unless its transfer is stated.  Through ``aobake.outputs.read``,
``aobake.compare.compare`` and ``aobake compare``.

Tolerances: a stored 8-bit value is within half a step (0.5 / 255) of the value written, a
16-bit one within 0.5 / 65535, a half float within 2^-11 relative; linearised through the
sRGB curve, whose slope is at most 2.4 / 1.055 * (1.055 / 1.055)^1.4 = 2.275 (at 1), a
stored step moves the linear value by at most 2.275 times as much.
"""

from __future__ import annotations

import json
import struct
import zlib

import numpy as np
import OpenImageIO as oiio
import pytest
from PIL import Image, ImageCms, PngImagePlugin

from aobake.compare import compare
from aobake.errors import InputError
from aobake.outputs import read
from aobake.outputs.image import Transfer, icc_transfer, write_exr, write_ldr
from conftest import run_cli

H, W = 6, 10
F32 = float(np.finfo(np.float32).eps)
STEP8, STEP16 = 0.5 / 255, 0.5 / 65535
SRGB_SLOPE = 2.4 / 1.055  # the sRGB EOTF's largest slope, at 1
HALF = 2.0 ** -11  # half float's relative rounding


def srgb_encode(x):
    """The sRGB OETF (inverse EOTF) of linear x in [0, 1]."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


@pytest.fixture
def ao():
    """(H, W) AO in [0, 1], every value different, both ends included."""
    return np.linspace(0.0, 1.0, H * W).reshape(H, W)


@pytest.fixture
def reference(tmp_path, ao):
    """An aobake-like lightmap EXR of ``ao``: its stderr, full coverage, aobake's metadata."""
    path = tmp_path / "ref.exr"
    write_exr(path, {"ao": ao, "ao_stderr": np.full((H, W), 0.01), "coverage": np.ones((H, W))},
              {"config": {"weighting": "cosine"}})
    return path


def png(path, pixels, chunks=(), icc=None):
    """An 8-bit ('L'), 16-bit ('I;16') grey or 8-bit RGB PNG written by Pillow, with raw
    ``chunks`` ((type, body), ...) inserted after its header and an ICC profile (Pillow's
    iCCP) when given."""
    options = {"pnginfo": PngImagePlugin.PngInfo()}
    if icc is not None:
        options["icc_profile"] = icc
    Image.fromarray(pixels).save(path, **options)
    data = path.read_bytes()
    at = 8 + 12 + 13  # the signature and IHDR
    extra = b"".join(struct.pack(">I", len(body)) + kind + body +
                     struct.pack(">I", zlib.crc32(kind + body)) for kind, body in chunks)
    path.write_bytes(data[:at] + extra + data[at:])
    return path


def stored8(x):
    return np.rint(np.clip(x, 0, 1) * 255).astype(np.uint8)


def stored16(x):
    return np.rint(np.clip(x, 0, 1) * 65535).astype(np.uint16)


def oiio_image(path, pixels, fmt, attributes=(), names=None):
    """(H, W, C) float ``pixels`` written by OpenImageIO as ``fmt`` with ``attributes``."""
    h, w, c = pixels.shape
    out = oiio.ImageOutput.create(str(path))
    spec = oiio.ImageSpec(w, h, c, fmt)
    if names:
        spec.channelnames = tuple(names)
    for name, value in dict(attributes).items():
        spec.attribute(name, value)
    assert out.open(str(path), spec), out.geterror()
    assert out.write_image(np.ascontiguousarray(pixels, dtype=np.float32))
    out.close()
    return path


def multipart(path, parts, fmt=oiio.HALF):
    """A multi-part EXR: ``parts`` a list of (part name, {channel name: (H, W)}, attributes),
    the way Blender 5 writes its render passes (each part named layer.pass, its channels
    layer.pass.channel, its colorInteropID)."""
    specs = []
    for name, channels, attributes in parts:
        spec = oiio.ImageSpec(W, H, len(channels), fmt)
        spec.channelnames = tuple(channels)
        spec.attribute("oiio:subimagename", name)
        for key, value in attributes.items():
            spec.attribute(key, value)
        specs.append(spec)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), specs), out.geterror()
    for index, (spec, (_, channels, _)) in enumerate(zip(specs, parts)):
        if index:
            assert out.open(str(path), spec, "AppendSubimage"), out.geterror()
        pixels = np.stack(list(channels.values()), axis=-1).astype(np.float32)
        assert out.write_image(pixels), out.geterror()
    out.close()
    return path


def blender_parts(ao, pass_name="AO", layer="ViewLayer", channel_names="RGB", prefixed=True):
    """Blender 5's multi-part layout: Combined, the AO pass (grey RGB), Depth."""
    def named(pass_, letters):
        return [f"{layer}.{pass_}.{c}" if prefixed else c for c in letters]

    linear = {"colorInteropID": "lin_rec709_scene"}
    combined = dict(zip(named("Combined", "RGBA"),
                        [ao * 0.8, ao * 0.7, ao * 0.6, np.ones_like(ao)]))
    occlusion = dict(zip(named(pass_name, channel_names), [ao] * len(channel_names)))
    depth = {named("Depth", "Z")[0]: np.full_like(ao, 5.0)}
    return [(f"{layer}.Combined", combined, linear), (f"{layer}.{pass_name}", occlusion, linear),
            (f"{layer}.Depth", depth, {})]


# ---------------------------------------------------------------------------------------------
# multi-part EXR


@pytest.mark.parametrize("pass_name,letters", [("AO", "RGB"), ("Ambient Occlusion", "RGB"),
                                               ("AO", "X")])
def test_blender_multipart_ao_pass_is_found_by_its_name(tmp_path, ao, reference, pass_name,
                                                        letters):
    path = multipart(tmp_path / "blender.exr", blender_parts(ao, pass_name, channel_names=letters))
    values = read(path, "ao", role="candidate")
    assert values.key == f"ViewLayer.{pass_name}.{letters[0]}"
    np.testing.assert_allclose(values.value, ao, rtol=HALF, atol=0)
    assert values.transfer == "linear" and values.stderr is None
    assert any("ambient occlusion pass" in note for note in values.notes)
    m = compare(reference, path)
    assert m["candidate_key"] == values.key and m["n"] == H * W
    assert m["max_error"] <= HALF + F32


def test_every_part_is_listed_and_any_part_is_read_by_key(tmp_path, ao):
    path = multipart(tmp_path / "passes.exr", blender_parts(ao, "Diffuse"))  # no AO pass
    with pytest.raises(InputError) as caught:
        read(path, "ao", role="candidate")
    text = str(caught.value)
    for part, channel in (("ViewLayer.Combined", "ViewLayer.Combined.A"),
                          ("ViewLayer.Diffuse", "ViewLayer.Diffuse.B"),
                          ("ViewLayer.Depth", "ViewLayer.Depth.Z")):
        assert f"part {part!r}" in text and channel in text
    assert "--candidate-key" in text
    # the full name, the pass's name, or a unique end of the name
    for key in ("ViewLayer.Diffuse.R", "ViewLayer.Diffuse", "Diffuse.R"):
        values = read(path, "ao", key=key, role="candidate")
        assert values.key == "ViewLayer.Diffuse.R"
        np.testing.assert_allclose(values.value, ao, rtol=HALF, atol=0)
    assert read(path, "ao", key="Depth.Z").value[0, 0] == 5.0  # a float part of its own


def test_parts_whose_channels_carry_no_layer_are_named_by_their_part(tmp_path, ao, reference):
    path = multipart(tmp_path / "short.exr", blender_parts(ao, prefixed=False))
    values = read(path, "ao", role="candidate")
    assert values.key == "ViewLayer.AO.R"  # part ViewLayer.AO, channel R
    np.testing.assert_allclose(values.value, ao, rtol=HALF, atol=0)
    res = run_cli("compare", reference, path, "--candidate-key", "ViewLayer.AO.G", "--json")
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["candidate_key"] == "ViewLayer.AO.G"


def test_two_ao_passes_are_ambiguous_and_a_key_picks_one(tmp_path, ao, reference):
    parts = blender_parts(ao) + blender_parts(0.5 * ao, layer="Background")[1:2]
    path = multipart(tmp_path / "layers.exr", parts)
    with pytest.raises(InputError, match=r"2 ambient occlusion passes \(Background.AO, "
                                         r"ViewLayer.AO\).*--candidate-key"):
        read(path, "ao", role="candidate")
    res = run_cli("compare", reference, path)
    assert res.exit_code == 1 and "2 ambient occlusion passes" in res.output
    res = run_cli("compare", reference, path, "--candidate-key", "Background.AO", "--json")
    assert res.exit_code == 0, res.output
    m = json.loads(res.stdout)
    assert m["candidate_key"] == "Background.AO.R"
    assert m["bias"] == pytest.approx(-0.5 * np.mean(ao), abs=HALF)


def test_an_ao_pass_that_is_not_grey_is_refused(tmp_path, ao):
    parts = blender_parts(ao)
    parts[1] = (parts[1][0], {"ViewLayer.AO.R": ao, "ViewLayer.AO.G": 0.5 * ao,
                              "ViewLayer.AO.B": ao}, {})
    path = multipart(tmp_path / "colour.exr", parts)
    with pytest.raises(InputError, match="not grey.*--candidate-key ViewLayer.AO.R"):
        read(path, "ao", role="candidate")


def test_a_layered_single_part_exr_is_read_too(tmp_path, ao, reference):
    """Blender's interleaved multilayer option: one part, channels layer.pass.channel."""
    names = ["ViewLayer.Combined.R", "ViewLayer.Ambient Occlusion.R",
             "ViewLayer.Ambient Occlusion.G", "ViewLayer.Ambient Occlusion.B"]
    path = oiio_image(tmp_path / "one.exr", np.stack([0.3 * ao, ao, ao, ao], -1), oiio.FLOAT,
                      names=names)
    assert read(path, "ao", role="candidate").key == "ViewLayer.Ambient Occlusion.R"
    res = run_cli("compare", reference, path, "--candidate-key",
                  "ViewLayer.Ambient Occlusion.R", "--json")
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["max_error"] <= F32


@pytest.mark.parametrize("fmt,tolerance", [(oiio.HALF, HALF), (oiio.FLOAT, 0.0)])
def test_half_and_float_exr_without_tags_are_linear(tmp_path, ao, reference, fmt, tolerance):
    path = oiio_image(tmp_path / "y.exr", ao[..., None], fmt, names=["Y"])
    values = read(path, "ao", role="candidate")
    assert values.transfer == "linear" and values.key == "Y"
    np.testing.assert_allclose(values.value, ao, rtol=tolerance, atol=F32)


def test_exr_tagged_srgb_is_linearised(tmp_path, ao):
    path = oiio_image(tmp_path / "srgb.exr", srgb_encode(ao)[..., None], oiio.FLOAT,
                      {"oiio:ColorSpace": "srgb_rec709_scene"}, names=["Y"])
    values = read(path, "ao", role="candidate")
    assert values.transfer == "srgb"
    np.testing.assert_allclose(values.value, ao, atol=1e-6)


def test_exr_with_a_colour_space_it_cannot_undo_is_refused(tmp_path, ao):
    path = oiio_image(tmp_path / "agx.exr", ao[..., None], oiio.FLOAT,
                      {"colorInteropID": "AgX Base sRGB"}, names=["Y"])
    with pytest.raises(InputError, match="'AgX Base sRGB'.*cannot linearise.*"
                                         "--candidate-transfer srgb\\|linear"):
        read(path, "ao", role="candidate")
    assert read(path, "ao", role="candidate", transfer="linear").transfer == "linear"


# ---------------------------------------------------------------------------------------------
# PNG and TIFF: colour tags


SRGB_CHUNK = (b"sRGB", b"\x00")
GAMA_LINEAR = (b"gAMA", struct.pack(">I", 100000))
GAMA_22 = (b"gAMA", struct.pack(">I", 45455))


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("case", ["sRGB", "cICP sRGB", "iCCP sRGB", "gAMA 1/2.2", "gAMA 1",
                                  "cICP linear"])
def test_tagged_png_is_linearised_as_its_tags_say(tmp_path, ao, reference, bits, case):
    encode = {"sRGB": srgb_encode, "cICP sRGB": srgb_encode, "iCCP sRGB": srgb_encode,
              "gAMA 1/2.2": lambda x: x ** (1 / 2.2)}.get(case, lambda x: x)
    chunks = {"sRGB": [SRGB_CHUNK], "cICP sRGB": [(b"cICP", bytes([1, 13, 0, 1]))],
              "gAMA 1/2.2": [GAMA_22], "gAMA 1": [GAMA_LINEAR],
              "cICP linear": [(b"cICP", bytes([1, 8, 0, 1]))]}.get(case, [])
    icc = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes() \
        if case == "iCCP sRGB" else None
    stored = (stored8 if bits == 8 else stored16)(encode(ao))
    path = png(tmp_path / "cand.png", stored, chunks, icc)
    values = read(path, "ao", role="candidate")
    step = STEP8 if bits == 8 else STEP16
    slope = {"gAMA 1/2.2": 2.2, "gAMA 1": 1.0, "cICP linear": 1.0}.get(case, SRGB_SLOPE)
    assert values.transfer == {"gAMA 1/2.2": "gamma 2.2", "gAMA 1": "linear",
                               "cICP linear": "linear"}.get(case, "srgb")
    np.testing.assert_allclose(values.value, ao, rtol=0, atol=slope * step + 1e-6)
    m = compare(reference, path)
    assert abs(m["bias"]) <= slope * step + 1e-6
    assert m["candidate_transfer"] == values.transfer


@pytest.mark.parametrize("bits", [8, 16])
def test_untagged_png_is_refused_with_what_to_do(tmp_path, ao, reference, bits):
    stored = (stored8 if bits == 8 else stored16)(srgb_encode(ao))
    path = png(tmp_path / "plain.png", stored)
    with pytest.raises(InputError) as caught:
        compare(reference, path)
    text = str(caught.value)
    assert text.startswith(f"{path}: {'an' if bits == 8 else 'a'} {bits}-bit PNG without a "
                           "colour chunk (sRGB, gAMA, cICP or iCCP) holds display-referred values")
    assert "display-referred" in text and "--candidate-transfer srgb|linear" in text
    assert "candidate_transfer=" in text and "gAMA 1.0" in text
    res = run_cli("compare", reference, path)
    assert res.exit_code == 1 and res.output.count("\n") == 1 and "display-referred" in res.output
    # stated: the same file compared as sRGB, or (wrongly, as the user says) as linear
    m = compare(reference, path, candidate_transfer="srgb")
    assert abs(m["bias"]) <= SRGB_SLOPE * STEP8 + 1e-6 and m["candidate_transfer"] == "srgb"
    assert any("linearised" in note for note in m["notes"])
    res = run_cli("compare", reference, path, "--candidate-transfer", "linear", "--json")
    assert res.exit_code == 0, res.output
    m = json.loads(res.stdout)
    # the sRGB curve lifts mid-tones: compared as linear, the bias the issue measured (~+0.14)
    assert m["bias"] == pytest.approx(np.mean(srgb_encode(ao) - ao), abs=STEP8)
    assert m["bias"] > 0.1 and m["candidate_transfer"] == "linear" and not m["warnings"]


def test_a_stated_transfer_wins_over_the_tags_with_a_warning(tmp_path, ao, reference):
    path = png(tmp_path / "srgb.png", stored8(ao), [SRGB_CHUNK])  # linear values tagged sRGB
    m = compare(reference, path, candidate_transfer="linear")
    assert abs(m["bias"]) <= STEP8 + F32 and m["candidate_transfer"] == "linear"
    assert len(m["warnings"]) == 1 and "its sRGB chunk says it holds sRGB-encoded values; " \
        "read as linear, as stated (--candidate-transfer linear)" in m["warnings"][0]


def test_the_reference_transfer_is_stated_the_same_way(tmp_path, ao):
    ref = png(tmp_path / "ref.png", stored16(srgb_encode(ao)))
    cand = oiio_image(tmp_path / "cand.exr", ao[..., None], oiio.FLOAT, names=["Y"])
    with pytest.raises(InputError, match="--reference-transfer srgb\\|linear"):
        compare(ref, cand)
    res = run_cli("compare", ref, cand, "--reference-transfer", "srgb", "--json")
    assert res.exit_code == 0, res.output
    m = json.loads(res.stdout)
    assert m["reference_transfer"] == "srgb" and m["max_error"] <= SRGB_SLOPE * STEP16 + 1e-6


def test_tiff_tags_icc_and_float(tmp_path, ao):
    # 8-bit TIFF tagged sRGB through OpenImageIO (the EXIF colour space)
    srgb = oiio_image(tmp_path / "srgb.tif", np.repeat(srgb_encode(ao)[..., None], 3, -1),
                      oiio.UINT8, {"oiio:ColorSpace": "sRGB"})
    values = read(srgb, "ao", role="candidate")
    assert values.transfer == "srgb" and values.key == "R"
    np.testing.assert_allclose(values.value, ao, atol=SRGB_SLOPE * STEP8 + 1e-6)
    # an ICC profile (Pillow), 8-bit RGB
    rgb = np.repeat(stored8(srgb_encode(ao))[..., None], 3, -1)
    icc = tmp_path / "icc.tif"
    Image.fromarray(rgb).save(icc, icc_profile=ImageCms.ImageCmsProfile(
        ImageCms.createProfile("sRGB")).tobytes())
    assert read(icc, "ao", role="candidate").transfer == "srgb"
    # no tag: 16-bit refused, float linear
    plain = oiio_image(tmp_path / "plain.tif", np.repeat(ao[..., None], 3, -1), oiio.UINT16)
    with pytest.raises(InputError, match="a 16-bit TIF without a colour tag .* display-referred"):
        read(plain, "ao", role="candidate")
    assert read(plain, "ao", role="candidate", transfer="linear").value == \
        pytest.approx(ao, abs=STEP16)
    floats = oiio_image(tmp_path / "float.tif", ao[..., None], oiio.FLOAT, names=["Y"])
    values = read(floats, "ao", role="candidate")
    assert values.transfer == "linear"
    np.testing.assert_allclose(values.value, ao, atol=F32)


@pytest.mark.parametrize("suffix,bits", [(".png", 8), (".png", 16), (".tif", 8), (".tif", 16)])
def test_aobake_own_images_read_as_before(tmp_path, ao, reference, suffix, bits):
    """aobake's PNG/TIFF hold linear AO: its PNG says so (gAMA 1.0, no sRGB chunk), its
    metadata says it is aobake's (a TIFF has no tag for linear); without the metadata a
    PNG of write_ldr is still read as linear by its gAMA."""
    path = tmp_path / f"own{suffix}"
    write_ldr(path, ao, np.ones((H, W)), bit_depth=bits, metadata={"config": {}, "map": "ao"})
    values = read(path, "ao", role="candidate")
    assert values.transfer == "linear" and values.key == "R"
    np.testing.assert_allclose(values.value, ao, atol=(STEP8 if bits == 8 else STEP16) + F32)
    assert compare(reference, path)["candidate_transfer"] == "linear"
    with pytest.raises(InputError, match="is an aobake output, which holds linear values"):
        compare(reference, path, candidate_transfer="srgb")
    if suffix == ".png":
        bare = tmp_path / f"bare{suffix}"
        write_ldr(bare, ao, np.ones((H, W)), bit_depth=bits)
        assert read(bare, "ao", role="candidate").transfer == "linear"


def test_linearised_stderr_follows_the_curve(tmp_path, ao):
    """A stderr beside sRGB-encoded values is carried through the curve by its slope."""
    path = oiio_image(tmp_path / "srgb.exr", np.stack([srgb_encode(ao), np.full((H, W), 1e-3)],
                                                      -1), oiio.FLOAT,
                      {"colorInteropID": "srgb_rec709_scene"}, names=["ao", "ao_stderr"])
    values = read(path, "ao", role="candidate")
    v = srgb_encode(ao)
    slope = Transfer("srgb", "").slope(v)
    np.testing.assert_allclose(values.stderr, 1e-3 * slope, rtol=1e-5)


def test_bad_transfer_arguments(reference, tmp_path):
    with pytest.raises(InputError, match="transfer must be one of"):
        read(reference, "ao", transfer="gamma")
    with pytest.raises(InputError, match="candidate_transfer must be one of"):
        compare(reference, reference, candidate_transfer="sRGB")
    res = run_cli("compare", reference, reference, "--candidate-transfer", "rec709")
    assert res.exit_code == 2 and "--candidate-transfer" in res.output


# ---------------------------------------------------------------------------------------------
# ICC curves and broken colour chunks


def icc_profile(trc: bytes, space=b"GRAY", sig=b"kTRC") -> bytes:
    """A minimal ICC profile: the header and one TRC tag."""
    tag = trc + b"\0" * (-len(trc) % 4)
    header = bytearray(128)
    header[16:20], header[36:40] = space, b"acsp"
    body = bytes(header) + struct.pack(">I", 1) + struct.pack(">4sII", sig, 144, len(trc)) + tag
    return struct.pack(">I", len(body)) + body[4:]


@pytest.mark.parametrize("trc,kind,gamma", [
    (b"curv\0\0\0\0" + struct.pack(">I", 0), "linear", 1.0),
    (b"curv\0\0\0\0" + struct.pack(">IH", 1, 563), "gamma", 563 / 256),  # 2.2 in u8.8
    (b"para\0\0\0\0" + struct.pack(">HHi", 0, 0, 2 << 16), "gamma", 2.0),
    (b"para\0\0\0\0" + struct.pack(">HH5i", 3, 0, *[round(p * 65536) for p in
                                                    (2.4, 1 / 1.055, 0.055 / 1.055, 1 / 12.92,
                                                     0.04045)]), "srgb", 1.0),
])
def test_icc_curves(trc, kind, gamma):
    transfer = icc_transfer(icc_profile(trc), "Y", "its ICC profile")
    assert transfer.kind == kind and transfer.gamma == pytest.approx(gamma, rel=1e-3)


def test_icc_table_curve_is_interpolated():
    x = np.linspace(0, 1, 17)
    table = np.rint(x ** 3 * 65535).astype(">u2").tobytes()
    transfer = icc_transfer(icc_profile(b"curv\0\0\0\0" + struct.pack(">I", 17) + table),
                            "Y", "its ICC profile")
    assert transfer.kind == "curve" and transfer.name == "ICC curve"
    np.testing.assert_allclose(transfer.to_linear(x), x ** 3, atol=1e-4)
    broken = icc_transfer(b"not a profile" * 20, "Y", "its ICC profile")
    assert broken.kind == "unsupported" and "cannot be read" in broken.source


def test_broken_colour_chunks_are_refused_naming_the_file(tmp_path, ao):
    cases = {"cicp_pq": [(b"cICP", bytes([9, 16, 0, 1]))], "cicp_short": [(b"cICP", b"\x01")],
             "gama_zero": [(b"gAMA", struct.pack(">I", 0))],
             "iccp_garbage": [(b"iCCP", b"name\0\0" + zlib.compress(b"garbage"))]}
    for name, chunks in cases.items():
        path = png(tmp_path / f"{name}.png", stored8(ao), chunks)
        with pytest.raises(InputError, match=rf"^{path}: its .*--candidate-transfer"):
            read(path, "ao", role="candidate")
        assert read(path, "ao", role="candidate", transfer="linear").transfer == "linear"


def test_a_stated_transfer_applies_to_per_vertex_numbers_too(tmp_path):
    """Per-vertex files hold numbers, read as linear; sRGB-encoded vertex colours (another
    tool's PLY) are linearised when stated."""
    ao = np.linspace(0.0, 1.0, 11)
    np.savez(tmp_path / "ref.npz", ao=ao, ao_stderr=np.full(11, 0.01))
    np.savez(tmp_path / "cand.npz", ao=srgb_encode(ao))
    assert compare(tmp_path / "ref.npz", tmp_path / "cand.npz")["bias"] > 0.1
    m = compare(tmp_path / "ref.npz", tmp_path / "cand.npz", candidate_transfer="srgb")
    assert m["max_error"] <= 1e-12 and m["candidate_transfer"] == "srgb"


@pytest.mark.parametrize("key, a, b", [
    ("charts", 54, 30), ("atlas", "instance regions", "own UVs"), ("uv_set", 0, 1),
    ("instances", {"regions": [[2, 2, 10, 10]]}, {"regions": [[2, 2, 10, 10], [14, 2, 6, 6]]}),
])
def test_lightmaps_of_other_layouts_are_refused(tmp_path, ao, key, a, b):
    """Two aobake lightmaps whose texels are other surface points (another atlas, a set's
    regions placed otherwise: a --bake subset's) are refused, not compared texel by texel;
    the same layout with other settings is compared."""
    files = []
    for name, value in (("a", a), ("b", b), ("c", a)):
        path = tmp_path / f"{name}.exr"
        write_exr(path, {"ao": ao, "coverage": np.ones((H, W))},
                  {"config": {"weighting": "cosine", "rays": 64 if name == "c" else 16},
                   "texture": {key: value, "padding": 2 if name == "c" else 4}})
        files.append(path)
    with pytest.raises(InputError, match="is a lightmap of another layout"):
        compare(files[0], files[1])
    assert compare(files[0], files[2])["rmse"] == 0.0


def test_the_kind_of_what_a_file_holds_is_named(tmp_path, ao, reference):
    """A view, a lightmap and per-vertex values are named as what they are in a refusal."""
    view = tmp_path / "view.exr"
    write_exr(view, {"ao": ao, "coverage": np.ones((H, W))},
              {"config": {"weighting": "cosine"}, "camera": {"width": W, "height": H}})
    vertices = tmp_path / "v.npz"
    np.savez(vertices, ao=np.ones(4), positions=np.zeros((4, 3)))
    with pytest.raises(InputError, match=r"holds per-vertex values, but the reference "
                                         r".*view\.exr holds a camera view \(per pixel\)"):
        compare(view, vertices)
    with pytest.raises(InputError, match=r"holds a camera view \(per pixel\), but the "
                                         r"reference .*ref\.exr holds a lightmap"):
        compare(reference, view)
