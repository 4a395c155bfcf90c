"""glTF 2.0 files as stored, parsed once: the GLB container, a .gltf's JSON, the buffers both
point into (the GLB's BIN chunk, ``data:`` URIs, files beside the .gltf), buffer views,
images and accessors.

Every reader of a glTF in aobake goes through here: ``aobake.outputs.glb`` writes its
container with :func:`write_glb` and reads its files back with :func:`parse_glb` and
:func:`accessor_array`; an input loader reads a .gltf or .glb with :func:`read_gltf` (an
``InputError`` naming the file) and an embedded or external texture with
:func:`image_bytes`.

The GLB container (glTF 2.0, section 4.4): a 12-byte header (magic ``glTF``, version 2, the
file's length), then chunks of (length, type, data): the JSON first, then optionally the
BIN chunk, which is buffer 0 when that buffer has no ``uri``.  The JSON chunk is padded with
spaces and the BIN chunk with zeros to 4 bytes.

A malformation raises ``Unreadable`` (a ``ValueError``) with the reason and without the file
name; what is allocated is bounded by the bytes the file holds (an accessor's count is
checked against its buffer before anything is made).
"""

from __future__ import annotations

import base64
import binascii
import json
import struct
from pathlib import Path
from urllib.parse import unquote, unquote_to_bytes

import numpy as np

from aobake.outputs.table import Unreadable, parse_json

#: the GLB header's magic and version
MAGIC = b"glTF"
VERSION = 2
#: chunk types: "JSON" and "BIN\0" as little-endian uint32
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942

#: accessor componentType -> its dtype (little-endian)
COMPONENT_DTYPES = {
    5120: np.dtype("i1"),
    5121: np.dtype("u1"),
    5122: np.dtype("<i2"),
    5123: np.dtype("<u2"),
    5125: np.dtype("<u4"),
    5126: np.dtype("<f4"),
}
#: accessor type -> components per element (the matrix types are not read)
TYPE_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


# ---------------------------------------------------------------------------------------------
# the container


def parse_glb(data: bytes, *, strict: bool = False, exact: bool = True
              ) -> tuple[dict, bytes | None]:
    """The GLB container ``data``: (gltf, the JSON chunk parsed, an object; binary, the BIN
    chunk's bytes with their padding, or None without one).

    exact : the header's length must be the file's (else bytes after it are ignored, as an
    input loader may; a header claiming more than the file holds is refused either way).
    strict : bytes after the last chunk, too few for a chunk header, are refused (else
    ignored).
    """
    if len(data) < 12:
        raise Unreadable(f"truncated GLB: {len(data)} bytes, its header needs 12")
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != MAGIC:
        raise Unreadable(f"not a GLB file (magic {magic!r}, expected {MAGIC!r})")
    if version != VERSION:
        raise Unreadable(f"GLB version {version} is not supported (only {VERSION})")
    if length > len(data):
        raise Unreadable(f"truncated GLB: its header says {length} bytes, the file has "
                         f"{len(data)}")
    if exact and length != len(data):
        raise Unreadable(f"its header says {length} bytes, the file has {len(data)}")
    chunks, offset = [], 12
    while offset + 8 <= length:
        size, kind = struct.unpack_from("<II", data, offset)
        if offset + 8 + size > length:
            raise Unreadable(f"truncated GLB: the chunk at byte {offset} ({size} bytes) runs "
                             "past the end of the file")
        chunks.append((kind, data[offset + 8:offset + 8 + size]))
        offset += 8 + size
    if strict and offset < length:
        raise Unreadable(f"truncated chunk header at byte {offset}")
    if not chunks:
        raise Unreadable(f"GLB has no JSON chunk (length {length})")
    if chunks[0][0] != CHUNK_JSON:
        raise Unreadable(f"GLB's first chunk is not JSON (type 0x{chunks[0][0]:08x})")
    gltf = _document(parse_json(chunks[0][1], "its JSON chunk"))
    binary = chunks[1][1] if len(chunks) > 1 and chunks[1][0] == CHUNK_BIN else None
    return gltf, binary


def parse_gltf(data: bytes, *, glb: bool | None = None, strict: bool = False,
               exact: bool = True) -> tuple[dict, bytes | None]:
    """A .glb's or a .gltf's bytes: (gltf, the JSON object; binary, the GLB's BIN chunk or
    None).  glb : True / False, or None: by the magic.  strict, exact : ``parse_glb``'s."""
    if glb or glb is None and data[:4] == MAGIC:
        return parse_glb(data, strict=strict, exact=exact)
    return _document(parse_json(data, "glTF JSON")), None


def read_gltf(path) -> tuple[dict, bytes | None]:
    """(the glTF JSON, an object; the GLB's BIN chunk or None) of a .gltf or .glb file (a GLB
    by its magic or its suffix), as an input loader reads it: bytes after the GLB header's
    length are ignored.  Raises ``InputError('FILE: cannot read ...: reason')``."""
    from aobake.errors import InputError

    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    glb = data[:4] == MAGIC or path.suffix.lower() == ".glb"
    try:
        return parse_gltf(data, glb=glb, exact=False)
    except Unreadable as exc:
        raise InputError(f"{path}: cannot read as {'GLB' if glb else 'glTF'}: {exc}") from None


def _document(gltf) -> dict:
    if not isinstance(gltf, dict):
        raise Unreadable(f"glTF JSON must be an object, got {type(gltf).__name__}")
    return gltf


def write_glb(handle, gltf: dict, binary: bytes | bytearray | None = None, *,
              allow_nan: bool = False) -> None:
    """Write ``gltf`` (the JSON object, compact) and ``binary`` (the BIN chunk; None: none) as
    a GLB container to the binary file object ``handle``, each chunk padded to 4 bytes (JSON
    with spaces, BIN with zeros).  ``gltf["buffers"][0]["byteLength"]`` is the caller's."""
    text = json.dumps(gltf, allow_nan=allow_nan, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    pad = b"" if binary is None else b"\0" * (-len(binary) % 4)
    total = 12 + 8 + len(text) + (0 if binary is None else 8 + len(binary) + len(pad))
    handle.write(struct.pack("<4sII", MAGIC, VERSION, total))
    handle.write(struct.pack("<II", len(text), CHUNK_JSON))
    handle.write(text)
    if binary is not None:
        handle.write(struct.pack("<II", len(binary) + len(pad), CHUNK_BIN))
        handle.write(bytes(binary))
        handle.write(pad)


# ---------------------------------------------------------------------------------------------
# buffers, views and images


def buffer_bytes(gltf: dict, binary: bytes | None, index: int, base=None) -> bytes:
    """The bytes of buffer ``index``: the GLB's BIN chunk (``binary``) for buffer 0 without a
    ``uri``, a ``data:`` URI decoded, or the file ``uri`` names in directory ``base`` (None:
    such a buffer is refused).  OSError where that file cannot be read."""
    buffers = gltf.get("buffers")
    if buffers is None and index == 0:
        entry = {}  # views naming buffer 0 of a GLB that lists no buffers: its BIN chunk
    elif not isinstance(buffers, list) or not _whole(index) or not 0 <= index < len(buffers) \
            or not isinstance(buffers[index], dict):
        raise Unreadable(f"no buffer {index!r}")
    else:
        entry = buffers[index]
    if "uri" not in entry:
        if index != 0 or binary is None:
            raise Unreadable(f"buffer {index} has no uri, and the file no BIN chunk holding it")
        return binary
    return uri_bytes(entry["uri"], base, f"buffer {index}")


def uri_bytes(uri, base=None, what: str = "uri") -> bytes:
    """The bytes a glTF ``uri`` names: a ``data:`` URI decoded (base64 or percent-encoded),
    else the file at the (percent-decoded) relative path in directory ``base`` (None: refused
    with ``Unreadable``).  OSError where that file cannot be read."""
    if not isinstance(uri, str):
        raise Unreadable(f"{what} has a uri of {type(uri).__name__}, not a string")
    if uri.startswith("data:"):
        head, comma, payload = uri.partition(",")
        if not comma:
            raise Unreadable(f"{what}: a data URI without ','")
        try:
            if head.endswith(";base64"):
                return base64.b64decode(payload, validate=False)
            return unquote_to_bytes(payload)
        except (binascii.Error, ValueError) as exc:
            raise Unreadable(f"{what}: a malformed data URI ({exc})") from None
    if base is None:
        raise Unreadable(f"{what} is the file {uri!r} (only what the file itself holds is "
                         "read here)")
    return (Path(base) / unquote(uri)).read_bytes()


def view_bytes(gltf: dict, binary: bytes | None, index: int, base=None) -> bytes:
    """The bytes of bufferView ``index`` (e.g. an embedded image), from its buffer
    (:func:`buffer_bytes`); Unreadable for a view past its buffer's end."""
    views = gltf.get("bufferViews")
    if not isinstance(views, list) or not _whole(index) or not 0 <= index < len(views) \
            or not isinstance(views[index], dict):
        raise Unreadable(f"no bufferView {index!r}")
    view = views[index]
    buffer = buffer_bytes(gltf, binary, view.get("buffer", 0), base)
    start, length = view.get("byteOffset", 0), view.get("byteLength")
    if not _whole(start) or start < 0 or not _whole(length) or length < 0:
        raise Unreadable(f"bufferView {index} has byteOffset {start!r}, byteLength {length!r}")
    end = start + length
    if end > len(buffer):
        raise Unreadable(f"bufferView {index} ends at byte {end}, past the buffer "
                         f"({len(buffer)})")
    return buffer[start:end]


def image_bytes(gltf: dict, binary: bytes | None, index: int, base=None) -> bytes:
    """The bytes of ``images[index]`` (PNG, JPEG ... as stored): its ``uri``
    (:func:`uri_bytes`) or its bufferView (:func:`view_bytes`)."""
    images = gltf.get("images")
    if not isinstance(images, list) or not _whole(index) or not 0 <= index < len(images) \
            or not isinstance(images[index], dict):
        raise Unreadable(f"no image {index!r}")
    image = images[index]
    if "uri" in image:
        return uri_bytes(image["uri"], base, f"image {index}")
    if "bufferView" not in image:
        raise Unreadable(f"image {index} has neither a uri nor a bufferView")
    return view_bytes(gltf, binary, image["bufferView"], base)


# ---------------------------------------------------------------------------------------------
# accessors


def accessor_array(gltf: dict, binary: bytes | None, index: int, *, base=None,
                   strict: bool = False, max_bytes: int | None = None) -> np.ndarray:
    """Accessor ``index`` as stored: (count,) for SCALAR, else (count, k), in its component
    dtype (normalised integers not rescaled), interleaved or not; a copy.  Not sparse ones.

    An accessor without a bufferView is all zeros (the spec); it may take at most
    ``max_bytes`` (default: the BIN chunk's size), an accessor with one is bounded by the
    bytes of its buffer.  strict: the accessor must lie within its bufferView, itself within
    its buffer; else only within the buffer.  base : ``buffer_bytes``'s.
    """
    accessors = gltf.get("accessors")
    if not isinstance(accessors, list) or not _whole(index) or not 0 <= index < len(accessors) \
            or not isinstance(accessors[index], dict):
        raise Unreadable(f"no accessor {index}")
    accessor = accessors[index]
    if "sparse" in accessor:
        raise Unreadable(f"accessor {index} is sparse (not supported)")
    width = TYPE_WIDTHS.get(accessor.get("type")) if isinstance(accessor.get("type"), str) \
        else None
    if width is None:
        raise Unreadable(f"accessor {index} has type {accessor.get('type')} (not supported)")
    component = accessor.get("componentType")
    if not _whole(component) or component not in COMPONENT_DTYPES:
        raise Unreadable(f"accessor {index} has componentType {component} (not a glTF one)")
    dtype = COMPONENT_DTYPES[component]
    count = accessor.get("count")
    if not _whole(count) or count < 0:
        raise Unreadable(f"accessor {index} has count {count!r}")
    size = dtype.itemsize * width  # bytes of one element
    if "bufferView" not in accessor:
        limit = len(binary or b"") if max_bytes is None else max_bytes
        if count * size > limit:
            raise Unreadable(f"accessor {index} claims {count} zero elements ({count * size} "
                             f"bytes), more than the file holds ({limit})")
        values = np.zeros((count, width), dtype=dtype)
        return values[:, 0] if width == 1 else values
    views = gltf.get("bufferViews")
    at = accessor["bufferView"]
    if not isinstance(views, list) or not _whole(at) or not 0 <= at < len(views) \
            or not isinstance(views[at], dict):
        raise Unreadable(f"accessor {index} names bufferView {at!r}, which does not exist")
    view = views[at]
    start = accessor.get("byteOffset", 0)
    stride = view.get("byteStride", size)
    for label, number in (("byteOffset", start), ("bufferView byteOffset",
                                                  view.get("byteOffset", 0))):
        if not _whole(number) or number < 0:
            raise Unreadable(f"accessor {index} has {label} {number!r}")
    if not _whole(stride) or stride < size:
        raise Unreadable(f"accessor {index}: byteStride {stride!r} is less than its "
                         f"{size}-byte elements")
    if max_bytes is not None and count * size > max_bytes:
        raise Unreadable(f"accessor {index} claims {count * size} bytes, more than the file "
                         f"holds ({max_bytes})")
    if strict:
        buffer, within = view_bytes(gltf, binary, at, base), "bufferView"
    else:
        buffer, within = buffer_bytes(gltf, binary, view.get("buffer", 0), base), "buffer"
        start += view.get("byteOffset", 0)
    if count and start + stride * (count - 1) + size > len(buffer):
        raise Unreadable(f"accessor {index} runs past the end of the {within}")
    values = np.ndarray((count, width), dtype=dtype, buffer=buffer, offset=start,
                        strides=(stride, dtype.itemsize)).copy()
    return values[:, 0] if width == 1 else values


def _whole(value) -> bool:
    """A JSON integer (not a bool, which Python counts as one)."""
    return isinstance(value, int) and not isinstance(value, bool)
