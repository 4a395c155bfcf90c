"""The one glTF container module (``aobake.outputs.gltf``, issue 31): the GLB writer and every
reader of a glTF in aobake go through it, so a GLB and a .gltf whose buffers are ``data:``
URIs or files beside it read alike: buffers, views, images, accessors (compared exactly:
nothing is converted on the way).
"""

from __future__ import annotations

import base64
import io
import json

import numpy as np
import pytest

from aobake.errors import InputError
from aobake.outputs import gltf
from aobake.outputs.table import Unreadable

def document(buffer: dict) -> dict:
    """A triangle with POSITION (float32), an index accessor (uint16) and one image, all in
    buffer 0 (``buffer``: its entry, without byteLength)."""
    return {"asset": {"version": "2.0"}, "buffers": [buffer],
            "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36},
                            {"buffer": 0, "byteOffset": 36, "byteLength": 6},
                            {"buffer": 0, "byteOffset": 44, "byteLength": 4}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3,
                           "type": "VEC3"},
                          {"bufferView": 1, "componentType": 5123, "count": 3,
                           "type": "SCALAR"}],
            "images": [{"bufferView": 2, "mimeType": "image/png"}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}]}


POSITIONS = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
INDICES = np.array([0, 1, 2], np.uint16)
BLOB = POSITIONS.tobytes() + INDICES.tobytes() + b"\0\0" + b"IMG!"


def glb_bytes(gltf_json: dict, binary: bytes | None) -> bytes:
    out = io.BytesIO()
    gltf.write_glb(out, gltf_json, binary)
    return out.getvalue()


def test_write_glb_and_parse_glb_round_trip():
    data = glb_bytes(document({}), BLOB)
    assert data[:4] == gltf.MAGIC and len(data) % 4 == 0
    parsed, binary = gltf.parse_glb(data, strict=True)
    assert parsed == document({}) and binary == BLOB  # 48 bytes: no padding
    assert gltf.parse_glb(glb_bytes({"asset": {}}, None)) == ({"asset": {}}, None)
    # bytes after the header's length: refused by default, ignored as a loader reads
    with pytest.raises(Unreadable, match="its header says"):
        gltf.parse_glb(data + b"junk")
    assert gltf.parse_glb(data + b"junk", exact=False)[1] == BLOB
    for cut, words in ((data[:8], "truncated GLB"), (data[:-4], "truncated GLB"),
                       (b"glTX" + data[4:], "not a GLB file"),
                       (data[:12] + data[12:16] + b"BIN\0" + data[20:], "not JSON")):
        with pytest.raises(Unreadable, match=words):
            gltf.parse_glb(cut)


@pytest.mark.parametrize("where", ["glb", "data uri", "external file"])
def test_buffers_views_images_and_accessors_wherever_the_buffer_is(tmp_path, where):
    if where == "glb":
        path = tmp_path / "t.glb"
        path.write_bytes(glb_bytes(document({"byteLength": len(BLOB)}), BLOB))
    else:
        uri = ("data:application/octet-stream;base64," + base64.b64encode(BLOB).decode()
               if where == "data uri" else "the%20buffer.bin")
        (tmp_path / "the buffer.bin").write_bytes(BLOB)
        path = tmp_path / "t.gltf"
        path.write_text(json.dumps(document({"uri": uri, "byteLength": len(BLOB)})))
    parsed, binary = gltf.read_gltf(path)
    assert (binary is None) == (where != "glb")
    base = path.parent
    for strict in (False, True):
        np.testing.assert_array_equal(
            gltf.accessor_array(parsed, binary, 0, base=base, strict=strict), POSITIONS)
        np.testing.assert_array_equal(
            gltf.accessor_array(parsed, binary, 1, base=base, strict=strict), INDICES)
    assert gltf.image_bytes(parsed, binary, 0, base) == b"IMG!"
    assert gltf.view_bytes(parsed, binary, 1, base) == INDICES.tobytes()
    if where == "external file":  # without a directory, only what the file holds is read
        with pytest.raises(Unreadable, match="only what the file itself holds"):
            gltf.accessor_array(parsed, binary, 0)


def test_an_accessor_is_bounded_by_its_buffer():
    gltf_json = document({})
    gltf_json["accessors"][0]["count"] = 10 ** 12
    with pytest.raises(Unreadable, match="runs past the end of the buffer"):
        gltf.accessor_array(gltf_json, BLOB, 0)
    del gltf_json["accessors"][0]["bufferView"]  # all zeros: bounded by the file's size
    with pytest.raises(Unreadable, match="more than the file holds"):
        gltf.accessor_array(gltf_json, BLOB, 0)


def test_read_gltf_names_the_file(tmp_path):
    for name, data, words in (("cut.glb", b"glTF\x02\0\0\0", "truncated GLB"),
                              ("list.gltf", b"[1, 2]", "glTF JSON must be an object"),
                              ("text.gltf", b"{nope", "not valid JSON")):
        path = tmp_path / name
        path.write_bytes(data)
        with pytest.raises(InputError, match=words) as error:
            gltf.read_gltf(path)
        assert str(path) in str(error.value)
    with pytest.raises(InputError, match="cannot read"):
        gltf.read_gltf(tmp_path / "missing.gltf")
