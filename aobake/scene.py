"""Load a mesh file into one bakeable triangle scene, validate it, and give it normals.

Data flow: file -> :class:`Scene` (float64 positions, int64 triangles, unit
vertex normals, optional per-corner UVs).  Every object of a multi-object file
or glTF scene is flattened into one scene with its node transform applied, so
every object occludes every other.

Vertex normal policy (``--normals``):

* ``file``: the file's own normals where it has them (OBJ ``vn`` averaged over the
  corners of each ``v``; glTF/PLY vertex normals), otherwise ``angle``.
* ``angle``: angle-weighted mean of the adjacent face normals (Thürmer & Wüthrich).
* ``area``: area-weighted mean of the adjacent face normals.

A vertex on a sharp crease gets one averaged normal; the hemisphere around it may
dip below an adjacent face.  Rays in those directions hit that face and count as
occluded: at a concave crease that is what the geometry says (the corner is
darker); at a convex crease no hemisphere direction enters the solid, so nothing
is lost.  A vertex whose normal is undefined (unreferenced, or touching only
zero-area faces) is not sampled: it gets 0 rays and the no-information estimate
(see ``aobake.quantities``), and the report counts it.

Winding (``--fix-normals``, :mod:`aobake.repair`): triangles wound against their
neighbours and components turned inside out are found before any normal is computed.
``warn`` (default) counts them in a warning and changes nothing; ``fix`` flips them
(faces and per-corner UV indices), so face and computed vertex normals come from the
repaired winding, and a file normal of a flipped triangle's vertex that points against
the vertex's repaired angle-weighted normal is replaced by that normal; ``off`` skips
the check.  ``Scene.repair`` (report: ``scene.fix_normals``) says what was found and done.
"""

from __future__ import annotations

import gc
import logging
import os
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import math
import warnings

import numpy as np

from aobake import _native
from aobake import repair as repairs
from aobake.vectors import column_bounds, column_medians, normalize

from aobake.errors import InputError

log = logging.getLogger(__name__)

#: file extensions read by :func:`load_scene`; OBJ by aobake's own reader, the rest by trimesh.
MESH_EXTENSIONS = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")


#: a float64 coordinate step above this fraction of the median triangle size is warned of
QUANTISED_FRACTION = 1e-3

_trim = []  # [glibc's malloc_trim, or None], looked up once


def release_freed_memory() -> None:
    """Hand the pages of freed heap blocks back to the system (glibc's ``malloc_trim(0)``;
    nothing where the C library has none).

    glibc raises its mmap threshold to the size of each large block freed (up to 32 MiB), so
    later arrays below it come from its heap, and keeps the holes they leave resident: after the
    loader's temporaries are freed, ~90 MiB of a 2M-triangle mesh's load stayed in the
    process and under every later stage's peak (benchmarks/bench_memory.py).  Called
    where a stage's temporaries have just been freed (the end of a load and of the
    occluders' build); it takes milliseconds and changes no value."""
    if not _trim:
        import ctypes

        try:
            _trim.append(ctypes.CDLL(None).malloc_trim)
        except (AttributeError, OSError):  # not glibc
            _trim.append(None)
    if _trim[0] is not None:
        _trim[0](0)


@dataclass(frozen=True)
class ExtraOccluder:
    """Triangles that block a bake's rays beside the scene's own faces.

    name : what they are (the report's), vertices : (v, 3) float64 scene units, faces :
    (f, 3) int64, skip : float scene units: a hit counts only beyond this distance from the
    ray's origin, and only on a front face (the ray travels against the face's normal), so
    a surface the baked points lie on or just under does not shadow them (docs/studio.md).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    skip: float = 0.0


#: faces whose normals and areas are remade at a time from a scene's ``frame``
#: (:func:`face_rows`: bounds the corner temporary to ~150 bytes a face of one block)
FACE_BLOCK = 1 << 16


def face_rows(vertices: np.ndarray, faces: np.ndarray, center: np.ndarray, scale: float,
              normals: bool = True):
    """(unit normals (f, 3) float64 | None, areas (f,) float64) of ``faces`` over
    ``vertices`` (v, 3) float64, computed as :func:`make_scene` computes them: from the
    coordinates rebased on ``center`` and scaled by the power of two ``scale`` (the scene's
    ``frame``), the area ``0.5 |cross| / scale^2``: the same bits, a block of faces at a
    time (each row's value depends on its own three corners alone, and the local
    coordinates are ``(vertices - center) * scale`` whether made per vertex or per corner),
    so that no (v, 3) copy of the mesh is made."""
    n = len(faces)
    unit = np.empty((n, 3)) if normals else None
    areas = np.empty(n)
    corners = None
    for start in range(0, n, FACE_BLOCK):
        block = slice(start, min(n, start + FACE_BLOCK))
        k = block.stop - block.start
        tri = ((vertices[faces[block]] - center) * scale).reshape(-1, 3)
        if corners is None or len(corners) != k:
            corners = np.arange(3 * k, dtype=np.int64).reshape(k, 3)
        compiled = compiled_triangle_normals(tri, corners)
        if compiled is not None:
            rows, length = compiled[0], compiled[1]
        else:  # make_scene's numpy lines
            tri = tri.reshape(k, 3, 3)
            cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            rows, length = _normalize(cross), np.linalg.norm(cross, axis=1)
        if normals:
            unit[block] = rows
        areas[block] = 0.5 * length / (scale * scale)
    return unit, areas


#: the longest run :func:`pairwise_sum` hands to numpy's own sum
PAIRWISE_LEAF = 1 << 16


def pairwise_sum(n: int, leaf, start: int = 0) -> float:
    """``float(values.sum())`` of n float64 values that are never held at once: ``leaf(a,
    b)`` gives values[a:b] ((b - a,) float64), PAIRWISE_LEAF at most at a time.

    numpy sums a contiguous float64 array pairwise: a run of more than 128 values is split
    at ``n2 = n // 2 - (n // 2) % 8`` and its halves summed the same way (numpy's
    ``pairwise_sum``), so the sum of the whole is the sum of the halves' sums, bit for bit;
    this splits as numpy does down to runs numpy then sums itself (tests/test_memory.py
    checks it against ``np.sum``)."""
    if n <= PAIRWISE_LEAF:
        return float(np.add.reduce(leaf(start, start + n))) if n else 0.0
    half = n // 2
    half -= half % 8
    return pairwise_sum(half, leaf, start) + pairwise_sum(n - half, leaf, start + half)


class _FaceNormals:
    """``Scene.face_normals``: the array given, or where it was let go (``Scene.lean``)
    remade from the scene's ``frame`` on first use (:func:`face_rows`, the same bits) and
    kept from then on.  A data descriptor of a dataclass field: ``__init__`` sets it, a
    frozen scene's own assignment is refused as for every field."""

    def __set_name__(self, owner, name):
        self._key = "_" + name

    def __get__(self, scene, owner=None):
        if scene is None:  # no default: the field is required
            raise AttributeError("face_normals")
        value = scene.__dict__.get(self._key)
        if value is None and scene.__dict__.get("frame") is not None:
            center, scale = scene.frame
            value = face_rows(scene.vertices, scene.faces, center, scale)[0]
            scene.__dict__[self._key] = value
        return value

    def __set__(self, scene, value):
        scene.__dict__[self._key] = value


class _Names:
    """``Scene.names``: the dict given (or None), or where a function was given, the dict it
    makes, made on first use and kept (see the field)."""

    def __get__(self, scene, owner=None):
        if scene is None:
            return None  # the field's default
        value = scene.__dict__.get("_names")
        if callable(value):
            value = value()
            scene.__dict__["_names"] = value
        return value

    def __set__(self, scene, value):
        # (the field's default, as dataclass hands it to __init__, is this descriptor)
        scene.__dict__["_names"] = None if value is self else value


@dataclass(frozen=True)
class Scene:
    """One triangle scene in float64, as baked.

    vertices : (v, 3) float64        positions in scene units
    faces : (f, 3) int64             triangles (degenerate ones kept; they never occlude)
    vertex_normals : (v, 3) float64  unit, or zero where undefined
    face_normals : (f, 3) float64    unit (winding order, counter-clockwise = front), zero if degenerate
    uv : (t, 2) float64 | None       texture coordinates (OBJ convention, v = 0 at image bottom)
    faces_uv : (f, 3) int64 | None   per-corner index into ``uv``
    source : str                     file name or "<memory>"
    normals_source : str             "file" | "angle" | "area": what vertex normals came from
    """

    vertices: np.ndarray
    faces: np.ndarray
    vertex_normals: np.ndarray
    face_normals: np.ndarray = _FaceNormals()
    uv: np.ndarray | None = None
    faces_uv: np.ndarray | None = None
    source: str = "<memory>"
    normals_source: str = "angle"
    warnings: list = field(default_factory=list)
    #: the input's materials (base colour and alpha mode only), kept for lightmap GLBs and
    #: alpha-cutout occluders: a list of {"name": str, "base_color_png": bytes | None,
    #: "base_color_factor": [r, g, b, a] | None, "metallic_roughness_png": bytes | None (glTF:
    #: G roughness, B metalness; for --orm), "alpha_mode": "OPAQUE" | "MASK" | "BLEND",
    #: "alpha_cutoff": float (glTF's, default 0.5), and for a MASK material whose declared
    #: base-colour texture cannot be read, "base_color_error": str (the texture and why;
    #: ``--alpha-cutout`` refuses such a material, see ``aobake.backends.cutout``)}, or None
    #: when the input has none (or no UVs to map them with)
    materials: list | None = None
    #: (f,) int64 index into ``materials`` of each face (None with ``materials``)
    face_material: np.ndarray | None = None
    #: (f,) float64 triangle areas (computed with the face normals; None: computed on demand)
    face_areas: np.ndarray | None = field(default=None, repr=False)
    #: what --fix-normals found and did (see :func:`repair_record`); None for a Scene built
    #: directly
    repair: dict | None = None
    #: the names the input gives its faces, for selecting them (``aobake.groups``): kind ->
    #: (names: tuple of str, index: (f,) int64 each face's name, -1 for none), kinds
    #: "object" and "group" (OBJ ``o`` / ``g``), "node" and "mesh" (glTF / other formats
    #: through trimesh: the scene-graph node and its mesh), "material" (OBJ ``usemtl``, a
    #: glTF material); None when the input names nothing.  Given as a function that makes
    #: that dict (a set's baked instances: ``aobake.placed``), it is made where first read
    #: (a selection by name) and kept: a bake that selects nothing never holds the index
    names: dict | None = field(default=_Names(), repr=False)
    #: (f,) bool the faces that block rays (``aobake.groups``: the others are baked but cast
    #: nothing), or None: every face does
    occluding: np.ndarray | None = field(default=None, repr=False)
    #: which of the input's UV sets ``uv`` is (glTF ``TEXCOORD_<uv_set>``; 0 for every other
    #: format, whose one set is 0)
    uv_set: int = 0
    #: with ``uv_set`` > 0: every UV set of the glTF input, {k: (v, 2) float64 per vertex,
    #: OBJ convention} (``uv`` is ``uv_sets[uv_set]``), kept for the lightmap GLB; else None
    uv_sets: dict | None = field(default=None, repr=False)
    #: triangles that occlude but are not the scene's faces (:class:`ExtraOccluder`: a
    #: high-to-low bake's low mesh with ``--low-occludes``): never baked, never hit by a
    #: primary or cage ray, only by the method's rays
    extra_occluders: tuple = field(default=(), repr=False)
    #: a scene whose meshes stand in many places (``aobake.instances.Instances``: glTF
    #: nodes sharing a mesh, EXT_mesh_gpu_instancing): every instance occludes, and the
    #: faces above are the baked instances' (all of them unless ``--bake`` chose some), placed
    #: in scene units, in instance order; None for a scene loaded flat
    instances: object = field(default=None, repr=False)
    #: (center (3,) float64, scale float: a power of two) the frame :func:`make_scene`
    #: computed the face normals and areas in, ``(vertices - center) * scale``; with it
    #: they can be let go while a bake does not read them and remade, the same bits
    #: (:meth:`lean`, :func:`face_rows`); None for a Scene built directly
    frame: tuple | None = field(default=None, repr=False)

    def __post_init__(self):
        """Shapes and index ranges checked, also for a Scene built directly (``make_scene``
        validates everything else): a bad one is an InputError now, not an IndexError
        deep in a bake."""
        v, f = np.asarray(self.vertices), np.asarray(self.faces)
        if v.ndim != 2 or v.shape[1] != 3 or v.dtype.kind != "f":
            raise InputError(f"{self.source}: vertices must be (n, 3) floats, got "
                             f"{v.shape} {v.dtype}")
        if f.ndim != 2 or f.shape[1] != 3 or f.dtype.kind not in "iu" or len(f) == 0:
            raise InputError(f"{self.source}: faces must be (f, 3) integers (f > 0), got "
                             f"{f.shape} {f.dtype}")
        if f.min() < 0 or f.max() >= len(v):
            raise InputError(f"{self.source}: face index out of range (have {len(v)} "
                             "vertices)")
        given = self.__dict__.get("_face_normals")
        if given is None and self.frame is None:
            raise InputError(f"{self.source}: face_normals must be ({len(f)}, 3), got None")
        for name, rows in (("vertex_normals", len(v)), ("face_normals", len(f))):
            array = np.asarray(self.vertex_normals if name == "vertex_normals" else given)
            if name == "face_normals" and given is None:
                continue  # let go (lean): remade from the frame when read
            if array.shape != (rows, 3):
                raise InputError(f"{self.source}: {name} must be ({rows}, 3), got "
                                 f"{array.shape}")
        given_names = self.__dict__.get("_names")
        for kind, (names, index) in (given_names if isinstance(given_names, dict)
                                     else {}).items():
            if np.shape(index) != (len(f),) or (len(index) and (np.min(index) < -1 or
                                                                 np.max(index) >= len(names))):
                raise InputError(f"{self.source}: the {kind} names do not match the faces")
        if self.occluding is not None and np.shape(self.occluding) != (len(f),):
            raise InputError(f"{self.source}: occluding must be ({len(f)},) bools, got "
                             f"{np.shape(self.occluding)}")

    def referenced(self) -> np.ndarray:
        """(v,) bool the vertices that faces reference."""
        referenced = np.zeros(len(self.vertices), dtype=bool)  # np.unique without a sort
        referenced[self.faces.ravel()] = True
        return referenced

    @property
    def used(self) -> np.ndarray:
        """(u,) int64 sorted indices of the vertices that faces reference (made on each
        use, not kept: 8 bytes a vertex a bake would hold while it traces; the bounds it
        gives are kept)."""
        return np.flatnonzero(self.referenced())

    @cached_property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64 min and max corner over vertices used by faces (with
        ``instances`` some of which are not baked: over every instance's, so the diagonal, a
        relative max distance and the ground plane are the whole scene's)."""
        if self.instances is not None and not self.instances.everything:
            return np.array(self.instances.bounds, dtype=np.float64)
        referenced = self.referenced()
        return column_bounds(self.vertices, None if referenced.all() else referenced)

    def used_median(self) -> np.ndarray:
        """(3,) float64 the per-axis median of the used vertices (the tracer's origin),
        ``np.median(vertices[used], axis=0)``'s bits without its copies of the rows."""
        referenced = self.referenced()
        return column_medians(self.vertices, None if referenced.all() else referenced)

    @cached_property
    def diagonal(self) -> float:
        """Length of the bounding-box diagonal: the scene's scale for relative settings."""
        lo, hi = self.bounds
        return float(np.linalg.norm(hi - lo))

    def areas(self, block: slice | None = None) -> np.ndarray:
        """(f,) float64 triangle areas (computed at load, or now: from the ``frame`` where
        the scene has one, the load's bits; not kept); with ``block``, of ``faces[block]``
        alone (the same bits as those rows of the whole)."""
        faces = self.faces if block is None else self.faces[block]
        if self.face_areas is not None:
            return self.face_areas if block is None else self.face_areas[block]
        if self.frame is not None:
            return face_rows(self.vertices, faces, *self.frame, normals=False)[1]
        return _face_areas(self.vertices, faces)  # (each row's bits its own)

    def lean(self) -> "Scene":
        """This scene without its face normals and areas (32 bytes a triangle): a bake that
        reads them only at its start (a per-vertex AO bake reads the areas for the points'
        sizes and the report, no face normal after the load) does not hold them while it
        traces; whatever reads them later gets them remade from ``frame``, the same bits
        (face normals kept from then on, areas made per call).  The scene itself where it
        has no frame (built directly: nothing to remake them from)."""
        if self.frame is None:
            return self
        out = self.replaced(face_normals=None, face_areas=None)
        if self.face_areas is not None:
            # the report's area figures, made while the areas are here (a cached value, as
            # ``bounds``: a scene replaced from this one makes its own)
            out.__dict__["area_summary"] = self.area_summary
        return out

    def replaced(self, **changes) -> "Scene":
        """``dataclasses.replace`` that leaves face normals let go (:meth:`lean`) let go and
        names still to be made unmade (``replace`` reads every field it is not given: it
        would make them)."""
        if self.__dict__.get("_face_normals") is None and "face_normals" not in changes:
            changes["face_normals"] = None
        if callable(self.__dict__.get("_names")) and "names" not in changes:
            changes["names"] = self.__dict__["_names"]  # still to be made where read
        return replace(self, **changes)

    @cached_property
    def area_summary(self) -> tuple:
        """(surface area float: the areas' sum, degenerate triangles int: area <= 0).
        Without the areas held (a lean scene): the same sum made a block of faces at a
        time (:func:`pairwise_sum`)."""
        if self.face_areas is not None or self.frame is None:
            areas = self.areas()
            return float(areas.sum()), int(np.count_nonzero(areas <= 0))
        degenerate = [0]

        def leaf(start, stop):
            areas = self.areas(slice(start, stop))
            degenerate[0] += int(np.count_nonzero(areas <= 0))
            return areas

        return pairwise_sum(len(self.faces), leaf), degenerate[0]

    def stats(self) -> dict:
        """Scene statistics for the report."""
        lo, hi = self.bounds
        surface, degenerate = self.area_summary
        return {
            "source": self.source,
            "vertices": int(len(self.vertices)),
            "triangles": int(len(self.faces)),
            "degenerate_triangles": degenerate,
            "unreferenced_vertices": int(len(self.vertices)
                                         - np.count_nonzero(self.referenced())),
            "surface_area": surface,
            "bounds_min": lo.tolist(),
            "bounds_max": hi.tolist(),
            "diagonal": self.diagonal,
            "normals_source": self.normals_source,
            "has_uv": self.faces_uv is not None,
            "fix_normals": self.repair if self.repair is not None else repair_record("off"),
            **({} if self.instances is None else {"instances": self.instances.record()}),
        }


def repair_record(mode: str, counts: dict | None = None, flipped: int = 0,
                  replaced: int = 0) -> dict:
    """The report's ``scene.fix_normals``: the mode, the detector's counts (None with
    ``off``: nothing was looked at), ``faces_flipped`` and ``normals_replaced`` (file
    normals replaced by computed ones; 0 unless ``fix``)."""
    keys = ("components", "closed_components", "nearly_closed_components",
            "faces_against_neighbours",
            "components_with_faces_against", "inward_components", "conflicting_edges")
    out = {"mode": mode}
    out.update({key: None if counts is None else counts[key] for key in keys})
    out.update(faces_flipped=int(flipped), normals_replaced=int(replaced))
    return out


def _face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(f,) float64 triangle areas."""
    tri = vertices[faces]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def _normalize(vectors: np.ndarray) -> np.ndarray:
    """Unit rows; rows of zero (or non-finite) length become zero rather than NaN."""
    return normalize(vectors)[0]


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(f, 3) float64 unit face normals from the winding; zero for degenerate faces."""
    compiled = compiled_triangle_normals(vertices, faces)
    if compiled is not None:
        return compiled[0]
    tri = vertices[faces]
    return _normalize(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]))


def _corner_cosines(tri: np.ndarray) -> np.ndarray:
    """(3, f) float64 the cosine of each corner's angle of the triangles ``tri`` (f, 3, 3),
    clipped to [-1, 1]: the dot product of the unit edges, summed (x x' + z z') + y y'.
    That is np.einsum("ij,ij->i")'s order where numpy reduces a row of 3 in AVX-512 lanes
    (x86-64 with AVX-512, as the machines the outputs were fixed on), written out so that
    every build gives those bits and the compiled kernel can give them too."""
    cosines = np.empty((3, len(tri)))
    for corner in range(3):
        a = _normalize(tri[:, (corner + 1) % 3] - tri[:, corner])
        b = _normalize(tri[:, (corner + 2) % 3] - tri[:, corner])
        dot = (a[:, 0] * b[:, 0] + a[:, 2] * b[:, 2]) + a[:, 1] * b[:, 1]
        cosines[corner] = np.clip(dot, -1.0, 1.0)
    return cosines


def compiled_triangle_normals(vertices, faces, cross: bool = False, cosines: bool = False):
    """(unit (f, 3), length (f,), cross (f, 3) | None, cosines (3, f) | None) from the
    compiled kernel (``triangle_normals``: the numpy formulations' bits, tested), or None
    where it was not built, is switched off, or the input is not float64 vertices (v, 3)
    and integer faces (f, 3) in range (the numpy path then does, or raises, what it does)."""
    kernels = _native.kernels()
    if kernels is None:
        return None
    vertices, faces = np.asarray(vertices), np.asarray(faces)
    if (vertices.dtype != np.float64 or vertices.ndim != 2 or vertices.shape[1] != 3
            or faces.ndim != 2 or faces.shape[1] != 3 or faces.dtype.kind not in "iu"):
        return None
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    n = len(faces)
    unit, length = np.empty((n, 3)), np.empty(n)
    out_cross = np.empty((n if cross else 0, 3))
    out_cos = np.empty((3, n if cosines else 0))
    if not kernels.triangle_normals(np.ascontiguousarray(vertices), faces, unit, length,
                                    out_cross, out_cos):
        return None
    return unit, length, out_cross if cross else None, out_cos if cosines else None


def vertex_normals(vertices: np.ndarray, faces: np.ndarray, weighting: str = "angle") -> np.ndarray:
    """(v, 3) float64 unit vertex normals, weighted by corner angle or face area; zero where undefined.

    With the compiled kernels (``triangle_normals``, np.arccos, ``vertex_normal_sums``)
    the same bits, ~5x faster (tests/test_normals_kernel.py compares them)."""
    if weighting not in ("area", "angle"):
        raise ValueError(f"unknown normal weighting {weighting!r}")
    compiled = compiled_triangle_normals(vertices, faces, cross=weighting == "area",
                                 cosines=weighting == "angle")
    if compiled is not None:
        unit, _, cross, cosines = compiled
        out = compiled_vertex_normals(faces, len(vertices), unit, cross, cosines)
        if out is not None:
            return out
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    if weighting == "area":
        # |cross| = 2 * area, so the raw cross product is already area-weighted.
        weights = np.repeat(cross[:, None, :], 3, axis=1)
    else:
        unit = _normalize(cross)
        weights = unit[:, None, :] * np.arccos(_corner_cosines(tri)).T[:, :, None]
    # Sums in the order np.add.at over corner 0, 1, 2 would make (bincount adds its inputs
    # in sequence), so the same bits, 5-10x faster.
    index = np.ascontiguousarray(np.asarray(faces, dtype=np.intp).T).reshape(-1)
    w = np.ascontiguousarray(weights.transpose(1, 0, 2)).reshape(-1, 3)
    accum = np.stack([np.bincount(index, weights=w[:, d], minlength=len(vertices))
                      for d in range(3)], axis=1)
    return _normalize(accum)


def compiled_vertex_normals(faces, n_vertices: int, unit, cross, cosines):
    """The compiled ``vertex_normal_sums`` of :func:`vertex_normals`: (v, 3) unit normals
    from the face rows ``cross`` (area weighting; ``cosines`` None) or ``unit`` weighted by
    the corner angles ``np.arccos(cosines)`` ((3, f), taken in place: ``cosines`` is
    consumed), or None where the kernel declines."""
    out = np.empty((n_vertices, 3))
    if cosines is None:
        rows, angles = cross, np.empty((3, 0))
    else:  # np.arccos is numpy's own: its float64 arccos is not the C library's everywhere
        rows, angles = unit, np.arccos(cosines, out=cosines)
    if _native.kernels().vertex_normal_sums(np.ascontiguousarray(faces, dtype=np.int64),
                                            rows, angles, out):
        return out
    return None


#: the largest coordinate magnitude and the smallest extent a scene may have: beyond them
#: triangle areas (products of two coordinates) leave float64's range.  Tracing itself
#: works at any scale (aobake.trace rescales the scene for Embree's float32).
MAX_COORDINATE = 1e150
MIN_EXTENT = 1e-150


def checked_materials(face_material, materials, n_faces: int, source: str):
    """(f,) int64 each face's index into ``materials``, checked (InputError naming
    ``source`` where they do not match the faces); None without materials."""
    if materials is None:
        return None
    face_material = np.asarray(face_material, dtype=np.int64)
    if face_material.shape != (n_faces,) or face_material.min() < 0 \
            or face_material.max() >= len(materials):
        raise InputError(f"{source}: material indices do not match the faces")
    return face_material


def replace_flipped_normals(vnormals, local, faces, flipped):
    """A flipped face's file normals were made for its old side: where one points against
    its vertex's repaired (angle-weighted) normal it is replaced by that.  vnormals (v, 3)
    float64 unit file normals, local (v, 3) the vertices in the load's frame, faces (f, 3)
    int64 as repaired, flipped (f,) bool the faces flipped.  Returns (normals (v, 3), the
    count replaced)."""
    computed = vertex_normals(local, faces, "angle")
    touched = np.zeros(len(vnormals), dtype=bool)
    touched[faces[flipped].ravel()] = True
    against = touched & (np.einsum("ij,ij->i", vnormals, computed) < 0)
    return np.where(against[:, None], computed, vnormals), int(np.count_nonzero(against))


def make_scene(
    vertices,
    faces,
    normals=None,
    normals_mode: str = "file",
    uv=None,
    faces_uv=None,
    source: str = "<memory>",
    warnings=None,
    materials: list | None = None,
    face_material=None,
    fix_normals: str = "warn",
    names: dict | None = None,
) -> Scene:
    """Validate arrays and build a :class:`Scene`.

    vertices : (v, 3) float, faces : (f, 3) int, normals : (v, 3) float or None
    (the shading normals when ``normals_mode == "file"``; with any mode they orient
    open components, see :mod:`aobake.repair`).  fix_normals : "warn" | "fix" | "off"
    (see the module docstring).  names : see ``Scene.names`` (kinds without a name dropped).  Raises InputError naming ``source`` on empty,
    non-finite or out-of-range input.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise InputError(f"{source}: vertices must be (n, 3), got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise InputError(f"{source}: mesh has no faces" if faces.size == 0
                         else f"{source}: faces must be (n, 3) triangles, got {faces.shape}")
    if not np.issubdtype(faces.dtype, np.integer):
        raise InputError(f"{source}: face indices must be integers, got {faces.dtype}")
    faces = faces.astype(np.int64, copy=False)  # the loader's own array: no copy
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError(f"{source}: face index out of range (have {len(vertices)} vertices)")
    bad = ~np.isfinite(vertices).all(axis=1)  # unreferenced ones too: nothing unchecked
    if bad.any():
        raise InputError(f"{source}: {int(bad.sum())} vertices have NaN or infinite coordinates")
    referenced = np.zeros(len(vertices), dtype=bool)  # a mask, not np.unique: no sort
    referenced[faces.ravel()] = True
    used = vertices[referenced]
    lo, hi = used.min(axis=0), used.max(axis=0)
    extent = float((hi - lo).max())
    largest = float(np.abs(used).max())
    del used
    if largest > MAX_COORDINATE or 0 < extent < MIN_EXTENT:
        raise InputError(f"{source}: coordinates up to {largest:.3g} and extent {extent:.3g} are "
                         f"outside what aobake bakes: |coordinates| <= {MAX_COORDINATE:g} and "
                         f"extent >= {MIN_EXTENT:g} scene units (areas are float64; rescale "
                         "the mesh)")
    warnings = list(warnings or [])
    if fix_normals not in repairs.MODES:
        raise InputError(f"fix_normals must be one of {sorted(repairs.MODES)}, got {fix_normals!r}")
    # Normals and areas from coordinates rebased and scaled by a power of two (exact), so
    # neither the cross products nor their norms under- or overflow at extreme scales.
    center = 0.5 * (lo + hi)
    scale = 2.0 ** -math.frexp(extent)[1] if extent > 0 else 1.0
    local = (vertices - center) * scale
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != vertices.shape:
            if normals_mode == "file":
                raise InputError(f"{source}: normals must be {vertices.shape}, got {normals.shape}")
            normals = None  # not used for shading; the repair's vote goes without them
    if uv is not None:  # checked before a repair reorders its corners
        faces_uv = np.asarray(faces_uv if faces_uv is not None else faces, dtype=np.int64)
        if faces_uv.shape != faces.shape:
            raise InputError(f"{source}: UV indices do not match the faces")
    flipped = None
    if fix_normals == "off":
        record = repair_record("off")
    else:
        # One unit vote per vertex (an OBJ's are sums over its corners); a non-finite or
        # zero normal does not vote.
        votes = None if normals is None else _normalize(normals)
        orientation = repairs.orient(local, faces, votes)
        counts = orientation.counts()
        if fix_normals == "fix" and orientation.flip.any():
            flipped = orientation.flip
            faces = repairs.flip_faces(faces, flipped)
            if uv is not None:
                faces_uv = repairs.flip_faces(faces_uv, flipped)
        text = repairs.orientation_warning(fix_normals, counts,
                                           0 if flipped is None else int(flipped.sum()), source)
        if text:
            warnings.append(text)
        record = repair_record(fix_normals, counts, 0 if flipped is None else flipped.sum())
    # Angle-weighted vertex normals need the face normals and the corner cosines: one pass
    # of the kernel gives both (the same bits as two), and the cosines are dropped as soon
    # as the normals are summed.
    angles = normals_mode == "angle" or (normals_mode == "file" and normals is None)
    compiled = compiled_triangle_normals(local, faces, cosines=angles)
    cosines = None
    if compiled is not None:  # the bits of the lines below (normalize's length is norm's)
        fnormals, length, cosines = compiled[0], compiled[1], compiled[3]
    else:
        tri = local[faces]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        fnormals = _normalize(cross)  # as face_normals(), sharing the cross product
        length = np.linalg.norm(cross, axis=1)
    areas = 0.5 * length / (scale * scale)
    del length
    n_degenerate = int(np.count_nonzero(~fnormals.any(axis=1)))
    if n_degenerate == len(faces):
        raise InputError(f"{source}: every face has zero area")
    if n_degenerate:
        warnings.append(f"{source}: {n_degenerate} zero-area triangles (they never occlude)")

    mode = normals_mode
    if normals_mode == "file":
        if normals is not None:
            vnormals = _normalize(normals)
            if flipped is not None:
                vnormals, replaced = replace_flipped_normals(vnormals, local, faces, flipped)
                record["normals_replaced"] = replaced
        else:
            mode = "angle"
    if mode != "file":
        vnormals = None
        if cosines is not None and mode == "angle":
            vnormals = compiled_vertex_normals(faces, len(vertices), fnormals, None, cosines)
        if vnormals is None:
            vnormals = vertex_normals(local, faces, mode)
    elif not vnormals[referenced].any(axis=1).all():
        # Fill the file's missing (zero) normals rather than leaving holes.
        computed = vertex_normals(local, faces, "angle")
        vnormals = np.where(vnormals.any(axis=1, keepdims=True), vnormals, computed)
    del cosines, local
    if uv is not None:
        uv = np.asarray(uv, dtype=np.float64)
        if faces_uv.shape != faces.shape or faces_uv.min() < 0 or faces_uv.max() >= len(uv):
            raise InputError(f"{source}: UV indices do not match the faces")
        if not np.isfinite(uv[faces_uv]).all():
            raise InputError(f"{source}: UV coordinates contain NaN or infinity")
    face_material = checked_materials(face_material, materials, len(faces), source)
    # float64 itself quantises coordinates far from the origin: at 1e15 every coordinate is a
    # multiple of 0.125.  Say so where that step is a visible fraction of the triangles.
    sized = areas[areas > 0]
    typical = math.sqrt(2.0 * float(np.median(sized))) if len(sized) else 0.0
    step = float(np.spacing(largest))
    if typical > 0 and step > QUANTISED_FRACTION * typical:
        warnings.append(f"{source}: coordinates up to {largest:.3g} are quantised by float64 "
                        f"itself to steps of {step:.3g}, {step / typical:.2g} of the median "
                        "triangle size: the file's positions are already rounded (translate "
                        "the mesh nearer the origin before exporting it)")
    for message in warnings:
        log.warning(message)
    names = {kind: (tuple(str(n) for n in given), np.asarray(index, dtype=np.int64))
             for kind, (given, index) in (names or {}).items() if len(given)} or None
    return Scene(vertices, faces, vnormals, fnormals, uv, faces_uv if uv is not None else None,
                 source, mode, warnings, materials, face_material, areas, record, names,
                 frame=(center, scale))


def _obj_normals(data) -> np.ndarray | None:
    """Per-``v`` normals from an OBJ: the mean of the ``vn`` its corners use (None if absent).

    Vertices none of whose corners has a ``vn`` get zero here and are filled by
    angle weighting in :func:`make_scene`.
    """
    if data.faces_normal is None:
        return None
    corners = data.faces_normal.ravel()
    has = corners >= 0
    at, rows = data.faces.ravel()[has], data.normals[corners[has]]
    # np.add.at's sums (in corner order, from 0.0) by bincount, a column at a time: the
    # same additions in the same order, ten times faster
    accum = np.empty_like(data.vertices, dtype=np.float64)
    for k in range(3):
        accum[:, k] = np.bincount(at, weights=rows[:, k], minlength=len(data.vertices))
    return accum


def _png_bytes(image) -> bytes:
    """Any PIL image -> PNG file bytes (glTF embeds PNG or JPEG; the GLB writer takes PNG)."""
    import io

    buffer = io.BytesIO()
    image.save(buffer, format="PNG")
    return buffer.getvalue()


def _white(name: str) -> dict:
    return {"name": name, "base_color_png": None, "base_color_factor": None,
            "metallic_roughness_png": None, "roughness_factor": None, "metallic_factor": None,
            "alpha_mode": "OPAQUE", "alpha_cutoff": 0.5}


def _read_mtl(path: Path, names: list) -> dict:
    """name -> {"Kd": [...], "map_Kd": [...]} for the materials ``names`` defined in ``path``."""
    found, current = {}, None
    for line in path.read_text(errors="replace").splitlines():
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        if parts[0] == "newmtl":
            current = " ".join(parts[1:])
        elif current in names and parts[0] in ("Kd", "map_Kd") and len(parts) > 1:
            found.setdefault(current, {})[parts[0]] = parts[1:]
    return found


def _obj_materials(path: Path, data) -> tuple[list | None, np.ndarray | None]:
    """Base colours (Kd, map_Kd) of an OBJ's materials from its .mtl files, and each face's
    material.  Faces before any ``usemtl`` get a white material named "default"."""
    if not data.materials or not data.mtllibs:
        return None, None
    found = {}
    for lib in data.mtllibs:
        mtl = path.parent / lib
        try:
            defined = _read_mtl(mtl, data.materials) if mtl.is_file() else {}
        except OSError as exc:
            log.warning("%s: material library %s not read (%s)", path, lib, exc)
            defined = {}
        for name, values in defined.items():
            found.setdefault(name, values)
    materials = []
    for name in data.materials:
        material = _white(name)
        values = found.get(name, {})
        try:
            if "Kd" in values:
                material["base_color_factor"] = [min(max(float(x), 0.0), 1.0)
                                                 for x in values["Kd"][:3]] + [1.0]
            if "map_Kd" in values:
                from PIL import Image

                with Image.open(path.parent / values["map_Kd"][-1]) as image:
                    material["base_color_png"] = _png_bytes(image)
        except (OSError, ValueError) as exc:
            log.warning("%s: base colour of material %r not kept (%s)", path, name, exc)
        materials.append(material)
    face_material = data.face_material.copy()
    if (face_material < 0).any():
        materials.append(_white("default"))
        face_material[face_material < 0] = len(materials) - 1
    return materials, face_material


def _image_name(header: dict, index) -> str:
    """How a message names glTF ``images[index]``: its file, else its place in the file."""
    image = header["images"][index]
    uri = image.get("uri")
    if isinstance(uri, str) and not uri.startswith("data:"):
        return uri
    return f"images[{index}] (embedded)"


def gltf_broken_textures(path: Path) -> dict:
    """glTF material name (None: unnamed) -> "texture X: problem" for every alphaMode MASK
    material whose declared baseColorTexture cannot be read or decoded.

    trimesh drops such an image without a word (its loader only logs at debug level), and a
    cut-out material without its alpha would occlude everywhere: wrong AO, not an error,
    unless it is noticed here.  Only MASK materials are checked (only their alpha is used)."""
    import io

    from PIL import Image

    from aobake.outputs.gltf import image_bytes, read_gltf

    try:
        header, binary = read_gltf(path)
    except InputError:
        return {}  # trimesh has read it: let its result stand
    broken = {}
    materials = header.get("materials") if isinstance(header, dict) else None
    for material in materials if isinstance(materials, list) else []:
        if not isinstance(material, dict) or material.get("alphaMode") != "MASK":
            continue
        pbr = material.get("pbrMetallicRoughness")
        texture = pbr.get("baseColorTexture") if isinstance(pbr, dict) else None
        if texture is None:
            continue
        name, what = material.get("name"), "its baseColorTexture"
        try:
            source = header["textures"][texture["index"]]["source"]
            what = f"texture {_image_name(header, source)}"
            data = image_bytes(header, binary, source, path.parent)
        except FileNotFoundError:
            broken[name] = f"{what}: no such file"
            continue
        except (OSError, ValueError, KeyError, IndexError, TypeError) as exc:
            broken[name] = f"{what}: cannot be read ({type(exc).__name__}: {exc})"
            continue
        try:
            with Image.open(io.BytesIO(data)) as image:
                image.load()  # open() reads the header alone; a truncated image fails here
        except Image.UnidentifiedImageError:
            broken[name] = f"{what}: not an image PIL can decode ({len(data)} bytes)"
        except (OSError, ValueError, Image.DecompressionBombError) as exc:
            broken[name] = f"{what}: corrupt image ({exc})"
    return broken


def trimesh_material(mesh, index: int, broken: dict | None = None) -> dict:
    """Base colour of one trimesh mesh's PBR (or simple) material; ``broken`` as
    :func:`gltf_broken_textures` returns (its entries mark MASK materials left without
    their texture)."""
    material = getattr(mesh.visual, "material", None)
    out = _white(getattr(material, "name", None) or f"material_{index}")
    if material is None:
        return out
    texture = getattr(material, "baseColorTexture", None)
    if texture is None:
        texture = getattr(material, "image", None)
    factor = getattr(material, "baseColorFactor", None)
    mode = getattr(material, "alphaMode", None)
    if isinstance(mode, str) and mode.upper() in ("OPAQUE", "MASK", "BLEND"):
        out["alpha_mode"] = mode.upper()
    cutoff = getattr(material, "alphaCutoff", None)
    try:
        if cutoff is not None and math.isfinite(float(cutoff)):
            out["alpha_cutoff"] = float(cutoff)
    except (TypeError, ValueError):  # a hand-edited cutoff that is not a number
        log.warning("alpha cutoff %r of material %r is not a number: 0.5 kept", cutoff,
                    out["name"])
    # roughness and metalness factors (glTF: they multiply the metallicRoughnessTexture's G
    # and B; absent means 1): an --orm GLB keeps them on its materials
    for key, attribute in (("roughness_factor", "roughnessFactor"),
                           ("metallic_factor", "metallicFactor")):
        value = getattr(material, attribute, None)
        try:
            if value is not None:
                value = float(value)
                if not 0.0 <= value <= 1.0:  # also NaN
                    raise ValueError
                out[key] = value
        except (TypeError, ValueError):  # hand-edited: not a number in [0, 1]
            log.warning("%s %r of material %r is not a number in [0, 1]: 1 (glTF's default) "
                        "kept", attribute, value, out["name"])
    try:
        if texture is not None:
            out["base_color_png"] = _png_bytes(texture)
        roughness = getattr(material, "metallicRoughnessTexture", None)
        if roughness is not None:  # G roughness, B metalness: what --orm packs beside AO
            out["metallic_roughness_png"] = _png_bytes(roughness)
        if factor is not None:
            factor = np.asarray(factor)
            # trimesh stores colours as uint8 (0-255); floats are already in [0, 1].
            scaled = factor / 255.0 if np.issubdtype(factor.dtype, np.integer) else factor
            rgba = np.clip(np.asarray(scaled, dtype=np.float64).reshape(-1)[:4], 0.0, 1.0).tolist()
            out["base_color_factor"] = (rgba + [1.0] * 4)[:4] if len(rgba) >= 3 else None
    except (OSError, ValueError, TypeError, AttributeError) as exc:
        log.warning("base colour of material %r not kept (%s)", out["name"], exc)
    raw = getattr(material, "name", None)
    if broken and out["alpha_mode"] == "MASK" and raw in broken and out["base_color_png"] is None:
        out["base_color_error"] = broken[raw]
    return out


def _trimesh_materials(meshes, broken: dict | None = None) -> tuple[list, np.ndarray]:
    """One entry per distinct material object of the meshes, and each face's index."""
    index, materials, per_mesh = {}, [], []
    for mesh in meshes:
        material = trimesh_material(mesh, len(materials), broken)
        # By content: trimesh's scene dump may copy one shared material per node.
        factor = material["base_color_factor"]
        key = (material["name"], material["base_color_png"], tuple(factor) if factor else None,
               material["metallic_roughness_png"], material["roughness_factor"],
               material["metallic_factor"], material["alpha_mode"], material["alpha_cutoff"],
               material.get("base_color_error"))
        if key not in index:
            index[key] = len(materials)
            materials.append(material)
        per_mesh.append(np.full(len(mesh.faces), index[key], dtype=np.int64))
    return materials, np.concatenate(per_mesh)


def _load_with_trimesh(path: Path, uv_set: int = 0, bake: tuple = ()):
    """(vertices, faces, normals | None, uv | None, (materials, face_material) | None, names,
    uv_sets | None, instances | None) for non-OBJ formats via trimesh.

    uv_set > 0 (glTF / GLB only): ``uv`` is ``TEXCOORD_<uv_set>`` and ``uv_sets`` every set
    the file's triangle primitives all have, {k: (v, 2) float64} (``aobake.uvsets``).
    A glTF scene that places a mesh more than once (or given ``bake`` patterns) is read as
    instances (``aobake.instances``): the arrays are then the baked instances' and
    ``instances`` the ``Instances`` record; else None.
    """
    import trimesh

    def read(source, kind):
        try:
            # trimesh's parsers cast whatever a corrupt file holds (NaN, overflow) with numpy
            # warnings; make_scene validates every value, so the warnings tell the user nothing.
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore")
                if kind == "gltf":  # its buffers and images beside it
                    from trimesh.resolvers import FilePathResolver

                    return trimesh.load(source, file_type=kind, process=False,
                                        resolver=FilePathResolver(str(path)))
                if kind is not None:
                    return trimesh.load(source, file_type=kind, process=False)
                return trimesh.load(source, process=False)
        except Exception as exc:  # trimesh raises many types for corrupt files
            raise InputError(f"{path}: cannot read mesh ({type(exc).__name__}: {exc})") \
                from None

    every = None
    if uv_set:
        from aobake import uvsets

        source, kind, every = uvsets.aliased(path)
        if uv_set not in every:
            raise uvsets.missing_set_error(path, uv_set, every, uvsets.sets_of(
                uvsets.read_json(path)[0])[1])
        loaded = read(source, kind)
    else:
        loaded = read(str(path), None)
        if path.suffix.lower() in (".gltf", ".glb"):
            from aobake import uvsets

            # trimesh gives TEXCOORD_0 only to primitives with a material: where it dropped
            # the file's UVs, they are read as --uv-set N's are (aliased), not lost
            if uvsets.dropped_first_set(loaded, path):
                loaded = read(*uvsets.aliased(path)[:2])
                uvsets.keep_first_set(loaded)
    placed = None
    if bake and not (isinstance(loaded, trimesh.Scene) and path.suffix.lower() in (".gltf", ".glb")):
        raise InputError(f"{path}: --bake names glTF nodes or OBJ objects and groups; this "
                         "file names none (to bake some of its faces and let the others "
                         "occlude, give the others --occluder-only)")
    if isinstance(loaded, trimesh.Scene):
        meshes = []
        if not uv_set and path.suffix.lower() in (".gltf", ".glb"):
            from aobake import instances

            try:  # the placed copies decode their materials' images, as dump() does
                placed = instances.read(loaded, path, tuple(bake))
            except InputError:
                raise
            except Exception as exc:  # noqa: BLE001 - PIL raises several types for a bad image
                raise InputError(f"{path}: cannot read mesh ({type(exc).__name__}: {exc})") \
                    from None
        if placed is not None:  # one copy of each mesh; the baked instances placed, one at a time
            from aobake.placed import placed_arrays

            return (*placed_arrays(placed, path), None, placed.instances)
        else:
            try:  # dump() copies each material, decoding its images: a truncated one fails here
                dumped = loaded.dump()
            except Exception as exc:  # noqa: BLE001 - PIL raises several types for a bad image
                raise InputError(f"{path}: cannot read mesh ({type(exc).__name__}: {exc})") \
                    from None
            # dump() applies every node's transform; one entry per node instance.
            for geom in dumped:
                if isinstance(geom, trimesh.Trimesh) and len(geom.faces):
                    meshes.append(geom)
        if not meshes:
            raise InputError(f"{path}: mesh has no faces")
    elif isinstance(loaded, trimesh.Trimesh):
        meshes = [loaded]
    else:
        raise InputError(f"{path}: holds no triangle mesh (got {type(loaded).__name__})")
    vertices, faces, normals, uvs, offset = [], [], [], [], 0
    names = _trimesh_names(meshes)
    have_normals = all("vertex_normals" in m._cache for m in meshes)
    have_uv = all(getattr(m.visual, "uv", None) is not None and len(m.visual.uv) == len(m.vertices)
                  for m in meshes)
    for mesh in meshes:
        vertices.append(np.asarray(mesh.vertices, dtype=np.float64))
        own = np.asarray(mesh.faces, dtype=np.int64)
        faces.append(own + offset if offset else own)
        if have_normals:
            normals.append(np.asarray(mesh.vertex_normals, dtype=np.float64))
        if have_uv:
            uvs.append(np.asarray(mesh.visual.uv, dtype=np.float64))
        offset += len(mesh.vertices)
    if len(meshes) == 1:  # no copies of one mesh's arrays
        vertices, faces = vertices[0], faces[0]
    else:
        vertices, faces = np.concatenate(vertices), np.concatenate(faces)
    if path.suffix.lower() == ".stl":
        # STL is a triangle soup: weld identical positions so vertices are shared.
        vertices, inverse = np.unique(vertices, axis=0, return_inverse=True)
        faces = inverse.reshape(-1)[faces]
        normals = []
    sets = None
    if uv_set:
        from aobake import uvsets

        sets = {}
        for k in every:
            per_mesh = [uvsets.mesh_uv(m, k) for m in meshes]
            if any(uv is None for uv in per_mesh):  # a primitive trimesh did not load as given
                raise InputError(f"{path}: cannot read TEXCOORD_{k} of every mesh")
            sets[k] = np.concatenate(per_mesh)
    materials = None
    if uvs:
        broken = gltf_broken_textures(path) if path.suffix.lower() in (".gltf", ".glb") else {}
        materials = _trimesh_materials(meshes, broken)
    def joined(arrays):  # one mesh's array as it is (no copy)
        return None if not arrays else arrays[0] if len(arrays) == 1 else np.concatenate(arrays)

    return (vertices, faces, joined(normals), joined(uvs), materials, names, sets,
            None if placed is None else placed.instances)


def _trimesh_names(meshes) -> dict:
    """``Scene.names`` of trimesh meshes (``Scene.dump``'s copies know their node and mesh
    names; a material its name): kind -> (names, (f,) int64 index)."""
    out = {}
    for kind, name_of in (("node", lambda m: m.metadata.get("node")),
                          ("mesh", lambda m: m.metadata.get("name")),
                          ("material", lambda m: getattr(getattr(m.visual, "material", None),
                                                         "name", None))):
        names = []
        for mesh in meshes:
            name = name_of(mesh)
            if name is not None and str(name) not in names:
                names.append(str(name))
        if not names:  # nothing named: no per-face index (make_scene drops the kind)
            out[kind] = (names, None)
            continue
        index = [np.full(len(mesh.faces), -1 if name_of(mesh) is None else
                         names.index(str(name_of(mesh))), dtype=np.int64) for mesh in meshes]
        out[kind] = (names, np.concatenate(index))
    return out


def load_scene(source, normals_mode: str = "file", fix_normals: str = "warn",
               uv_set: int = 0, bake=()) -> Scene:
    """Load a path or an in-memory mesh into a :class:`Scene`.

    source : str | PathLike | trimesh.Trimesh | trimesh.Scene | Scene (returned as it is)
    fix_normals : "warn" | "fix" | "off", see :func:`make_scene`
    uv_set : which UV set becomes ``Scene.uv``: glTF ``TEXCOORD_<uv_set>`` (InputError naming
    the sets the file has when it lacks it); every other format has set 0 alone
    bake : glTF node patterns (``--bake``, ``aobake.instances``): the scene's faces are
    those instances' alone, every other instance only occludes (``Scene.instances``); for an
    OBJ, object and group patterns: the scene's faces are those objects' and groups' (their
    vertices in file order, with the whole file's normals), every other face only occludes
    (``Scene.instances`` an ``aobake.instances.Subset``)
    Raises InputError (naming the file and the problem) for a missing file, an
    unsupported extension, a corrupt or empty file or invalid geometry.

    A glTF file that places a mesh more than once (nodes sharing it, EXT_mesh_gpu_instancing)
    loads as instances: ``Scene.instances`` holds each mesh once and every placement; the
    faces are every instance's placed (the flattened scene's, bit for bit) unless ``bake``
    names some.
    """
    bake = () if bake is None else (bake,) if isinstance(bake, str) else tuple(bake)
    if isinstance(source, Scene):
        instances = source.instances
        if bake and tuple(bake) != (() if instances is None else tuple(instances.patterns)):
            raise InputError(f"{source.source}: bake {list(bake)}: a Scene is baked as it "
                             "was loaded; load the file with these patterns")
        return source
    if bake and not isinstance(source, (str, os.PathLike)):
        raise InputError("bake names glTF nodes or OBJ objects: pass the file's path")
    if uv_set and not isinstance(source, (str, os.PathLike)):
        raise InputError(f"uv_set {uv_set}: an in-memory mesh has one UV set; pass the "
                         "glTF file (or give the Scene its uv)")
    if not isinstance(source, (str, os.PathLike)):
        import trimesh

        if isinstance(source, trimesh.Scene):
            source = source.to_mesh()
        if not isinstance(source, trimesh.Trimesh):
            raise InputError(f"cannot bake a {type(source).__name__}; pass a path or a trimesh mesh")
        normals = source.vertex_normals if "vertex_normals" in source._cache else None
        uv = getattr(source.visual, "uv", None)
        return make_scene(source.vertices, source.faces, normals, normals_mode,
                          uv=uv if uv is not None and len(uv) == len(source.vertices) else None,
                          fix_normals=fix_normals)
    path = Path(source)
    suffix = path.suffix.lower()
    if path.is_dir():
        raise InputError(f"{path}: is a directory, not a mesh file")
    if suffix not in MESH_EXTENSIONS:
        raise InputError(f"{path}: unsupported mesh format {suffix or '(no extension)'!r}; "
                         f"use one of {', '.join(MESH_EXTENSIONS)}")
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: file is empty")
    if bake and suffix not in (".gltf", ".glb", ".obj"):
        raise InputError(f"{path}: --bake names glTF nodes or OBJ objects and groups; a "
                         f"{suffix} file names none (to bake some of its faces and let the "
                         "others occlude, give the others --occluder-only)")
    if uv_set and suffix not in (".gltf", ".glb"):
        raise InputError(f"{path}: a {suffix} file has one UV set (set 0); --uv-set {uv_set} "
                         "needs a glTF or GLB input (TEXCOORD_<N>)")
    if suffix == ".obj":
        from aobake.obj import read_obj

        data = read_obj(path)
        has_uv = data.faces_uv is not None
        materials, face_material = _obj_materials(path, data) if has_uv else (None, None)
        names = {"object": (data.objects, data.face_object),
                 "group": (data.groups, data.face_group),
                 "material": (data.materials, data.face_material)}
        whole = make_scene(data.vertices, data.faces, _obj_normals(data), normals_mode,
                           uv=data.uv if has_uv else None, faces_uv=data.faces_uv,
                           source=str(path), warnings=data.warnings, materials=materials,
                           face_material=face_material, fix_normals=fix_normals, names=names)
        del data
        release_freed_memory()  # the reader's and make_scene's temporaries
        if not bake:
            return whole
        from aobake import instances  # the objects and groups named, the rest occluding

        return instances.subset(whole, bake)
    vertices, faces, normals, uv, materials, names, sets, instances = _load_with_trimesh(
        path, uv_set, bake)
    gc.collect()  # trimesh's objects are cycles: free them (and their copies) before make_scene
    materials, face_material = materials or (None, None)
    if sets is not None:
        uv = sets[uv_set]
        if materials is None:  # no TEXCOORD_0 for trimesh: the materials have no UVs either
            materials = face_material = None
    if instances is not None:  # the baked instances, a placement at a time (lean)
        from aobake.placed import make_placed_scene

        scene = make_placed_scene(vertices, faces, normals, normals_mode,
                                  (instances.vertex_offsets, instances.face_offsets), str(path),
                                  fix_normals, uv=uv, materials=materials,
                                  face_material=face_material, names=names)
    else:
        scene = make_scene(vertices, faces, normals, normals_mode, uv=uv, source=str(path),
                           materials=materials, face_material=face_material,
                           fix_normals=fix_normals, names=names)
    if sets is not None:
        scene = scene.replaced(uv_set=uv_set, uv_sets=sets)
    if instances is not None:
        scene = scene.replaced(instances=instances)
    release_freed_memory()  # the loader's and make_scene's temporaries
    return scene
