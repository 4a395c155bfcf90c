"""Round trips of the output writers (NPZ, PLY, GLB, report.json).

Values are compared with explicit tolerances: positions exactly where the format
stores float64, float32-stored values exactly against the float32 cast of the
input (atol 0), and float32 against float64 input within float32 rounding.
"""

from __future__ import annotations

import json
import math
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import trimesh

from aobake.errors import OutputError
from aobake.outputs import glb, npz, ply, write_vertices
from aobake.quantities import FIELDS
from aobake.outputs.registry import suffixes
from readers import read_accessor, read_glb, read_ply, read_view
from aobake.outputs.strictjson import to_jsonable, write_report

# float32 storage of values in [-2, 2]: half an ulp is 1.2e-7
F32_ATOL = 2.5e-7

METADATA = {
    "convention": "ao: 1 = fully open, 0 = fully occluded",
    "samples": np.int64(64),
    "max_distance": math.inf,
    "offset": np.float32(1e-4),
    "path": Path("scene dir/model.obj"),
    "seeds": np.arange(3),
    "nested": {"estimator": "cosine", "flags": [True, False, None]},
}
METADATA_JSON = {
    "convention": "ao: 1 = fully open, 0 = fully occluded",
    "samples": 64,
    "max_distance": "inf",
    "offset": float(np.float32(1e-4)),
    "path": "scene dir/model.obj",
    "seeds": [0, 1, 2],
    "nested": {"estimator": "cosine", "flags": [True, False, None]},
}


@pytest.fixture
def mesh():
    return trimesh.creation.icosphere(subdivisions=1)


def make_fields(mesh, seed=0):
    """Every field of the registry, random but valid: (n,) in [0, 1], (n, 3) unit, rays int."""
    rng = np.random.default_rng(seed)
    n = len(mesh.vertices)
    bent = rng.normal(size=(n, 3))
    fields = {
        "normals": np.asarray(mesh.vertex_normals, dtype=np.float64),
        "bent_normal": bent / np.linalg.norm(bent, axis=1, keepdims=True),
        "bent_normal_stderr": 0.1 * rng.random(n),
        "rays": rng.integers(1, 1 << 20, n),
        "missed": rng.integers(0, 2, n).astype(np.uint8),
        "back_hit": rng.integers(0, 2, n).astype(np.uint8),
        "projection_distance": 0.1 * rng.normal(size=n),
        "thickness": 2 * rng.random(n),
        "thickness_stderr": 0.05 * rng.random(n),
    }
    for name in ("ao", "obscurance", "indirect"):
        value, se = rng.random(n), 0.05 * rng.random(n)
        fields.update({name: value, f"{name}_stderr": se, f"{name}_ci_low": value - 2 * se,
                       f"{name}_ci_high": value + 2 * se})
    assert set(fields) == set(FIELDS), "make_fields covers every registry field"
    return fields


def make_png(rgb: np.ndarray) -> bytes:
    """(h, w, 3) uint8 -> bytes of an 8-bit RGB PNG (no dependency needed)."""
    height, width, _ = rgb.shape
    raw = b"".join(b"\0" + row.tobytes() for row in rgb)

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = struct.pack(">I", zlib.crc32(kind + data))
        return struct.pack(">I", len(data)) + kind + data + crc

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(raw))
        + chunk(b"IEND", b"")
    )


def expected_grey(value) -> np.ndarray:
    """The documented colour mapping, from the float32 value the file stores."""
    value = np.asarray(value, dtype=np.float32).astype(np.float64)
    return np.rint(np.nan_to_num(np.clip(value, 0, 1), nan=0.0) * 255).astype(np.uint8)


# ----------------------------------------------------------------------------- NPZ


def test_npz_round_trip(tmp_path, mesh):
    fields = make_fields(mesh)
    path = tmp_path / "bake.npz"
    npz.write(path, mesh.vertices, mesh.faces, fields, METADATA)
    with np.load(path, allow_pickle=False) as data:
        loaded = {k: data[k] for k in data.files}
    assert set(loaded) == {"positions", "faces", "metadata", *fields}
    assert loaded["positions"].dtype == np.float64
    np.testing.assert_array_equal(loaded["positions"], mesh.vertices)
    assert loaded["faces"].dtype == np.int64
    np.testing.assert_array_equal(loaded["faces"], mesh.faces)
    assert loaded["normals"].dtype == np.float64
    np.testing.assert_array_equal(loaded["normals"], fields["normals"])
    for name in ("ao", "ao_stderr", "obscurance", "obscurance_stderr", "bent_normal", "bent_normal_stderr"):
        assert loaded[name].dtype == np.float32, name
        np.testing.assert_allclose(loaded[name], fields[name], rtol=0, atol=F32_ATOL)
    assert loaded["rays"].dtype == np.int32
    np.testing.assert_array_equal(loaded["rays"], fields["rays"])
    assert loaded["metadata"].shape == ()
    assert json.loads(loaded["metadata"].item()) == METADATA_JSON


def test_npz_keeps_the_name_without_npz_suffix(tmp_path, mesh):
    # np.savez appends ".npz" to file names; the writer must not
    path = tmp_path / "bake.data"
    npz.write(path, mesh.vertices, mesh.faces, {"ao": np.ones(len(mesh.vertices))}, {})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bake.data"]
    with np.load(path) as data:
        assert set(data.files) == {"positions", "faces", "ao", "metadata"}


def test_npz_only_present_fields(tmp_path, mesh):
    path = tmp_path / "bake.npz"
    npz.write(path, mesh.vertices, mesh.faces, {}, None)
    with np.load(path) as data:
        assert set(data.files) == {"positions", "faces", "metadata"}
        assert json.loads(data["metadata"].item()) == {}


# ----------------------------------------------------------------------------- PLY


def test_ply_own_parse(tmp_path, mesh):
    fields = make_fields(mesh)
    path = tmp_path / "bake.ply"
    ply.write(path, mesh.vertices, mesh.faces, fields, METADATA)

    header = path.read_bytes().split(b"end_header\n")[0].decode("ascii").splitlines()
    properties = [line.split()[1:] for line in header if line.startswith("property")]
    assert properties == [
        ["double", "x"], ["double", "y"], ["double", "z"],
        ["float", "nx"], ["float", "ny"], ["float", "nz"],
        ["float", "ao"], ["float", "ao_stderr"], ["float", "ao_ci_low"], ["float", "ao_ci_high"],
        ["float", "obscurance"], ["float", "obscurance_stderr"],
        ["float", "obscurance_ci_low"], ["float", "obscurance_ci_high"],
        ["float", "bent_normal_x"], ["float", "bent_normal_y"], ["float", "bent_normal_z"],
        ["float", "bent_normal_stderr"],
        ["float", "indirect"], ["float", "indirect_stderr"],
        ["float", "indirect_ci_low"], ["float", "indirect_ci_high"],
        ["float", "thickness"], ["float", "thickness_stderr"],
        ["int", "rays"],
        ["int", "missed"], ["int", "back_hit"], ["float", "projection_distance"],
        ["uchar", "red"], ["uchar", "green"], ["uchar", "blue"],
        ["list", "uchar", "int", "vertex_indices"],
    ]  # fmt: skip
    assert header[1] == "format binary_little_endian 1.0"
    # the metadata comment is one whitespace-free token
    (comment,) = [line for line in header if line.startswith("comment aobake-metadata ")]
    assert len(comment.split()) == 3

    vertex, faces, metadata = read_ply(path)
    assert metadata == METADATA_JSON
    np.testing.assert_array_equal(faces, mesh.faces)
    positions = np.column_stack([vertex[a] for a in "xyz"])
    np.testing.assert_array_equal(positions, mesh.vertices)  # double: exact
    normals = np.column_stack([vertex[a] for a in ("nx", "ny", "nz")])
    np.testing.assert_allclose(normals, fields["normals"], rtol=0, atol=F32_ATOL)
    for name in ("ao", "ao_stderr", "obscurance", "obscurance_stderr", "bent_normal_stderr"):
        np.testing.assert_allclose(vertex[name], fields[name], rtol=0, atol=F32_ATOL)
    bent = np.column_stack([vertex[f"bent_normal_{a}"] for a in "xyz"])
    np.testing.assert_allclose(bent, fields["bent_normal"], rtol=0, atol=F32_ATOL)
    np.testing.assert_array_equal(vertex["rays"], fields["rays"])
    for channel in ("red", "green", "blue"):
        np.testing.assert_array_equal(vertex[channel], expected_grey(fields["ao"]))


def test_ply_colour_mapping_edges(tmp_path):
    ao = np.array([0.0, 0.5, 1.0, -0.2, 1.3, np.nan, 0.25, 1 / 255])
    n = len(ao)
    positions = np.column_stack([np.arange(n), np.zeros(n), np.zeros(n)]).astype(float)
    path = tmp_path / "edges.ply"
    ply.write(path, positions, np.zeros((0, 3), dtype=np.int64), {"ao": ao}, {})
    vertex, faces, _ = read_ply(path)
    assert faces.shape == (0, 3)
    # linear grey, no sRGB curve; 127.5 rounds half to even; NaN -> 0
    np.testing.assert_array_equal(vertex["red"], [0, 128, 255, 0, 255, 0, 64, 1])


def test_ply_colour_source(tmp_path, mesh):
    fields = make_fields(mesh)
    path = tmp_path / "obscurance.ply"
    ply.write(path, mesh.vertices, mesh.faces, {"obscurance": fields["obscurance"]}, {})
    vertex, _, _ = read_ply(path)
    np.testing.assert_array_equal(vertex["green"], expected_grey(fields["obscurance"]))

    ply.write(path, mesh.vertices, mesh.faces, {"rays": fields["rays"]}, {})
    vertex, _, _ = read_ply(path)
    assert (vertex["blue"] == 255).all()
    assert "ao" not in vertex.dtype.names


def test_ply_trimesh_load(tmp_path, mesh):
    fields = make_fields(mesh)
    path = tmp_path / "bake.ply"
    ply.write(path, mesh.vertices, mesh.faces, fields, METADATA)
    loaded = trimesh.load(path, process=False)
    np.testing.assert_array_equal(loaded.vertices, mesh.vertices)
    np.testing.assert_array_equal(loaded.faces, mesh.faces)
    # trimesh keeps every vertex property in the raw element data
    data = loaded.metadata["_ply_raw"]["vertex"]["data"]
    np.testing.assert_allclose(data["ao"], fields["ao"], rtol=0, atol=F32_ATOL)
    np.testing.assert_array_equal(data["rays"], fields["rays"])
    grey = expected_grey(fields["ao"])
    np.testing.assert_array_equal(loaded.visual.vertex_colors[:, :3], np.column_stack([grey] * 3))


# ----------------------------------------------------------------------------- GLB


def check_glb_layout(path: Path) -> tuple[dict, bytes]:
    """Container invariants: lengths, chunk types, 4-byte alignment, views in bounds."""
    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    json_length, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A and json_length % 4 == 0
    bin_start = 20 + json_length
    bin_length, bin_type = struct.unpack_from("<II", data, bin_start)
    assert bin_type == 0x004E4942 and bin_length % 4 == 0
    assert bin_start + 8 + bin_length == length
    gltf, binary = read_glb(path)
    assert len(binary) == bin_length
    (buffer,) = gltf["buffers"]
    assert "uri" not in buffer and buffer["byteLength"] <= bin_length
    for view in gltf["bufferViews"]:
        assert view["byteOffset"] % 4 == 0
        assert view["byteOffset"] + view["byteLength"] <= buffer["byteLength"]
    for accessor in gltf["accessors"]:
        view = gltf["bufferViews"][accessor["bufferView"]]
        width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[accessor["type"]]
        assert accessor["componentType"] in (5125, 5126)
        assert accessor["count"] * width * 4 == view["byteLength"]
    return gltf, binary


def attribute(gltf, binary, name):
    (primitive,) = gltf["meshes"][0]["primitives"]
    return read_accessor(gltf, binary, primitive["attributes"][name])


def test_glb_round_trip(tmp_path, mesh):
    fields = make_fields(mesh)
    path = tmp_path / "bake.glb"
    glb.write(path, mesh.vertices, mesh.faces, fields, METADATA)
    gltf, binary = check_glb_layout(path)

    assert gltf["asset"]["version"] == "2.0"
    assert gltf["asset"]["generator"] == "aobake"
    assert gltf["asset"]["extras"] == METADATA_JSON
    (primitive,) = gltf["meshes"][0]["primitives"]
    assert primitive["mode"] == 4
    assert set(primitive["attributes"]) == {
        "POSITION", "NORMAL", "COLOR_0", "_AO", "_AO_STDERR", "_AO_CI_LOW", "_AO_CI_HIGH",
        "_OBSCURANCE", "_OBSCURANCE_STDERR", "_OBSCURANCE_CI_LOW", "_OBSCURANCE_CI_HIGH",
        "_BENT_NORMAL", "_BENT_NORMAL_STDERR", "_INDIRECT", "_INDIRECT_STDERR",
        "_INDIRECT_CI_LOW", "_INDIRECT_CI_HIGH", "_THICKNESS", "_THICKNESS_STDERR", "_RAYS",
    }  # fmt: skip
    assert gltf["scenes"][gltf["scene"]]["nodes"] == [0]
    assert gltf["nodes"][0]["mesh"] == 0
    pbr = gltf["materials"][primitive["material"]]["pbrMetallicRoughness"]
    assert pbr["baseColorFactor"] == [1.0, 1.0, 1.0, 1.0]

    position = attribute(gltf, binary, "POSITION")
    assert position.dtype == np.float32
    np.testing.assert_allclose(position, mesh.vertices, rtol=0, atol=F32_ATOL)
    accessor = gltf["accessors"][primitive["attributes"]["POSITION"]]
    # min/max must equal the stored float32 bounds exactly
    assert accessor["min"] == position.min(axis=0).tolist()
    assert accessor["max"] == position.max(axis=0).tolist()

    indices = read_accessor(gltf, binary, primitive["indices"])
    assert gltf["accessors"][primitive["indices"]]["componentType"] == 5125
    np.testing.assert_array_equal(indices.reshape(-1, 3), mesh.faces)

    normal = attribute(gltf, binary, "NORMAL")
    np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1.0, rtol=0, atol=1e-6)
    np.testing.assert_allclose(normal, fields["normals"], rtol=0, atol=1e-6)

    color = attribute(gltf, binary, "COLOR_0")
    assert color.shape == (len(mesh.vertices), 4)
    for channel in range(3):
        np.testing.assert_array_equal(color[:, channel], fields["ao"].astype(np.float32))
    assert (color[:, 3] == 1).all()

    for name, attr in glb.CUSTOM_ATTRIBUTES.items():
        values = attribute(gltf, binary, attr)
        assert values.dtype == np.float32, attr
        assert values.shape == fields[name].shape, attr
        np.testing.assert_array_equal(values, fields[name].astype(np.float32), err_msg=attr)


def test_glb_colour_from_obscurance_and_no_colour(tmp_path, mesh):
    fields = make_fields(mesh)
    path = tmp_path / "obscurance.glb"
    glb.write(path, mesh.vertices, mesh.faces, {"obscurance": fields["obscurance"]}, {})
    gltf, binary = check_glb_layout(path)
    color = attribute(gltf, binary, "COLOR_0")
    np.testing.assert_array_equal(color[:, 0], fields["obscurance"].astype(np.float32))
    assert "extras" not in gltf["asset"]  # empty metadata

    glb.write(path, mesh.vertices, mesh.faces, {}, {})
    gltf, _ = check_glb_layout(path)
    assert set(gltf["meshes"][0]["primitives"][0]["attributes"]) == {"POSITION"}


def test_glb_trimesh_load(tmp_path, mesh):
    fields = make_fields(mesh)
    path = tmp_path / "bake.glb"
    glb.write(path, mesh.vertices, mesh.faces, fields, METADATA)
    loaded = trimesh.load(path).to_geometry()
    np.testing.assert_allclose(loaded.vertices, mesh.vertices, rtol=0, atol=F32_ATOL)
    np.testing.assert_array_equal(loaded.faces, mesh.faces)
    # trimesh keeps "_" attributes in vertex_attributes; scalars come back (n, 1)
    ao = np.asarray(loaded.vertex_attributes["_AO"]).reshape(-1)
    np.testing.assert_array_equal(ao, fields["ao"].astype(np.float32))
    bent = np.asarray(loaded.vertex_attributes["_BENT_NORMAL"])
    np.testing.assert_array_equal(bent, fields["bent_normal"].astype(np.float32))


def test_glb_rejects_empty(tmp_path, mesh):
    with pytest.raises(ValueError, match="at least one"):
        glb.write(tmp_path / "e.glb", mesh.vertices, np.zeros((0, 3), int), {}, {})
    assert list(tmp_path.iterdir()) == []


def test_glb_zero_normal_becomes_unit(tmp_path, mesh, caplog):
    normals = np.array(mesh.vertex_normals)
    normals[0] = 0.0
    path = tmp_path / "z.glb"
    glb.write(path, mesh.vertices, mesh.faces, {"normals": normals}, {})
    gltf, binary = check_glb_layout(path)
    np.testing.assert_array_equal(attribute(gltf, binary, "NORMAL")[0], [0, 0, 1])
    assert "zero-length normals" in caplog.text


# --------------------------------------------------------------------- textured GLB


@pytest.fixture
def atlas(mesh):
    rng = np.random.default_rng(1)
    n = len(mesh.vertices)
    rgb = np.zeros((4, 8, 3), dtype=np.uint8)
    rgb[..., 0] = np.arange(32, dtype=np.uint8).reshape(4, 8) * 8
    return {
        "atlas_uv": rng.random((n, 2)),
        "base_uv": 3 * rng.random((n, 2)) - 1,  # tiling UVs outside [0, 1]
        "occlusion_png": make_png(rgb),
        "base_color_png": make_png(np.full((2, 2, 3), 200, dtype=np.uint8)),
    }


def test_textured_glb_atlas_only(tmp_path, mesh, atlas):
    path = tmp_path / "lightmap.glb"
    glb.write_textured(
        path, mesh.vertices, mesh.faces, mesh.vertex_normals,
        atlas["atlas_uv"], atlas["occlusion_png"], METADATA,
    )  # fmt: skip
    gltf, binary = check_glb_layout(path)
    assert gltf["asset"]["extras"] == METADATA_JSON
    (primitive,) = gltf["meshes"][0]["primitives"]
    assert set(primitive["attributes"]) == {"POSITION", "NORMAL", "TEXCOORD_0"}
    material = gltf["materials"][primitive["material"]]
    occlusion = material["occlusionTexture"]
    assert occlusion["texCoord"] == 0
    texture = gltf["textures"][occlusion["index"]]
    image = gltf["images"][texture["source"]]
    assert image["mimeType"] == "image/png"
    assert read_view(gltf, binary, image["bufferView"]) == atlas["occlusion_png"]
    sampler = gltf["samplers"][texture["sampler"]]
    assert sampler == {"magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071}
    assert "baseColorTexture" not in material["pbrMetallicRoughness"]

    # glTF's v runs down the image: stored v = 1 - v(OBJ)
    uv = attribute(gltf, binary, "TEXCOORD_0")
    np.testing.assert_allclose(uv[:, 0], atlas["atlas_uv"][:, 0], rtol=0, atol=F32_ATOL)
    np.testing.assert_allclose(uv[:, 1], 1 - atlas["atlas_uv"][:, 1], rtol=0, atol=F32_ATOL)

    # trimesh (an independent reader) flips v back on load
    loaded = trimesh.load(path).to_geometry()
    np.testing.assert_allclose(loaded.vertices, mesh.vertices, rtol=0, atol=F32_ATOL)
    np.testing.assert_array_equal(loaded.faces, mesh.faces)
    np.testing.assert_allclose(loaded.visual.uv, atlas["atlas_uv"], rtol=0, atol=F32_ATOL)


def test_textured_glb_keeps_base_uv(tmp_path, mesh, atlas):
    path = tmp_path / "lightmap.glb"
    factor = [0.5, 0.25, 1.0, 1.0]
    glb.write_textured(
        path, mesh.vertices, mesh.faces, None, atlas["atlas_uv"], atlas["occlusion_png"], {},
        base_uv=atlas["base_uv"], base_color_png=atlas["base_color_png"], base_color_factor=factor,
    )  # fmt: skip
    gltf, binary = check_glb_layout(path)
    (primitive,) = gltf["meshes"][0]["primitives"]
    assert set(primitive["attributes"]) == {"POSITION", "TEXCOORD_0", "TEXCOORD_1"}
    material = gltf["materials"][primitive["material"]]
    assert material["occlusionTexture"]["texCoord"] == 1
    pbr = material["pbrMetallicRoughness"]
    assert pbr["baseColorFactor"] == factor
    assert pbr["baseColorTexture"]["texCoord"] == 0
    base_texture = gltf["textures"][pbr["baseColorTexture"]["index"]]
    base_image = gltf["images"][base_texture["source"]]
    assert read_view(gltf, binary, base_image["bufferView"]) == atlas["base_color_png"]
    assert gltf["samplers"][base_texture["sampler"]]["wrapS"] == 10497  # base UVs may tile
    occlusion_texture = gltf["textures"][material["occlusionTexture"]["index"]]
    occlusion_image = gltf["images"][occlusion_texture["source"]]
    assert read_view(gltf, binary, occlusion_image["bufferView"]) == atlas["occlusion_png"]

    for name, uv in (("TEXCOORD_0", atlas["base_uv"]), ("TEXCOORD_1", atlas["atlas_uv"])):
        stored = attribute(gltf, binary, name)
        np.testing.assert_allclose(stored[:, 0], uv[:, 0], rtol=0, atol=5e-7)
        np.testing.assert_allclose(stored[:, 1], 1 - uv[:, 1], rtol=0, atol=5e-7)

    loaded = trimesh.load(path).to_geometry()
    np.testing.assert_array_equal(loaded.faces, mesh.faces)
    np.testing.assert_allclose(loaded.visual.uv, atlas["base_uv"], rtol=0, atol=5e-7)


def test_textured_glb_material_through_trimesh(tmp_path, mesh, atlas):
    # trimesh decodes embedded images only with Pillow
    pytest.importorskip("PIL")
    path = tmp_path / "lightmap.glb"
    glb.write_textured(
        path, mesh.vertices, mesh.faces, None, atlas["atlas_uv"], atlas["occlusion_png"], {}
    )
    material = trimesh.load(path).to_geometry().visual.material
    assert material.occlusionTexture is not None
    assert material.occlusionTexture.size == (8, 4)


def test_textured_glb_rejects_bad_input(tmp_path, mesh, atlas):
    args = (tmp_path / "t.glb", mesh.vertices, mesh.faces, None)
    with pytest.raises(ValueError, match="occlusion_png is not a PNG"):
        glb.write_textured(*args, atlas["atlas_uv"], b"GIF89a", {})
    with pytest.raises(ValueError, match=r"atlas_uv must be \(n, 2\)"):
        glb.write_textured(*args, atlas["atlas_uv"][:-1], atlas["occlusion_png"], {})
    with pytest.raises(ValueError, match="needs base_uv"):
        glb.write_textured(
            *args, atlas["atlas_uv"], atlas["occlusion_png"], {},
            base_color_png=atlas["base_color_png"],
        )  # fmt: skip
    with pytest.raises(ValueError, match="base_color_factor"):
        glb.write_textured(
            *args, atlas["atlas_uv"], atlas["occlusion_png"], {}, base_color_factor=[1, 1, 1]
        )
    two = [{"name": "a", "base_color_png": None, "base_color_factor": None}] * 2
    with pytest.raises(ValueError, match="either materials or"):
        glb.write_textured(*args, atlas["atlas_uv"], atlas["occlusion_png"], {}, materials=two,
                           face_material=np.zeros(len(mesh.faces)), base_color_factor=[1, 1, 1, 1])
    with pytest.raises(ValueError, match="face_material must be"):
        glb.write_textured(*args, atlas["atlas_uv"], atlas["occlusion_png"], {}, materials=two,
                           face_material=np.full(len(mesh.faces), 2))
    with pytest.raises(ValueError, match="must not be empty"):
        glb.write_textured(*args, atlas["atlas_uv"], atlas["occlusion_png"], {}, materials=[],
                           face_material=np.zeros(len(mesh.faces)))
    assert list(tmp_path.iterdir()) == []


def test_textured_glb_one_primitive_per_material(tmp_path, mesh, atlas):
    half = np.arange(len(mesh.faces)) % 2
    materials = [{"name": "plain", "base_color_png": None, "base_color_factor": [0.5, 0.5, 0.5, 1]},
                 {"name": "textured", "base_color_png": atlas["base_color_png"],
                  "base_color_factor": None},
                 {"name": "unused", "base_color_png": None, "base_color_factor": None}]
    path = tmp_path / "multi.glb"
    glb.write_textured(path, mesh.vertices, mesh.faces, None, atlas["atlas_uv"],
                       atlas["occlusion_png"], {}, base_uv=atlas["base_uv"], materials=materials,
                       face_material=half)
    gltf, binary = check_glb_layout(path)
    primitives = gltf["meshes"][0]["primitives"]
    assert [gltf["materials"][p["material"]]["name"] for p in primitives] == ["plain", "textured"]
    for k, prim in enumerate(primitives):
        indices = read_accessor(gltf, binary, prim["indices"]).reshape(-1, 3)
        np.testing.assert_array_equal(indices, mesh.faces[half == k])
        assert prim["attributes"] == primitives[0]["attributes"]  # shared vertex data
    assert len(trimesh.load(path).geometry) == 2


# --------------------------------------------------------- validation and atomicity


@pytest.mark.parametrize("suffix", sorted(suffixes("vertices")))
def test_wrong_shape_leaves_no_file(tmp_path, mesh, suffix):
    fields = make_fields(mesh)
    fields["ao"] = fields["ao"][:-1]
    with pytest.raises(ValueError, match=r"ao must be \(n,\) = \(42,\), got \(41,\)"):
        write_vertices(tmp_path / f"bake{suffix}", mesh.vertices, mesh.faces, fields, {})
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix", sorted(suffixes("vertices")))
def test_failure_half_way_keeps_old_file_and_no_temp(tmp_path, mesh, monkeypatch, suffix):
    path = tmp_path / f"bake{suffix}"
    path.write_bytes(b"previous")
    module = {".npz": npz, ".ply": ply, ".glb": glb}[suffix]

    class FailingFile:
        """Writes the first chunk, then fails like a full disk."""

        def __init__(self, name, mode):
            self.handle = open(name, mode)
            self.writes = 0

        def write(self, data):
            if self.writes:
                raise OSError(28, "No space left on device")
            self.writes += 1
            return self.handle.write(data)

        def __getattr__(self, name):
            return getattr(self.handle, name)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.handle.close()

    # the writers call the builtin open(); a module global shadows it
    monkeypatch.setattr(module, "open", FailingFile, raising=False)
    with pytest.raises(OSError, match="No space left"):
        module.write(path, mesh.vertices, mesh.faces, make_fields(mesh), METADATA)
    assert [p.name for p in tmp_path.iterdir()] == [path.name]
    assert path.read_bytes() == b"previous"


# The mesh fixture is a 42-vertex icosphere; each case is (fields given n, message).
@pytest.mark.parametrize("bad_fields, message", [
    (lambda n: {"normals": np.zeros((n, 4))}, r"normals must be \(n, 3\) = \(42, 3\), got \(42, 4\)"),
    (lambda n: {"bent_normal": np.zeros(n)}, r"bent_normal must be \(n, 3\)"),
    (lambda n: {"rays": np.ones(n)}, "rays must be integer, got float64"),
    (lambda n: {"rays": -np.ones(n, dtype=int)}, r"rays must be in \[0, 2\*\*31\)"),
    (lambda n: {"occlusion": np.ones(n)}, "unknown fields \\['occlusion'\\]"),
    (lambda n: {"normals": np.full((n, 3), np.nan)}, "normals must be finite"),
], ids=["normals-shape", "bent-normal-shape", "rays-float", "rays-negative", "unknown-field",
        "normals-nan"])
def test_bad_fields_are_rejected(tmp_path, mesh, bad_fields, message):
    with pytest.raises(ValueError, match=message):
        npz.write(tmp_path / "x.npz", mesh.vertices, mesh.faces, bad_fields(len(mesh.vertices)), {})
    assert list(tmp_path.iterdir()) == []


def test_validation_messages(tmp_path, mesh):
    out = tmp_path / "x.npz"
    with pytest.raises(ValueError, match=r"positions must be \(n, 3\)"):
        npz.write(out, mesh.vertices[:, :2], mesh.faces, {}, {})
    with pytest.raises(ValueError, match="faces index vertices 0..42, but there are 42"):
        npz.write(out, mesh.vertices, np.vstack([mesh.faces, [[0, 1, 42]]]), {}, {})
    with pytest.raises(ValueError, match="metadata must be a dict"):
        npz.write(out, mesh.vertices, mesh.faces, {}, ["not", "a", "dict"])
    assert list(tmp_path.iterdir()) == []


def test_unsupported_extension(tmp_path, mesh):
    with pytest.raises(OutputError, match=r"bake\.obj: unsupported output format '\.obj' for a vertex "
                       r"bake \(--target vertices\); use one of \.npz, \.ply, \.glb"):  # fmt: skip
        write_vertices(tmp_path / "bake.obj", mesh.vertices, mesh.faces, {}, {})
    with pytest.raises(OutputError, match="'\\(none\\)'"):
        write_vertices(tmp_path / "bake", mesh.vertices, mesh.faces, {}, {})
    assert list(tmp_path.iterdir()) == []


def test_extension_is_case_insensitive(tmp_path, mesh):
    path = tmp_path / "BAKE.PLY"
    write_vertices(path, mesh.vertices, mesh.faces, {"ao": np.ones(len(mesh.vertices))}, {})
    assert path.read_bytes().startswith(b"ply\n")


def test_missing_directory_is_output_error(tmp_path, mesh):
    with pytest.raises(OutputError, match="does not exist"):
        write_vertices(tmp_path / "nope" / "bake.glb", mesh.vertices, mesh.faces, {}, {})


# ----------------------------------------------------------------------------- report


def strict_json(text: str):
    def refuse(constant):
        raise ValueError(f"non-standard JSON constant {constant}")

    return json.loads(text, parse_constant=refuse)


def test_report_round_trip(tmp_path):
    report = {
        "zeta": 1,  # insertion order is kept, not sorted
        "alpha": np.float64(0.25),
        "count": np.int32(7),
        "flag": np.bool_(True),
        "limits": [math.inf, -math.inf, math.nan, np.float32(np.inf)],
        "grid": np.array([[1.5, np.nan], [2.0, 3.0]]),
        "path": Path("out") / "bake.glb",
        "by_id": {np.int64(3): "three", 4: "four"},
        "tuple": (1, "a", None),
    }
    path = tmp_path / "report.json"
    write_report(path, report)
    text = path.read_text(encoding="utf-8")
    assert text.startswith('{\n  "zeta": 1,\n  "alpha": 0.25,')
    loaded = strict_json(text)
    assert loaded == {
        "zeta": 1,
        "alpha": 0.25,
        "count": 7,
        "flag": True,
        "limits": ["inf", "-inf", "nan", "inf"],
        "grid": [[1.5, "nan"], [2.0, 3.0]],
        "path": str(Path("out") / "bake.glb"),
        "by_id": {"3": "three", "4": "four"},
        "tuple": [1, "a", None],
    }
    assert isinstance(loaded["flag"], bool) and isinstance(loaded["count"], int)
    assert [p.name for p in tmp_path.iterdir()] == ["report.json"]


def test_report_unsupported_value_leaves_no_file(tmp_path):
    with pytest.raises(TypeError, match=r"value\['config'\]\['sampler'\]: cannot write object"):
        write_report(tmp_path / "report.json", {"config": {"sampler": object()}})
    assert list(tmp_path.iterdir()) == []


def test_to_jsonable_scalars():
    assert to_jsonable(np.float32(0.5)) == 0.5
    assert type(to_jsonable(np.int64(2))) is int
    assert to_jsonable(float("nan")) == "nan"
    assert to_jsonable(np.array(-np.inf)) == "-inf"
    assert to_jsonable({True: 1, None: 2, 1.5: 3}) == {"true": 1, "null": 2, "1.5": 3}


def test_outputs_get_ordinary_file_permissions(tmp_path):
    import os

    from aobake.outputs.atomic import atomic_path

    umask = os.umask(0o022)
    try:
        target = tmp_path / "x.bin"
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"data")
        assert (target.stat().st_mode & 0o777) == 0o644
    finally:
        os.umask(umask)


def test_query_points_write_as_point_sets(tmp_path):
    """bake_points results (no faces) write to NPZ and PLY as point sets and read back;
    GLB, a mesh format, is refused with the reason; kept distances go to NPZ only (a PLY
    asked to hold them is refused, not written without them)."""
    import trimesh

    import aobake
    from aobake.outputs import read

    points = np.array([[0.0, 0.0, 0.6], [0.1, 0.0, 0.6], [0.0, 0.2, 0.6]])
    normals = np.tile([0.0, 0.0, 1.0], (3, 1))
    kept = aobake.bake_points(trimesh.creation.box(), points, normals, rays=8,
                              keep_distances=True)
    res = aobake.bake_points(trimesh.creation.box(), points, normals, rays=8)
    with pytest.raises(aobake.UsageError, match="--keep-distances needs an .npz"):
        aobake.write(kept, tmp_path / "kept.ply")
    assert not (tmp_path / "kept.ply").exists()
    for suffix, result in ((".npz", kept), (".ply", res)):
        aobake.write(result, tmp_path / f"p{suffix}")
        back = read(tmp_path / f"p{suffix}")
        np.testing.assert_allclose(back.value, res.ao, rtol=1e-6)
        np.testing.assert_allclose(back.positions, points)
    with pytest.raises(aobake.OutputError, match="no faces"):
        aobake.write(res, tmp_path / "p.glb")
    assert not (tmp_path / "p.glb").exists()


@pytest.mark.parametrize("arguments, name", [
    (dict(result="a string"), "result"),
    (dict(out=None), "out"),
    (dict(out=3), "out"),
    (dict(report=5), "report"),
    (dict(half="no"), "half"),
    (dict(r_only=1), "r_only"),
    (dict(bit_depth=7), "bit_depth"),
])
def test_write_names_a_bad_argument(tmp_path, arguments, name):
    import trimesh

    import aobake

    result = aobake.bake(trimesh.creation.box(), rays=4)
    call = dict(result=result, out=tmp_path / "ao.npz")
    call.update(arguments)
    with pytest.raises(aobake.InputError, match=f"write: {name} must be"):
        aobake.write(call.pop("result"), call.pop("out"), **call)
    assert not list(tmp_path.iterdir())
