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
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping

import numpy as np

from aobake.outputs.atomic import atomic_path
from aobake.outputs.npz import check_vertex_data
from aobake.outputs.report import metadata_json
from aobake.quantities import FIELDS

log = logging.getLogger(__name__)

METADATA_COMMENT = "aobake-metadata"

# field name -> PLY property names (from the registry); float32 ("float") except integers
_PROPERTIES = {f.name: f.ply for f in FIELDS.values()}
_PLY_TYPES = {"<f8": "double", "<f4": "float", "<i4": "int", "|u1": "uchar"}



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


