"""Readers of aobake's own output files, for the tests (the package only writes them).

``read_glb`` / ``read_view`` / ``read_accessor``: the GLB container and its accessors;
``read_ply``: the binary PLY layout ``aobake.outputs.ply`` writes; ``read_image``:
EXR/PNG/TIFF through OpenImageIO with unassociated alpha.
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path
from typing import Any

import numpy as np

from aobake.errors import InputError, OutputError
from aobake.outputs.glb import _CHUNK_BIN, _CHUNK_JSON, _COMPONENT_DTYPES, _MAGIC, _VERSION
from aobake.outputs.ply import METADATA_COMMENT

_TYPE_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_NUMPY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "<i2", "int16": "<i2", "ushort": "<u2", "uint16": "<u2",
    "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
    "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8",
}  # fmt: skip


def read_glb(path: str | os.PathLike) -> tuple[dict, bytes]:
    """Read a GLB file.

    Returns
    -------
    gltf : the JSON chunk, parsed
    bin : bytes of the BIN chunk (including its padding), b"" if there is none

    Raises ``InputError`` if the container is malformed.
    """
    data = Path(path).read_bytes()
    if len(data) < 20:
        raise InputError(f"{path}: too short to be a GLB file")
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != _MAGIC or version != _VERSION:
        raise InputError(f"{path}: not a glTF 2.0 binary file")
    if length != len(data):
        raise InputError(f"{path}: header says {length} bytes, file has {len(data)}")
    chunks = []
    offset = 12
    while offset < length:
        if offset + 8 > length:
            raise InputError(f"{path}: truncated chunk header at byte {offset}")
        size, kind = struct.unpack_from("<II", data, offset)
        if offset + 8 + size > length:
            raise InputError(f"{path}: chunk at byte {offset} runs past the end of the file")
        chunks.append((kind, data[offset + 8 : offset + 8 + size]))
        offset += 8 + size
    if not chunks or chunks[0][0] != _CHUNK_JSON:
        raise InputError(f"{path}: the first chunk is not JSON")
    gltf = json.loads(chunks[0][1].decode("utf-8"))
    binary = chunks[1][1] if len(chunks) > 1 and chunks[1][0] == _CHUNK_BIN else b""
    return gltf, binary


def read_view(gltf: dict, binary: bytes, index: int) -> bytes:
    """Bytes of bufferView ``index`` (e.g. an embedded image) of a GLB's BIN chunk."""
    view = gltf["bufferViews"][index]
    if view.get("buffer", 0) != 0:
        raise ValueError("only the GLB's own buffer (0) can be read")
    start = view.get("byteOffset", 0)
    end = start + view["byteLength"]
    if end > len(binary):
        raise ValueError(f"bufferView {index} ends at byte {end}, past the buffer ({len(binary)})")
    return binary[start:end]


def read_accessor(gltf: dict, binary: bytes, index: int) -> np.ndarray:
    """Values of accessor ``index``, as stored (normalised integers are not rescaled).

    Supports SCALAR and VEC2..VEC4 accessors, interleaved or not; not sparse ones.

    Returns
    -------
    values : (count,) for SCALAR, else (count, k), with the accessor's component
      dtype (float32, uint32 ...); a copy, safe to modify
    """
    accessor = gltf["accessors"][index]
    if "sparse" in accessor:
        raise ValueError(f"accessor {index}: sparse accessors are not supported")
    if accessor["type"] not in _TYPE_WIDTHS:
        raise ValueError(f"accessor {index}: type {accessor['type']} is not supported")
    dtype = _COMPONENT_DTYPES[accessor["componentType"]]
    width = _TYPE_WIDTHS[accessor["type"]]
    count = accessor["count"]
    shape = (count,) if width == 1 else (count, width)
    if "bufferView" not in accessor:
        # the spec: an accessor without a bufferView is all zeros
        return np.zeros(shape, dtype=dtype)
    view_index = accessor["bufferView"]
    view = read_view(gltf, binary, view_index)
    start = accessor.get("byteOffset", 0)
    element = dtype.itemsize * width
    stride = gltf["bufferViews"][view_index].get("byteStride", element)
    if count and start + stride * (count - 1) + element > len(view):
        raise ValueError(f"accessor {index} runs past the end of bufferView {view_index}")
    values = np.ndarray(
        (count, width), dtype=dtype, buffer=view, offset=start, strides=(stride, dtype.itemsize)
    )
    return values.reshape(shape).copy()


def read_ply(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, dict]:
    """Read a PLY file as ``write`` lays it out (binary little-endian, triangles).

    Not a general PLY reader: it accepts scalar vertex properties of any type
    and a face element whose only property is a ``list uchar int|uint`` of 3.

    Returns
    -------
    vertex : (n,) structured array, one field per vertex property, in file order
    faces : (f, 3) int64
    metadata : dict from the ``comment aobake-metadata`` line, {} if none
    """
    data = Path(path).read_bytes()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise ValueError(f"{path}: not a PLY file with a header")
    lines = data[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise ValueError(f"{path}: only binary_little_endian PLY is supported")
    metadata: dict = {}
    elements: dict[str, list] = {}
    counts: dict[str, int] = {}
    current = None
    for line in lines:
        words = line.split()
        if words[:2] == ["comment", METADATA_COMMENT]:
            metadata = json.loads(line.split(None, 2)[2])
        elif words[:1] == ["element"]:
            current = words[1]
            counts[current] = int(words[2])
            elements[current] = []
        elif words[:1] == ["property"]:
            elements[current].append(words[1:])
    vertex_dtype = [(p[1], _NUMPY_TYPES[p[0]]) for p in elements.get("vertex", [])]
    face_props = elements.get("face", [])
    if len(face_props) != 1 or face_props[0][:2] != ["list", "uchar"]:
        raise ValueError(f"{path}: expected one face property 'list uchar int vertex_indices'")
    face_dtype = [("count", "u1"), ("vertex_indices", _NUMPY_TYPES[face_props[0][2]], (3,))]

    offset = end + len(b"end_header\n")
    vertex = np.frombuffer(data, dtype=vertex_dtype, count=counts["vertex"], offset=offset)
    offset += vertex.nbytes
    face = np.frombuffer(data, dtype=face_dtype, count=counts["face"], offset=offset)
    if (face["count"] != 3).any():
        raise ValueError(f"{path}: only triangle faces are supported")
    return vertex.copy(), face["vertex_indices"].astype(np.int64), metadata


def read_image(path) -> tuple[np.ndarray, list[str], dict[str, Any]]:
    """Read an image back (mainly for tests and inspection).

    Returns (pixels (H, W, C) float32, channel_names, attributes).  Float files
    come back as stored; integer files in OIIO's normalised scale, x / (2**bits
    - 1), so ``np.rint(pixels * (2**bits - 1))`` recovers the stored integers
    exactly ('oiio:BitsPerSample' or the format says how many bits).  Alpha is
    read unassociated (colour is not multiplied by alpha).  attributes includes
    'oiio:format' (e.g. 'uint8', 'half') and, for EXR, channel names in the
    reader's order.
    """
    import OpenImageIO as oiio

    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(str(path), config)
    if inp is None:
        raise OutputError(f"{path}: {oiio.geterror() or 'cannot open for reading'}")
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        if pixels is None:
            raise OutputError(f"{path}: {inp.geterror() or 'cannot read pixels'}")
        attrs = {p.name: p.value for p in spec.extra_attribs}
        attrs["oiio:format"] = str(spec.format)
        # per-channel formats of a mixed file (--half keeps counts float32); [] when uniform
        attrs["oiio:channelformats"] = [str(f) for f in spec.channelformats]
        names = list(spec.channelnames)
    finally:
        inp.close()
    pixels = np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
    return pixels, names, attrs
