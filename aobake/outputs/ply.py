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
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from aobake.outputs.atomic import atomic_path
from aobake.outputs.npz import check_vertex_data
from aobake.outputs.report import metadata_json

log = logging.getLogger(__name__)

METADATA_COMMENT = "aobake-metadata"

# field name -> PLY property names; the dtype is float32 ("float") except rays
_PROPERTIES = {
    "normals": ("nx", "ny", "nz"),
    "ao": ("ao",),
    "ao_stderr": ("ao_stderr",),
    "obscurance": ("obscurance",),
    "obscurance_stderr": ("obscurance_stderr",),
    "bent_normal": ("bent_normal_x", "bent_normal_y", "bent_normal_z"),
    "bent_normal_stderr": ("bent_normal_stderr",),
    "rays": ("rays",),
}
_PLY_TYPES = {"<f8": "double", "<f4": "float", "<i4": "int", "|u1": "uchar"}
_NUMPY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "<i2", "int16": "<i2", "ushort": "<u2", "uint16": "<u2",
    "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
    "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8",
}  # fmt: skip


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
        dtype = "<i4" if name == "rays" else "<f4"
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
        *(f"property {_PLY_TYPES[dtype]} {prop}" for prop, dtype, _ in columns),
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


def read(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, dict]:
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
