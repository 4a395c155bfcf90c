"""A strict Wavefront OBJ reader for the forms real archives publish.

Why not trimesh's loader: with ``process=False`` it re-indexes faces per group
and, on a file mixing ``v/vt`` and ``v//vn`` faces across groups, silently
returns faces that point into the wrong object (seen with trimesh 5.2).  A baker
that other tools are checked against must bake the geometry that is in the file,
so OBJ is read here and every index is checked.

Supported: ``v`` (extra w or colour columns ignored), ``vt``, ``vn``, ``f`` with
``v``, ``v/vt``, ``v//vn``, ``v/vt/vn`` corners, negative (relative) indices,
quads and n-gons (fan-triangulated from the first corner, as most tools do),
``mtllib``/``usemtl`` (recorded, so a lightmap
GLB can keep the base colour), line continuations.  Ignored with a count in the
warnings: ``l``/``p`` elements.  Ignored silently: ``o``/``g`` groups (all faces are baked
as one mesh), ``s``, comments.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from aobake.errors import InputError


@dataclass(frozen=True)
class ObjData:
    """What an OBJ file holds, triangulated.

    vertices : (v, 3) float64   the ``v`` lines in file order
    faces : (f, 3) int64        triangles indexing ``vertices``
    uv : (t, 2) float64 | None  the ``vt`` lines (OBJ convention: v = 0 at the image bottom)
    faces_uv : (f, 3) int64 | None   per-corner index into ``uv``; None unless every face has one
    normals : (k, 3) float64 | None  the ``vn`` lines
    faces_normal : (f, 3) int64 | None  per-corner index into ``normals``, -1 where a corner has none
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None
    faces_uv: np.ndarray | None
    normals: np.ndarray | None
    faces_normal: np.ndarray | None
    warnings: list = field(default_factory=list)
    mtllibs: list = field(default_factory=list)
    materials: list = field(default_factory=list)
    #: (f,) int64 index into ``materials`` of each triangle, -1 before any usemtl
    face_material: np.ndarray | None = None


def _logical_lines(text: str):
    """Yield (line number, line) joining backslash continuations."""
    pending, start = "", 0
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].rstrip()
        if not pending:
            start = number
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        yield start, pending + line
        pending = ""
    if pending:
        yield start, pending


def _resolve(token: str, count: int, path, number: int, what: str) -> int:
    """Turn a 1-based or negative OBJ index into a 0-based one, checking range."""
    try:
        index = int(token)
    except ValueError:
        raise InputError(f"{path}: line {number}: bad {what} index {token!r}") from None
    if index > 0:
        resolved = index - 1
    elif index < 0:
        resolved = count + index  # -1 is the most recent element defined so far
    else:
        raise InputError(f"{path}: line {number}: {what} index 0 is not valid in OBJ")
    if not 0 <= resolved < count:
        raise InputError(
            f"{path}: line {number}: {what} index {index} out of range ({count} defined so far)"
        )
    return resolved


def read_obj(path: str | os.PathLike) -> ObjData:
    """Read and triangulate an OBJ file; raise InputError naming the file and line on bad content."""
    try:
        with open(path, "rb") as handle:
            data = handle.read()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    if "\x00" in text[:4096]:
        raise InputError(f"{path}: not a text OBJ file (binary content)")

    verts, uvs, norms = [], [], []
    tri_v, tri_t, tri_n = [], [], []
    skipped = 0
    mtllibs, materials, tri_m, current = [], [], [], -1
    all_have_t = True
    for number, line in _logical_lines(text):
        parts = line.split()
        if not parts:
            continue
        key = parts[0]
        try:
            if key == "v":
                verts.append((float(parts[1]), float(parts[2]), float(parts[3])))
            elif key == "vt":
                uvs.append((float(parts[1]), float(parts[2]) if len(parts) > 2 else 0.0))
            elif key == "vn":
                norms.append((float(parts[1]), float(parts[2]), float(parts[3])))
            elif key == "f":
                corners = parts[1:]
                if len(corners) < 3:
                    raise InputError(f"{path}: line {number}: a face needs 3 or more corners")
                cv, ct, cn = [], [], []
                for corner in corners:
                    fields = corner.split("/")
                    cv.append(_resolve(fields[0], len(verts), path, number, "vertex"))
                    t = fields[1] if len(fields) > 1 and fields[1] else None
                    n = fields[2] if len(fields) > 2 and fields[2] else None
                    ct.append(-1 if t is None else _resolve(t, len(uvs), path, number, "texture"))
                    cn.append(-1 if n is None else _resolve(n, len(norms), path, number, "normal"))
                all_have_t &= min(ct) >= 0
                # Fan triangulation from the first corner (what Blender's importer and
                # most archives' writers assume for convex polygons).
                for k in range(1, len(corners) - 1):
                    tri_v.append((cv[0], cv[k], cv[k + 1]))
                    tri_t.append((ct[0], ct[k], ct[k + 1]))
                    tri_n.append((cn[0], cn[k], cn[k + 1]))
                    tri_m.append(current)
            elif key in ("l", "p"):
                skipped += 1
            elif key == "mtllib":
                mtllibs.append(line.split(None, 1)[1].strip())
            elif key == "usemtl":
                name = line.split(None, 1)[1].strip()
                if name not in materials:
                    materials.append(name)
                current = materials.index(name)
        except InputError:
            raise
        except (IndexError, ValueError):
            raise InputError(f"{path}: line {number}: malformed {key!r} statement") from None

    if not verts:
        raise InputError(f"{path}: no vertices in OBJ file")
    if not tri_v:
        raise InputError(f"{path}: mesh has no faces")
    warnings = []
    if skipped:
        warnings.append(f"{path}: ignored {skipped} line/point elements (only faces are baked)")
    return ObjData(
        vertices=np.asarray(verts, dtype=np.float64),
        faces=np.asarray(tri_v, dtype=np.int64),
        uv=np.asarray(uvs, dtype=np.float64) if uvs else None,
        faces_uv=np.asarray(tri_t, dtype=np.int64) if uvs and all_have_t else None,
        normals=np.asarray(norms, dtype=np.float64) if norms else None,
        faces_normal=np.asarray(tri_n, dtype=np.int64) if norms else None,
        warnings=warnings,
        mtllibs=mtllibs,
        materials=materials,
        face_material=np.asarray(tri_m, dtype=np.int64),
    )
