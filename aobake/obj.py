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
warnings: ``l``/``p`` elements.  ``o``/``g`` names are recorded per triangle (the whole rest of
the line is one name; all faces are baked as one mesh, and ``aobake.groups`` selects faces by
these names, ``--bake`` the faces to bake while the rest occludes:
``aobake.instances.subset``).  Ignored silently: ``s``, comments.

Two readers give the same :class:`ObjData`: a vectorised one (:func:`_read_fast`, numpy over
the whole file) for files in the forms exporters write, and the line-by-line one
(:func:`_read_slow`) for everything else and for every error message.  The fast one returns
None, never an error, when a file is not in its forms or holds anything invalid, so what a
file reads as, and what is wrong with it, are always the line-by-line reader's.
"""

from __future__ import annotations

import os
from typing import NamedTuple
from dataclasses import dataclass, field

import numpy as np

from aobake import _native
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
    #: the names of the ``o`` and ``g`` statements, in order of first use, and (f,) int64
    #: each triangle's index into them (-1 before any, or after a ``g`` without a name)
    objects: list = field(default_factory=list)
    face_object: np.ndarray | None = None
    groups: list = field(default_factory=list)
    face_group: np.ndarray | None = None


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


class _Statements:
    """The statements that are not geometry (``l``/``p``, ``mtllib``, ``usemtl``, ``o``,
    ``g``), read the same way by both readers.  A malformed one raises IndexError."""

    #: the statements that name the faces after them: key -> attribute of the name lists
    NAMING = {"o": "objects", "g": "groups"}

    def __init__(self):
        self.skipped = 0
        self.mtllibs: list = []
        self.materials: list = []
        self.current = -1  # index into materials of the latest usemtl, -1 before any
        self.objects: list = []
        self.groups: list = []
        self.named = {"o": -1, "g": -1}  # index of the latest o / g name, -1 before any

    def read(self, key: str, line: str) -> None:
        if key in ("l", "p"):
            self.skipped += 1
        elif key == "mtllib":
            self.mtllibs.append(line.split(None, 1)[1].strip())
        elif key == "usemtl":
            name = line.split(None, 1)[1].strip()
            if name not in self.materials:
                self.materials.append(name)
            self.current = self.materials.index(name)
        elif key in self.NAMING:  # "g" alone: the default group, no name
            name = line.split(None, 1)[1].strip() if len(line.split()) > 1 else None
            names = getattr(self, self.NAMING[key])
            if name is not None and name not in names:
                names.append(name)
            self.named[key] = -1 if name is None else names.index(name)


def _result(path, statements: _Statements, vertices, faces, uv, faces_uv, normals, faces_normal,
            face_material, face_object, face_group) -> ObjData:
    warnings = []
    if statements.skipped:
        warnings.append(f"{path}: ignored {statements.skipped} line/point elements "
                        "(only faces are baked)")
    return ObjData(vertices=vertices, faces=faces, uv=uv, faces_uv=faces_uv, normals=normals,
                   faces_normal=faces_normal, warnings=warnings, mtllibs=statements.mtllibs,
                   materials=statements.materials, face_material=face_material,
                   objects=statements.objects, face_object=face_object,
                   groups=statements.groups, face_group=face_group)


def _read_text(path) -> tuple[bytes, str, str]:
    """(file bytes, text, the encoding that decoded them), or InputError."""
    try:
        with open(path, "rb") as handle:
            data = handle.read()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    # A UTF-8 byte-order mark (some Windows exporters) would make the first key "\ufeffv".
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    return (data, *_decode(path, data))


def _decode(path, data: bytes) -> tuple[str, str]:
    """(text, encoding): UTF-8, else latin-1 (every byte string decodes as latin-1)."""
    try:
        text, encoding = data.decode("utf-8"), "utf-8"
    except UnicodeDecodeError:
        text, encoding = data.decode("latin-1"), "latin-1"
    if "\x00" in text[:4096]:
        raise InputError(f"{path}: not a text OBJ file (binary content)")
    return text, encoding


def read_obj(path: str | os.PathLike) -> ObjData:
    """Read and triangulate an OBJ file; raise InputError naming the file and line on bad content."""
    data, text, encoding = _read_text(path)
    fast = _read_fast(path, data, text, encoding)
    return fast if fast is not None else _read_slow(path, text)


def _read_slow(path, text: str) -> ObjData:
    """The reference reader: one logical line at a time, every statement and index checked."""
    verts, uvs, norms = [], [], []
    tri_v, tri_t, tri_n = [], [], []
    statements, tri_m, tri_o, tri_g = _Statements(), [], [], []
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
                    tri_m.append(statements.current)
                    tri_o.append(statements.named["o"])
                    tri_g.append(statements.named["g"])
            else:
                statements.read(key, line)
        except InputError:
            raise
        except (IndexError, ValueError):
            raise InputError(f"{path}: line {number}: malformed {key!r} statement") from None

    if not verts:
        raise InputError(f"{path}: no vertices in OBJ file")
    if not tri_v:
        raise InputError(f"{path}: mesh has no faces")
    return _result(
        path, statements,
        vertices=np.asarray(verts, dtype=np.float64),
        faces=np.asarray(tri_v, dtype=np.int64),
        uv=np.asarray(uvs, dtype=np.float64) if uvs else None,
        faces_uv=np.asarray(tri_t, dtype=np.int64) if uvs and all_have_t else None,
        normals=np.asarray(norms, dtype=np.float64) if norms else None,
        faces_normal=np.asarray(tri_n, dtype=np.int64) if norms else None,
        face_material=np.asarray(tri_m, dtype=np.int64),
        face_object=np.asarray(tri_o, dtype=np.int64),
        face_group=np.asarray(tri_g, dtype=np.int64),
    )


# ---------------------------------------------------------------------------------------------
# The vectorised reader.  It works on the file's bytes: a line is classified by its first bytes
# ("v " / "vt " / "vn " / "f " with a space or tab after the key, "#", empty, or other), the lines
# of each element kind are gathered into one block, and each block is parsed in one go.  It
# declines (returns None) rather than guess:
#   * a backslash anywhere (line continuations) or the ASCII separators \x1c-\x1f (line breaks
#     or whitespace to str.splitlines/str.split, not to bytes.split);
#   * non-ASCII line breaks (\x85, \u2028, \u2029) in a non-ASCII file;
#   * an element line whose key does not start the line ("  v 1 2 3", "v" alone);
#   * v/vt/vn lines of one kind with different numbers of values, or with a value float()
#     rejects (a trailing comment, a colour name: the slow reader reads only what it needs);
#   * face corners with more than two slashes, an index of more than 18 characters, an
#     index 0 or out of range, a face of fewer than 3 corners, characters other than digits,
#     "-", "/", spaces and tabs on an f line;
#   * no v or no f lines, and a malformed l/p/mtllib/usemtl statement.
# Values: floats are parsed by numpy's bytes->float64 conversion, which calls Python's float()
# (the same bits and the same accepted spellings as the slow reader); integers by
# np.fromstring after checking each is [-]digits, at most 18 of them (no int64 overflow).
# Where aobake._kernels was built, its obj_floats and obj_corners (aobake/_obj.c) parse a
# block first, the same values in one pass, and leave to numpy what they do not read.

_SKIP, _V, _VT, _VN, _F, _OTHER = range(6)
_ELEMENTS = ("v", "vt", "vn", "f")
_FACE_BYTES = b"0123456789-/ \t\n\r\x0b\x0cf"  # what an f line of the fast forms holds
_FACE_TO_SPACE = bytes.maketrans(b"f/\t\n\r\x0b\x0c", b"       ")


class _Corners(NamedTuple):
    """The corners of the f lines, in file order (c corners in all).

    per_face : (f,) int64       corners of each f line
    vertex, texture, normal : (c,) int64   the indices as written (0 where absent)
    has_texture, has_normal : (c,) bool
    """

    per_face: np.ndarray
    vertex: np.ndarray
    texture: np.ndarray
    normal: np.ndarray
    has_texture: np.ndarray
    has_normal: np.ndarray


def _floats(block: bytes, count: int, key: bytes, least: int, kernels=None) -> np.ndarray | None:
    """(count, w) float64 from ``count`` lines ``key x1 ... xw`` that all have the same w >= least.

    ``kernels``: aobake._kernels, whose obj_floats reads the plain forms (aobake/_obj.c) and
    leaves the rest to the numpy below.  One split of the whole block; the lines have the
    same width exactly when every w+1-th token is the key (a value is never the key: float()
    rejects it, which raises ValueError).
    """
    if kernels is not None:
        parsed = kernels.obj_floats(block, count, key, least)
        if parsed is not None:
            return np.frombuffer(parsed[1], np.float64).reshape(count, parsed[0])
    if not block.isascii():  # non-ASCII whitespace (U+00A0 ...) splits str, not bytes
        return None
    tokens = block.split()
    width, rest = divmod(len(tokens), count)
    if rest or width <= least or tokens[::width].count(key) != count:
        return None
    del tokens[::width]
    return np.array(tokens, dtype=np.float64).reshape(count, width - 1)


def _edges(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(starts, ends) of the runs of True in a mask that is False at both ends."""
    edges = np.flatnonzero(mask[1:] != mask[:-1]) + 1
    return edges[0::2], edges[1::2]


def _corners(block: bytes, count: int, kernels=None) -> _Corners | None:
    """Tokenise ``count`` f lines (each "f", its corners, one line break) without a Python loop.

    ``kernels``: aobake._kernels, whose obj_corners reads the plain forms (aobake/_obj.c) and
    leaves the rest to the numpy below."""
    if kernels is not None:
        parsed = kernels.obj_corners(block, count)
        if parsed is not None:
            ints = [np.frombuffer(b, np.int64) for b in parsed[:4]]
            return _Corners(*ints, *(np.frombuffer(b, np.bool_) for b in parsed[4:]))
    if block.translate(None, _FACE_BYTES) or block.count(b"f") != count:
        return None
    a = np.frombuffer(block, np.uint8)
    digit = (a - 48) <= 9  # uint8 arithmetic wraps: 48 <= a <= 57
    has_slash, has_minus = b"/" in block, b"-" in block
    num = digit | (a == 45) if has_minus else digit  # the characters of one index
    corner = num | (a == 47) if has_slash else num  # the characters of one corner
    # The block starts with "f" and ends with a line break, so runs never touch its ends.
    corner_start, corner_end = _edges(corner)
    run_start, run_end = _edges(num) if has_slash else (corner_start, corner_end)
    breaks = np.flatnonzero((a - 10) <= 3)  # \n \v \f \r: one per line, at its end
    per_face = np.diff(np.searchsorted(corner_start, breaks), prepend=0)
    if has_minus:
        # "-" only as the sign of an index, before a digit (np.fromstring reads "1 -" as 1, 0).
        minus = np.flatnonzero(a == 45)
        if not digit[minus + 1].all() or num[minus - 1].any():
            return None
    # At most 18 characters: no index overflows int64.
    if len(run_start) and (run_end - run_start).max() > 18:
        return None
    values = np.fromstring(block.translate(_FACE_TO_SPACE), dtype=np.int64, sep=" ")
    if len(values) != len(run_start):
        return None
    n = len(corner_start)
    if not has_slash:
        absent = np.zeros(n, np.int64), np.zeros(n, bool)
        return _Corners(per_face, values, absent[0], absent[0], absent[1], absent[1])
    if not num[corner_start].all():
        return None  # a corner without its vertex index ("/2")
    # slashes[p - 1]: the slashes before byte p (p > 0: byte 0 is the "f").
    slashes = np.cumsum(a == 47, dtype=np.int32 if len(a) < 2**31 else np.int64)
    before_corner = slashes[corner_start - 1]
    if (slashes[corner_end - 1] - before_corner > 2).any():
        return None  # the slow reader ignores a fourth field; this one does not guess
    corner_of_run = np.searchsorted(corner_start, run_start, side="right") - 1
    field = slashes[run_start - 1] - before_corner[corner_of_run]
    out = [np.zeros(n, np.int64) for _ in range(3)]
    present = [np.zeros(n, bool) for _ in range(3)]
    for k in range(3):
        which = field == k
        out[k][corner_of_run[which]] = values[which]
        present[k][corner_of_run[which]] = True
    return _Corners(per_face, out[0], out[1], out[2], present[1], present[2])


def _resolve_all(index: np.ndarray, count: np.ndarray) -> np.ndarray | None:
    """Vectorised :func:`_resolve`: 0-based indices, or None if one is 0 or out of range."""
    resolved = np.where(index > 0, index - 1, count + index)
    if (index == 0).any() or (resolved < 0).any() or (resolved >= count).any():
        return None
    return resolved


def _read_fast(path, data: bytes, text: str, encoding: str) -> ObjData | None:
    """The reader vectorised over the whole file: the same ObjData as :func:`_read_slow`, or
    None if the file is not in the forms it reads (see the list above) or anything is wrong."""
    if b"\\" in data or any(c in data for c in (b"\x1c", b"\x1d", b"\x1e", b"\x1f")):
        return None
    if not data.isascii() and any(c in text for c in ("\x85", "\u2028", "\u2029")):
        return None
    try:
        return _read_fast_bytes(path, data, encoding, _native.kernels())
    except (ValueError, IndexError):  # a value float() rejects, a malformed usemtl ...
        return None


def _read_fast_bytes(path, data: bytes, encoding: str, kernels=None) -> ObjData | None:
    # One line break added so every line ends with one, two bytes so the first three bytes of
    # every line can be read.
    a = np.frombuffer(data + b"\n  ", np.uint8)
    size = len(data) + 1
    ends = np.flatnonzero((a[:size] - 10) <= 3)  # \n \v \f \r, as str.splitlines (\r\n: an
    starts = np.r_[0, ends[:-1] + 1]             # extra empty line, which changes nothing)
    c0, c1, c2 = a[starts], a[starts + 1], a[starts + 2]
    space1 = (c1 == 32) | (c1 == 9)
    space2 = (c2 == 32) | (c2 == 9)
    kind = np.full(len(starts), _OTHER, np.uint8)
    kind[(c0 == 35) | (starts == ends)] = _SKIP
    kind[(c0 == 118) & space1] = _V
    kind[(c0 == 118) & (c1 == 116) & space2] = _VT
    kind[(c0 == 118) & (c1 == 110) & space2] = _VN
    kind[(c0 == 102) & space1] = _F
    counts = np.bincount(kind, minlength=6)
    if not counts[_V] or not counts[_F]:
        return None

    # Everything else, one line at a time, as the slow reader reads it.
    statements = _Statements()
    usemtl_at, usemtl_material = [], []
    named_at = {key: ([], []) for key in _Statements.NAMING}  # line numbers, name indices
    other = np.flatnonzero(kind == _OTHER)
    for i, start, end in zip(other.tolist(), starts[other].tolist(), ends[other].tolist()):
        line = data[start:end].decode(encoding).split("#", 1)[0].rstrip()
        parts = line.split()
        if not parts:
            continue
        if parts[0] in _ELEMENTS:
            return None
        statements.read(parts[0], line)
        if parts[0] == "usemtl":
            usemtl_at.append(i)
            usemtl_material.append(statements.current)
        elif parts[0] in named_at:
            named_at[parts[0]][0].append(i)
            named_at[parts[0]][1].append(statements.named[parts[0]])

    kind_of_byte = np.repeat(kind, ends - starts + 1)
    body = a[:size]

    def block(k):
        return body[kind_of_byte == k].tobytes()

    values = _floats(block(_V), int(counts[_V]), b"v", 3, kernels)
    if values is None:
        return None
    vertices = np.ascontiguousarray(values[:, :3])
    uv = normals = None
    if counts[_VT]:
        values = _floats(block(_VT), int(counts[_VT]), b"vt", 1, kernels)
        if values is None:
            return None
        uv = np.zeros((len(values), 2))
        uv[:, :min(2, values.shape[1])] = values[:, :2]  # "vt u" has v = 0, as in the slow reader
    if counts[_VN]:
        values = _floats(block(_VN), int(counts[_VN]), b"vn", 3, kernels)
        if values is None:
            return None
        normals = np.ascontiguousarray(values[:, :3])

    corners = _corners(block(_F), int(counts[_F]), kernels)
    if corners is None:
        return None
    f_lines = np.flatnonzero(kind == _F)
    per_face = corners.per_face
    if per_face.min() < 3:
        return None

    # Negative indices count back from the elements defined before the face's line.
    def defined_before(k):
        return np.repeat(np.cumsum(kind == k)[f_lines], per_face)

    v = _resolve_all(corners.vertex, defined_before(_V))
    if v is None:
        return None
    t = np.full(len(v), -1, np.int64)
    n = np.full(len(v), -1, np.int64)
    for has, index, k, out in ((corners.has_texture, corners.texture, _VT, t),
                               (corners.has_normal, corners.normal, _VN, n)):
        if has.any():
            resolved = _resolve_all(index[has], defined_before(k)[has])
            if resolved is None:
                return None
            out[has] = resolved

    # Fan triangulation from each face's first corner, triangles in file order.
    tris = per_face - 2
    face_of_tri = np.repeat(np.arange(len(f_lines)), tris)
    first = (np.cumsum(per_face) - per_face)[face_of_tri]
    k = np.arange(len(face_of_tri)) - np.repeat(np.cumsum(tris) - tris, tris) + 1
    corner = np.stack([first, first + k, first + k + 1], axis=1)

    def latest(at, value):  # per f line: the value of the latest statement before it
        if not at:
            return np.full(len(f_lines), -1, np.int64)
        index = np.searchsorted(np.asarray(at), f_lines) - 1
        return np.where(index >= 0, np.asarray(value, np.int64)[index], -1)

    material = latest(usemtl_at, usemtl_material)
    return _result(
        path, statements,
        vertices=vertices,
        faces=v[corner],
        uv=uv,
        faces_uv=t[corner] if uv is not None and corners.has_texture.all() else None,
        normals=normals,
        faces_normal=n[corner] if normals is not None else None,
        face_material=material[face_of_tri],
        face_object=latest(*named_at["o"])[face_of_tri],
        face_group=latest(*named_at["g"])[face_of_tri],
    )
