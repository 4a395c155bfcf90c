"""Image files through OpenImageIO: EXR channels, PNG/TIFF integers, errors."""

import json
import struct

import numpy as np
import pytest

from aobake.errors import OutputError
from aobake.outputs.image import png_bytes, quantize, write_exr, write_ldr
from readers import read_image

H, W = 5, 7


@pytest.fixture
def maps():
    rng = np.random.default_rng(0)
    return {
        "ao": rng.random((H, W)),
        "ao_stderr": 0.01 * rng.random((H, W)),
        "obscurance": rng.random((H, W)),
        "bent_normal.X": rng.uniform(-1, 1, (H, W)),
        "bent_normal.Y": rng.uniform(-1, 1, (H, W)),
        "bent_normal.Z": rng.uniform(0, 1, (H, W)),
        "rays": rng.integers(1, 2048, (H, W)).astype(float),
        "coverage": rng.random((H, W)),
    }


def by_name(pixels, names):
    return {n: pixels[..., i] for i, n in enumerate(names)}


def leftovers(directory):
    return sorted(p.name for p in directory.iterdir())


@pytest.mark.parametrize("half", [False, True])
def test_exr_round_trip(tmp_path, maps, half):
    path = tmp_path / "ao.exr"
    meta = {"seed": 3, "samples": 256, "backend": "embree", "offset": 1e-4, "sizes": [1, 2]}
    write_exr(path, maps, meta, half=half)
    pixels, names, attrs = read_image(path)
    assert pixels.shape == (H, W, len(maps)) and pixels.dtype == np.float32
    assert sorted(names) == sorted(maps)
    assert json.loads(attrs["aobake:channels"]) == list(maps)  # the order as given
    got = by_name(pixels, names)
    for name, value in maps.items():
        if half:
            # half: 11 significant bits; integers up to 2048 stay exact
            np.testing.assert_allclose(got[name], value, rtol=2**-11, atol=2**-24)
        else:
            np.testing.assert_array_equal(got[name], value.astype(np.float32))
    np.testing.assert_array_equal(got["rays"], maps["rays"])
    if half:  # half everywhere but the counts, which stay float32 (exact, finite)
        formats = dict(zip(names, attrs["oiio:channelformats"]))
        assert {n: f for n, f in formats.items() if n != "rays"} == dict.fromkeys(
            [n for n in names if n != "rays"], "half") and formats["rays"] == "float"
    else:
        assert attrs["oiio:format"] == "float"
    assert attrs["compression"] == "zip"
    assert attrs["aobake:backend"] == "embree"
    assert attrs["aobake:seed"] == "3" and json.loads(attrs["aobake:sizes"]) == [1, 2]
    assert json.loads(attrs["aobake:metadata"]) == meta
    assert leftovers(tmp_path) == ["ao.exr"]


def test_exr_numpy_metadata_and_bad_channels(tmp_path):
    path = tmp_path / "m.exr"
    write_exr(path, {"ao": np.zeros((2, 3))}, {"n": np.int64(4), "v": np.array([1.5, 2.0])})
    _, _, attrs = read_image(path)
    assert json.loads(attrs["aobake:metadata"]) == {"n": 4, "v": [1.5, 2.0]}
    with pytest.raises(ValueError, match="channel 'b'"):
        write_exr(path, {"a": np.zeros((2, 3)), "b": np.zeros((3, 2))}, {})


@pytest.mark.parametrize("suffix,bits", [(".png", 8), (".png", 16), (".tif", 16), (".tiff", 8)])
def test_ldr_round_trip_exact_integers(tmp_path, suffix, bits):
    rng = np.random.default_rng(1)
    value = rng.random((H, W))
    value[0, :3] = [0.0, 1.0, 0.5]
    coverage = rng.random((H, W))
    coverage[1, :2] = [0.0, 1.0]  # zero alpha must not wipe the value (unassociated alpha)
    path = tmp_path / f"ao{suffix}"
    write_ldr(path, value, coverage, bit_depth=bits, metadata={"seed": 9})
    pixels, names, attrs = read_image(path)
    top = 2**bits - 1
    ints = np.rint(pixels.astype(np.float64) * top).astype(np.int64)
    assert names == ["R", "G", "B", "A"]
    expect = np.rint(np.clip(value, 0, 1) * top).astype(np.int64)
    for ch in range(3):
        np.testing.assert_array_equal(ints[..., ch], expect)
    np.testing.assert_array_equal(ints[..., 3], np.rint(coverage * top))
    assert ints[0, 0, 0] == 0 and ints[0, 1, 0] == top
    assert attrs["oiio:format"] == ("uint8" if bits == 8 else "uint16")
    assert json.loads(attrs["ImageDescription"]) == {"seed": 9}
    assert leftovers(tmp_path) == [path.name]


def test_png_is_tagged_linear(tmp_path):
    path = tmp_path / "ao.png"
    write_ldr(path, np.full((2, 2), 0.5), np.ones((2, 2)))
    data = path.read_bytes()
    chunks, i = {}, 8
    while i < len(data):
        n = struct.unpack(">I", data[i:i + 4])[0]
        chunks[data[i + 4:i + 8]] = data[i + 8:i + 8 + n]
        i += 12 + n
    assert b"sRGB" not in chunks
    assert struct.unpack(">I", chunks[b"gAMA"])[0] == 100000  # gamma 1.0
    _, _, attrs = read_image(path)
    assert attrs["aobake:metadata"] == "{}"


def test_r_only(tmp_path):
    path = tmp_path / "occ.png"
    write_ldr(path, np.full((H, W), 0.25), np.ones((H, W)), r_only=True)
    pixels, _, _ = read_image(path)
    assert np.all(np.rint(pixels[..., 0] * 255) == 64)
    assert np.all(pixels[..., 1:3] == 0) and np.all(pixels[..., 3] == 1)


def test_quantize_mapping():
    x = np.array([-1.0, 0.0, 0.5, 1.0, 2.0, np.nan, 1 / 255 * 0.49, 1 / 255 * 0.51])
    np.testing.assert_array_equal(quantize(x, 8), [0, 0, 128, 255, 255, 0, 0, 1])
    assert quantize(x, 16).dtype == np.uint16 and quantize(x, 16)[3] == 65535


def test_bad_bit_depth_and_suffix(tmp_path):
    with pytest.raises(ValueError, match="bit_depth"):
        write_ldr(tmp_path / "a.png", np.zeros((2, 2)), np.zeros((2, 2)), bit_depth=12)
    with pytest.raises(ValueError, match="bit_depth"):
        png_bytes(np.zeros((2, 2)), np.zeros((2, 2)), bit_depth=32)
    with pytest.raises(ValueError):
        write_ldr(tmp_path / "a.jpg", np.zeros((2, 2)), np.zeros((2, 2)))
    assert leftovers(tmp_path) == []


def test_unwritable_path_raises_output_error_and_leaves_nothing(tmp_path, maps):
    with pytest.raises(OutputError, match="missing"):
        write_exr(tmp_path / "missing" / "ao.exr", maps, {})
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(OutputError, match="file"):
        write_ldr(blocker / "ao.png", np.zeros((2, 2)), np.zeros((2, 2)))
    assert leftovers(tmp_path) == ["file"]


def test_oiio_failure_inside_the_temp_file_is_cleaned_up(tmp_path, maps, monkeypatch):
    # Force a failure after the temporary file exists: OIIO refuses 9-channel PNG.
    import aobake.outputs.image as image

    monkeypatch.setattr(image, "LDR_SUFFIXES", (".png", ".tif", ".tiff", ".xyz"))
    with pytest.raises(OutputError, match=r"ao\.xyz"):
        write_ldr(tmp_path / "ao.xyz", np.zeros((2, 2)), np.zeros((2, 2)))
    pixels = np.zeros((2, 2, 9), np.uint8)
    with pytest.raises(OutputError, match="channel"):
        image.write_pixels(tmp_path / "nine.png", pixels, "uint8", [f"c{i}" for i in range(9)], {})
    assert leftovers(tmp_path) == []


def test_png_bytes_decodes(tmp_path):
    value = np.linspace(0, 1, H * W).reshape(H, W)
    data = png_bytes(value, np.ones((H, W)), bit_depth=8)
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    path = tmp_path / "x.png"
    path.write_bytes(data)
    pixels, names, _ = read_image(path)
    assert pixels.shape == (H, W, 4)
    np.testing.assert_array_equal(np.rint(pixels[..., 0] * 255), np.rint(value * 255))
    assert np.all(pixels[..., 1:3] == 0)  # r_only by default for glTF occlusion


def test_half_exr_keeps_ray_counts_exact_and_finite(tmp_path):
    """--half with more than 65,504 rays per texel wrote inf into 'rays' (half's largest
    finite value): counts stay float32, exact, and nothing non-finite is written."""
    path = tmp_path / "h.exr"
    rays = np.full((2, 3), 1_000_001.0)
    write_exr(path, {"ao": np.full((2, 3), 0.5), "rays": rays}, half=True)
    pixels, names, attrs = read_image(path)
    assert np.isfinite(pixels).all()
    np.testing.assert_array_equal(pixels[..., names.index("rays")], rays)
    assert pixels[..., names.index("ao")][0, 0] == 0.5


def test_image_metadata_is_strict_json(tmp_path):
    """The image writer emitted a bare Infinity (non-JSON) for an unbounded max distance; every
    writer now shares the one strict encoder (non-finite floats as strings)."""
    import math

    def strict(text):
        return json.loads(text, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))

    meta = {"config": {"max_distance": math.inf, "tau": None}, "parameters": {"x": float("nan")}}
    for name in ("m.exr", "m.png", "m.tif"):
        path = tmp_path / name
        if name.endswith(".exr"):
            write_exr(path, {"ao": np.full((2, 2), 0.5)}, meta)
        else:
            write_ldr(path, np.full((2, 2), 0.5), np.ones((2, 2)), metadata=meta)
        _, _, attrs = read_image(path)
        data = strict(attrs.get("aobake:metadata") or attrs["ImageDescription"])
        assert data["config"]["max_distance"] == "inf" and data["parameters"]["x"] == "nan"


@pytest.mark.slow
def test_identical_inputs_give_byte_identical_images(tmp_path):
    """No time stamp in the files: the same channels written a second later are the same
    bytes (EXR, TIFF and PNG), so a cache may key bakes by file hash."""
    import time

    from aobake.outputs.image import write_exr, write_ldr

    values = np.linspace(0, 1, 48, dtype=np.float32).reshape(6, 8)
    cover = np.ones_like(values)
    for name, write in (("a.exr", lambda p: write_exr(p, {"ao": values}, {"k": 1})),
                        ("a.tif", lambda p: write_ldr(p, values, cover, metadata={"k": 1})),
                        ("a.png", lambda p: write_ldr(p, values, cover, metadata={"k": 1}))):
        first, second = tmp_path / ("1" + name), tmp_path / ("2" + name)
        write(first)
        time.sleep(1.01)  # DateTime has a resolution of one second
        write(second)
        assert first.read_bytes() == second.read_bytes(), name
