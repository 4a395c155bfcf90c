"""Per-vertex results as a binary little-endian PLY mesh.

Layout (properties appear only for the fields that were computed, in this order)::

    ply
    format binary_little_endian 1.0
    comment aobake-metadata {"...":...}
    element vertex n
    property double x            (and y, z: positions survive exactly)
    property float nx            (and ny, nz)          if normals
    property float ao                                  if ao
    property float ao_stderr                           if ao_stderr
    property float obscurance                          if obscurance
    property float obscurance_stderr                   if obscurance_stderr
    property float bent_normal_x (and _y, _z)          if bent_normal
    property float bent_normal_stderr                  if bent_normal (radians)
    property int rays                                  if rays
    property int missed                                high-to-low (--from): 1 = cage ray missed
    property int back_hit                              high-to-low: 1 = hit a back face
    property float projection_distance                 high-to-low: height above the low mesh, 0 if missed
    property uchar red           (and green, blue)     always
    element face f
    property list uchar int vertex_indices
    end_header

Vertex colour: ``red = green = blue = round(clip(value, 0, 1) * 255)`` where
``value`` is the stored (float32) AO, or the obscurance when AO is absent; NaN
maps to 0.  The grey level is the *linear* value, with no sRGB transfer curve,
so a viewer that treats vertex colours as sRGB shows the mid-tones darker than
a linear display would.  With neither AO nor obscurance the colour is white
(255).  Rounding is half-to-even (``numpy.rint``).

Metadata is one header line, ``comment aobake-metadata <json>``, whose JSON has
no whitespace (spaces inside strings are written ``\\u0020``) so that PLY
readers which split header lines on whitespace see it as one token.

The reader beside the writer: ``read`` (any PLY's vertex properties as a ``Table``, aobake's
or another tool's), on ``parse_ply``, which reads all three PLY formats.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aobake.outputs.atomic import atomic_path
from aobake.outputs.npz import check_vertex_data
from aobake.outputs.strictjson import metadata_json
from aobake.outputs.table import Table, Unreadable, parse_json
from aobake.quantities import FIELDS

log = logging.getLogger(__name__)

METADATA_COMMENT = "aobake-metadata"

# field name -> PLY property names (from the registry); float32 ("float") except integers
_PROPERTIES = {f.name: f.ply for f in FIELDS.values()}
#: stored dtype -> the PLY type written for it
_WRITTEN_TYPES = {"<f8": "double", "<f4": "float", "<i4": "int", "|u1": "uchar"}


def vertex_colors(fields: Mapping[str, np.ndarray], n: int) -> np.ndarray:
    """Grey vertex colours from AO (else obscurance), linear, no sRGB transfer.

    Returns
    -------
    grey : (n,) uint8, ``round(clip(value, 0, 1) * 255)`` of the float32 value
      (what the file stores), 0 where it is NaN, 255 when neither field exists
    """
    source = fields.get("ao", fields.get("obscurance"))
    if source is None:
        return np.full(n, 255, dtype=np.uint8)
    value = np.asarray(source).astype(np.float32).astype(np.float64)
    # NaN (no estimate) would cast to an arbitrary byte; show it black
    value = np.nan_to_num(np.clip(value, 0.0, 1.0), nan=0.0)
    return np.rint(value * 255.0).astype(np.uint8)


def write(
    path: str | os.PathLike,
    positions: np.ndarray,
    faces: np.ndarray,
    fields: Mapping[str, np.ndarray],
    metadata: Mapping | None,
) -> None:
    """Write a vertex bake to ``path`` as binary little-endian PLY, atomically.

    Parameters
    ----------
    path : output file
    positions : (n, 3) float, stored as double
    faces : (f, 3) int, stored as ``list uchar int``
    fields : dict of per-vertex arrays (``aobake.outputs.npz.VERTEX_FIELDS``), stored
      as float32 except ``rays`` (int32); see the module docstring for names
    metadata : JSON-serialisable dict, stored in one ``comment aobake-metadata`` line
    """
    positions, faces, fields = check_vertex_data(positions, faces, fields)
    if len(faces) and faces.max() > np.iinfo(np.int32).max:
        raise ValueError("PLY stores vertex indices as int32; too many vertices")
    n = len(positions)

    columns: list[tuple[str, str, np.ndarray]] = [
        (axis, "<f8", positions[:, i]) for i, axis in enumerate("xyz")
    ]
    for name, value in fields.items():
        dtype = "<i4" if np.issubdtype(FIELDS[name].dtype, np.integer) else "<f4"
        value = value.reshape(n, -1)
        columns += [(prop, dtype, value[:, i]) for i, prop in enumerate(_PROPERTIES[name])]
    grey = vertex_colors(fields, n)
    columns += [(channel, "|u1", grey) for channel in ("red", "green", "blue")]

    vertex = np.empty(n, dtype=[(prop, dtype) for prop, dtype, _ in columns])
    for prop, _, value in columns:
        vertex[prop] = value
    face = np.empty(len(faces), dtype=[("count", "|u1"), ("vertex_indices", "<i4", (3,))])
    face["count"] = 3
    face["vertex_indices"] = faces

    header = [
        "ply",
        "format binary_little_endian 1.0",
        f"comment {METADATA_COMMENT} {metadata_json(metadata, compact=True)}",
        f"element vertex {n}",
        *(f"property {_WRITTEN_TYPES[dtype]} {prop}" for prop, dtype, _ in columns),
        f"element face {len(faces)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:
            handle.write(("\n".join(header) + "\n").encode("ascii"))
            handle.write(vertex.tobytes())
            handle.write(face.tobytes())
    log.debug("wrote %s: %d vertices, %d faces, %s", path, n, len(faces), list(fields))


# ---------------------------------------------------------------------------------------------
# reading


def read(path) -> Table:
    """A PLY in any of its three formats as a ``Table`` (``naming`` 'ply'): every scalar
    vertex property (colour bytes, and other 8/16-bit unsigned properties, scaled to [0, 1]),
    triangle faces when the face element is a list of 3 (else None), the ``aobake-metadata``
    comment.  Raises ``Unreadable``."""
    ply = parse_ply(Path(path).read_bytes())
    vertex, metadata = ply.vertex, ply.metadata
    columns = {name: vertex[name] for name in vertex.dtype.names}
    for name, array in columns.items():  # colour bytes mean [0, 1]
        if array.dtype.kind == "u" and array.dtype.itemsize <= 2:
            columns[name] = array / float(np.iinfo(array.dtype).max)
    positions = normals = None
    if {"x", "y", "z"} <= set(columns):
        positions = np.column_stack([columns.pop(a) for a in "xyz"]).astype(np.float64)
    if {"nx", "ny", "nz"} <= set(columns):
        normals = np.column_stack([columns[a] for a in ("nx", "ny", "nz")]).astype(np.float64)
    return Table(columns, "ply", positions, normals, ply.faces,
                 metadata if isinstance(metadata, dict) else {})


PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


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
    if not data.startswith(b"ply"):
        raise Unreadable("not a PLY file (no 'ply' line)")
    end = data.find(b"end_header")
    if end < 0:
        raise Unreadable("no end_header")
    newline = data.find(b"\n", end)
    if newline < 0:
        raise Unreadable("truncated after end_header")
    body = newline + 1
    fmt, metadata, elements = None, {}, []
    for line in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        words = line.split()
        if not words:
            continue
        if words[0] == "format":
            fmt = words[1] if len(words) > 1 else None
        elif words[0] == "comment" and words[1:2] == [METADATA_COMMENT]:
            text = line.split(None, 2)[2] if len(words) > 2 else ""
            metadata = parse_json(text, f"its {METADATA_COMMENT} comment")
        elif words[0] == "element":
            if len(words) != 3:
                raise Unreadable(f"malformed header line {line.strip()!r}")
            elements.append((words[1], _ply_count(words[1], words[2], len(data)), []))
        elif words[0] == "property":
            if not elements:
                raise Unreadable("a property before any element")
            if len(words) != (5 if words[1:2] == ["list"] else 3):
                raise Unreadable(f"malformed header line {line.strip()!r}")
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


def _ply_count(name: str, text: str, size: int) -> int:
    """An element's count: a whole number, at most the file's size in bytes (every item
    takes at least one byte), so nothing is allocated beyond what the file holds."""
    try:
        count = int(text)
    except ValueError:
        raise Unreadable(f"element {name!r} has count {text!r}, not a number") from None
    if count < 0 or count > size:
        raise Unreadable(f"element {name!r} claims {count} items in a file of {size} bytes")
    return count


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
            lists = [p[0] for p in props if len(p) == 3]
            whole = max(len(data) - offset, 0) // dtype.itemsize  # the items the bytes hold
            head = np.frombuffer(data, dtype=dtype, count=whole, offset=offset) if whole \
                else None
            if lists and (head is None or any((head[p + "#count"] != 3).any() for p in lists)):
                break  # not all triangles: read as 3-lists, its true size is unknown here
            # the vertex element, or a triangle list, that ends before its count: a file cut
            # short (the faces cannot be dropped: the values would be read without them)
            raise Unreadable(f"truncated: element {name!r} runs past the end of the file "
                             f"({count} items declared, {whole} there)")
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
            whole = len(chunk) // width
            counts = np.array(chunk[:whole * width], dtype=object).reshape(whole, width)
            counts = counts[:, _lists_at(props)].astype(np.float64)
            if (counts != 3).any():
                break  # not all triangles: read as 3-lists, its true length is unknown here
            raise Unreadable(f"truncated: element {name!r} runs past the end of the file "
                             f"({count} items declared, {whole} there)")
        table = np.array(chunk, dtype=np.float64).reshape(count, width)
        columns, col = {}, 0
        for prop in props:
            if len(prop) == 2:
                columns[prop[0]] = _ascii_column(prop[0], table[:, col], prop[1])
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


def _lists_at(props) -> list:
    """The token offsets of the list counts in one row of ``props``, every list read as
    holding 3 (``_ply_ascii``'s layout)."""
    at, out = 0, []
    for prop in props:
        if len(prop) == 3:
            out.append(at)
            at += 4
        else:
            at += 1
    return out


def _ascii_column(name: str, values: np.ndarray, dtype: str) -> np.ndarray:
    """A text column in its declared type: an integer type's values must be whole numbers
    within its range (a cast would wrap them silently)."""
    dtype = np.dtype(dtype)
    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        bad = ~((values >= info.min) & (values <= info.max) & (values == np.floor(values)))
        if bad.any():
            raise Unreadable(f"property {name!r}: {values[bad][0]:g} is not a {dtype} value")
        return values.astype(dtype)
    with np.errstate(over="ignore"):  # a float32 property beyond its range is inf, refused later
        return values.astype(dtype)


