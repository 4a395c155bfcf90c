"""What PLY, GLB and image files hold, as stored: the byte-level parsing, done once.

``readers`` turns these into compare's table; ``tests/readers.py`` reads aobake's own
outputs back with the same functions (``strict=True`` where the tests refuse what aobake
never writes but compare tolerates in another tool's file).  Every malformation raises
``Unreadable`` (a ``ValueError``) with the reason, without the file name.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field

import numpy as np

PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_GLTF_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


class Unreadable(ValueError):
    """A reader's reason a file is malformed (compare: ``InputError('FILE: cannot read ...')``)."""


# ---------------------------------------------------------------------------------------------
# PLY


@dataclass
class Ply:
    """A PLY file as stored.

    format : 'ascii' | 'binary_little_endian' | 'binary_big_endian'
    elements : the header's (name, count, props) in file order; a prop is (name, dtype) for a
      scalar, (name, count dtype, item dtype) for a list (dtypes as in ``PLY_TYPES``)
    vertex : (n,) structured array, one field per vertex property in file order (binary: in
      the file's byte order)
    faces : (f, 3) int64 of the face element's first list, or None (no face element, not all
      triangles, or truncated after the vertices)
    metadata : the ``comment aobake-metadata`` line's JSON as parsed (not checked to be a
      dict), {} without one
    """

    format: str
    elements: list
    vertex: np.ndarray
    faces: np.ndarray | None = None
    metadata: object = field(default_factory=dict)


def parse_ply(data: bytes) -> Ply:
    """PLY in any of its three formats: the header, every vertex property, the triangles."""
    from aobake.outputs.ply import METADATA_COMMENT

    if not data.startswith(b"ply"):
        raise Unreadable("not a PLY file (no 'ply' line)")
    end = data.find(b"end_header")
    if end < 0:
        raise Unreadable("no end_header")
    body = data.index(b"\n", end) + 1
    fmt, metadata, elements = None, {}, []
    for line in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        words = line.split()
        if not words:
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "comment" and words[1:2] == [METADATA_COMMENT]:
            metadata = json.loads(line.split(None, 2)[2])
        elif words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if not elements:
                raise Unreadable("a property before any element")
            if words[1] == "list":
                elements[-1][2].append((words[4], _ply_type(words[2]), _ply_type(words[3])))
            else:
                elements[-1][2].append((words[2], _ply_type(words[1])))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise Unreadable(f"unknown format {fmt!r}")
    parsed = _ply_ascii(data[body:], elements) if fmt == "ascii" else \
        _ply_binary(data, body, elements, "<" if fmt == "binary_little_endian" else ">")
    if "vertex" not in parsed:
        raise Unreadable("no vertex element")
    return Ply(fmt, elements, parsed["vertex"], parsed.get("face"), metadata)


def _ply_type(name: str) -> str:
    if name not in PLY_TYPES:
        raise Unreadable(f"unknown property type {name!r}")
    return PLY_TYPES[name]


def _ply_binary(data: bytes, offset: int, elements, order: str) -> dict:
    """{'vertex': structured (n,), 'face': (f, 3) int64} as far as they can be read (a face
    list that is not all triangles ends the reading: later elements cannot be located)."""
    out = {}
    for name, count, props in elements:
        dtype = []
        for prop in props:
            if len(prop) == 2:
                dtype.append((prop[0], order + prop[1]))
            else:  # a list, read as if of 3, then checked
                dtype += [(prop[0] + "#count", order + prop[1]), (prop[0], order + prop[2], (3,))]
        dtype = np.dtype(dtype)
        if offset + dtype.itemsize * count > len(data):
            if name == "vertex" or "vertex" not in out:
                raise Unreadable(f"truncated: element {name!r} runs past the end of the file")
            break
        array = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
        lists = [p[0] for p in props if len(p) == 3]
        if any((array[p + "#count"] != 3).any() for p in lists):
            break  # not all triangles: stop (the vertices were read first, or are not here)
        offset += array.nbytes
        if name == "vertex":
            out["vertex"] = array
        elif name == "face" and lists:
            out["face"] = array[lists[0]].astype(np.int64)
        if "vertex" in out and "face" in out:
            break
    return out


def _ply_ascii(body: bytes, elements) -> dict:
    """The ASCII layout, read as one stream of tokens (line breaks do not matter)."""
    tokens = body.decode("ascii").split()
    out, at = {}, 0
    for name, count, props in elements:
        lists = [i for i, p in enumerate(props) if len(p) == 3]
        width = len(props) + 3 * len(lists)  # every list assumed to hold 3 (checked)
        chunk = tokens[at:at + width * count]
        if len(chunk) < width * count:
            if name == "vertex" or "vertex" not in out:
                raise Unreadable(f"truncated: element {name!r} runs past the end of the file")
            break
        table = np.array(chunk, dtype=np.float64).reshape(count, width)
        columns, col = {}, 0
        for prop in props:
            if len(prop) == 2:
                columns[prop[0]] = table[:, col].astype(prop[1])
                col += 1
            else:
                if (table[:, col] != 3).any():
                    return out  # not all triangles
                columns[prop[0]] = table[:, col + 1:col + 4].astype(np.int64)
                col += 4
        at += width * count
        if name == "vertex":
            vertex = np.empty(count, dtype=[(p[0], p[1]) for p in props if len(p) == 2])
            for key in vertex.dtype.names:
                vertex[key] = columns[key]
            out["vertex"] = vertex
        elif name == "face" and lists:
            out["face"] = columns[props[lists[0]][0]]
        if "vertex" in out and "face" in out:
            break
    return out


# ---------------------------------------------------------------------------------------------
# GLB


def parse_glb(data: bytes, *, strict: bool = False) -> tuple[dict, bytes]:
    """The GLB container: (gltf, the JSON chunk parsed; binary, the BIN chunk's bytes with their
    padding, b"" without one).  strict: bytes after the last chunk, too few for a chunk
    header, are refused (else ignored)."""
    from aobake.outputs.glb import _CHUNK_BIN, _CHUNK_JSON, _MAGIC, _VERSION

    if len(data) < 20:
        raise Unreadable("too short to be a GLB file")
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != _MAGIC or version != _VERSION:
        raise Unreadable("not a glTF 2.0 binary file")
    if length != len(data):
        raise Unreadable(f"header says {length} bytes, the file has {len(data)}")
    chunks, offset = [], 12
    while offset + 8 <= length:
        size, kind = struct.unpack_from("<II", data, offset)
        if offset + 8 + size > length:
            raise Unreadable(f"chunk at byte {offset} runs past the end of the file")
        chunks.append((kind, data[offset + 8:offset + 8 + size]))
        offset += 8 + size
    if strict and offset < length:
        raise Unreadable(f"truncated chunk header at byte {offset}")
    if not chunks or chunks[0][0] != _CHUNK_JSON:
        raise Unreadable("the first chunk is not JSON")
    gltf = json.loads(chunks[0][1].decode("utf-8"))
    binary = chunks[1][1] if len(chunks) > 1 and chunks[1][0] == _CHUNK_BIN else b""
    return gltf, binary


def glb_view(gltf: dict, binary: bytes, index: int) -> bytes:
    """Bytes of bufferView ``index`` (e.g. an embedded image) of the GLB's own buffer (0)."""
    view = gltf["bufferViews"][index]
    if view.get("buffer", 0) != 0:
        raise Unreadable("only the GLB's own buffer (0) can be read")
    start = view.get("byteOffset", 0)
    end = start + view["byteLength"]
    if end > len(binary):
        raise Unreadable(f"bufferView {index} ends at byte {end}, past the buffer ({len(binary)})")
    return binary[start:end]


def glb_accessor(gltf: dict, binary: bytes, index: int, *, strict: bool = False) -> np.ndarray:
    """Accessor ``index`` as stored: (count,) for SCALAR, else (count, k), in its component
    dtype (normalised integers not rescaled), interleaved or not; a copy.  Not sparse ones.

    An accessor without a bufferView is all zeros (the spec).  strict: the accessor must lie
    within its bufferView, itself within the GLB's own buffer (``glb_view``); else only
    within the BIN chunk.
    """
    from aobake.outputs.glb import _COMPONENT_DTYPES

    accessor = gltf["accessors"][index]
    if "sparse" in accessor:
        raise Unreadable(f"accessor {index} is sparse (not supported)")
    width = _GLTF_WIDTHS.get(accessor["type"])
    if width is None:
        raise Unreadable(f"accessor {index} has type {accessor['type']} (not supported)")
    dtype = _COMPONENT_DTYPES[accessor["componentType"]]
    count = accessor["count"]
    if "bufferView" not in accessor:
        values = np.zeros((count, width), dtype=dtype)
    else:
        view = gltf["bufferViews"][accessor["bufferView"]]
        start = accessor.get("byteOffset", 0)
        stride = view.get("byteStride", dtype.itemsize * width)
        if strict:
            buffer, within = glb_view(gltf, binary, accessor["bufferView"]), "bufferView"
        else:
            buffer, within = binary, "buffer"
            start += view.get("byteOffset", 0)
        if count and start + stride * (count - 1) + dtype.itemsize * width > len(buffer):
            raise Unreadable(f"accessor {index} runs past the end of the {within}")
        values = np.ndarray((count, width), dtype=dtype, buffer=buffer, offset=start,
                            strides=(stride, dtype.itemsize)).copy()
    return values[:, 0] if width == 1 else values


# ---------------------------------------------------------------------------------------------
# images


def read_pixels(path) -> tuple[np.ndarray, list[str], dict]:
    """The first subimage through OpenImageIO, alpha unassociated (colour is not multiplied by
    alpha; in aobake's files alpha is coverage, not opacity).

    Returns (pixels (H, W, C) float32, channel names, attributes).  Float files come back as
    stored; integer files in OIIO's normalised scale, x / (2**bits - 1).  The attributes are
    the file's, plus 'oiio:format' (e.g. 'uint8', 'half') and 'oiio:channelformats' (the
    per-channel formats of a mixed file; [] when uniform).
    """
    import OpenImageIO as oiio

    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(str(path), config)
    if inp is None:
        raise Unreadable(oiio.geterror() or "OpenImageIO cannot open it")
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        if pixels is None:
            raise Unreadable(inp.geterror() or "cannot read its pixels")
        attrs = {p.name: p.value for p in spec.extra_attribs}
        attrs["oiio:format"] = str(spec.format)
        attrs["oiio:channelformats"] = [str(f) for f in spec.channelformats]
        names = list(spec.channelnames)
    finally:
        inp.close()
    pixels = np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
    return pixels, names, attrs
