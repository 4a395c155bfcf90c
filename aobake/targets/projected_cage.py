"""The cage of a high-to-low bake, and the projection of low-poly points onto the source.

A *cage* is a mesh with the low-poly mesh's topology (the same vertex count and the same
triangles) lying outside both meshes.  A point of the low surface (face f, barycentric b)
has its cage point at the same (f, b) on the cage; its *projection ray* starts there and
runs towards the low point and beyond it, up to twice their distance:

    origin = cage(f, b),  direction = (low(f, b) - origin) / L,  L = |low(f, b) - origin|,
    tmax = 2 L

and the *projected point* is the ray's first hit on the source (the high-poly mesh).  Both
kinds of cage are such meshes:

* ``--cage-offset D``: every low vertex pushed out along its vertex normal by D (scene
  units, or 'P%' of the low mesh's bounding-box diagonal).  Its cage point is
  low(f, b) + D n(f, b), n the *unnormalised* interpolation of the vertex normals, so the
  ray runs along -n / |n| for 2 D |n| (|n| <= 1: a little less than 2 D inside a curved
  face): the cage is one watertight mesh, so neighbouring texels never fall into a gap
  between two faces' rays, as they can where each face is pushed along its own normal.
* ``--cage CAGE``: the user's mesh, refused unless its vertex count and triangles (each as a
  set of three vertex indices, so a flipped winding still counts as the same triangle)
  are the low mesh's.

A ray that hits nothing within 2 L has *missed*; one whose first hit is the back of a
source face (the ray travels along the face normal: its origin was inside the source,
the cage too tight there) has hit the *back*.  A back hit is baked where it landed, about
the source's own normal there, and flagged; a miss is not baked.  The *projection
distance* is L - t, the signed height of the projected point above the low surface along
the ray (positive: the source lies outside the low mesh), in [-L, L].
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from aobake.errors import InputError
from aobake.settings.studio import parse_offset
from aobake.vectors import normalize

#: rays projected at once (memory, not results: each ray's hit is its own)
PROJECT_CHUNK = 1 << 14


def resolve_offset(offset, diagonal: float) -> float:
    """An offset from :func:`parse_offset` in scene units (``diagonal``: the low mesh's)."""
    offset = parse_offset(offset)
    return float(offset[:-1]) / 100.0 * diagonal if isinstance(offset, str) else offset


@dataclass
class Cage:
    """A cage: positions (v, 3) float64 on the low mesh's vertices (its faces are the low
    mesh's), kind "offset" | "mesh", offset : the offset in scene units (None for a mesh),
    given : what the user gave (the offset as given, or the cage file's name)."""

    positions: np.ndarray
    kind: str
    offset: float | None
    given: object

    def record(self, low) -> dict:
        """The report's ``projection.cage``: what the cage is, and how far it lies from the
        low mesh (per vertex: min, median, max)."""
        gap = np.linalg.norm(self.positions[low.used] - low.vertices[low.used], axis=1)
        return {"kind": self.kind, "given": self.given, "offset": self.offset,
                "vertex_distance": {"min": float(gap.min()), "p50": float(np.median(gap)),
                                    "max": float(gap.max())}}


def offset_cage(low, offset) -> Cage:
    """The low mesh pushed out along its vertex normals by ``offset`` (parse_offset's)."""
    distance = resolve_offset(offset, low.diagonal)
    return Cage(low.vertices + distance * low.vertex_normals, "offset", distance,
                offset if isinstance(offset, str) else float(offset))


def mesh_cage(low, cage_scene, warnings: list) -> Cage:
    """The user's cage mesh (a loaded Scene), refused unless it has the low mesh's topology;
    a warning when some of its vertices lie on the inner side of the low surface (their
    rays run outwards)."""
    if len(cage_scene.vertices) != len(low.vertices) or len(cage_scene.faces) != len(low.faces):
        raise InputError(f"{cage_scene.source}: a cage must have the low mesh's topology: it "
                         f"has {len(cage_scene.vertices)} vertices and {len(cage_scene.faces)} "
                         f"triangles, {low.source} has {len(low.vertices)} and "
                         f"{len(low.faces)}")
    same = np.sort(cage_scene.faces, axis=1) == np.sort(low.faces, axis=1)
    differ = int(np.count_nonzero(~same.all(axis=1)))
    if differ:
        first = int(np.flatnonzero(~same.all(axis=1))[0])
        raise InputError(f"{cage_scene.source}: a cage must have the low mesh's topology: "
                         f"{differ} of its {len(low.faces)} triangles use other vertices "
                         f"than {low.source}'s (the first: triangle {first}, "
                         f"{cage_scene.faces[first].tolist()} against "
                         f"{low.faces[first].tolist()})")
    push = cage_scene.vertices - low.vertices
    inward = int(np.count_nonzero(np.einsum("ij,ij->i", push, low.vertex_normals)[low.used] < 0))
    if inward:
        warnings.append(f"{cage_scene.source}: {inward} cage vertices lie on the inner side of "
                        f"{low.source} (their projection rays run outwards)")
    return Cage(np.asarray(cage_scene.vertices, dtype=np.float64).copy(), "mesh", None,
                str(cage_scene.source))


@dataclass
class Projection:
    """Where the cage rays of n low-poly points land on the source.

    hit : (n,) bool the ray hit the source within 2 L; back : (n,) bool the hit is the back
    of a source face (a subset of ``hit``); faces : (n,) int64 the source triangle hit (-1:
    missed); bary : (n, 3) float64 the barycentric coordinates of the hit there (0 on a
    miss); points : (n, 3) float64 the projected points, on the source triangle in float64
    (a miss: the low point); normals : (n, 3) float64 unit, the source's shading normal at
    the hit (its vertex normals interpolated, on the side of the face's own normal; zero on
    a miss: not traced); distance : (n,) float64 L - t, the height of the projected point
    above the low surface along the ray (0 on a miss); reach : (n,) float64 L, the cage
    point's distance from the low point (0: no cage ray, counted as a miss).
    """

    hit: np.ndarray
    back: np.ndarray
    faces: np.ndarray
    bary: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    distance: np.ndarray
    reach: np.ndarray

    def counts(self) -> dict:
        """The report's counts: points, hit (front and back), missed, back."""
        return {"points": int(len(self.hit)), "hit": int(np.count_nonzero(self.hit)),
                "missed": int(np.count_nonzero(~self.hit)),
                "back": int(np.count_nonzero(self.back))}


def project(occluders, high, low_points: np.ndarray, cage_points: np.ndarray,
            threads: int = 1, receivers=None) -> Projection:
    """Project low points (n, 3) float64 onto the source ``high`` (a Scene) along the rays
    from their cage points (n, 3) float64 (see the module docstring).

    occluders : ``aobake.occluders.Occluders`` whose backend holds ``high``'s triangles (the
    pipeline's: its ground plane is not a surface to project onto and is not asked);
    receivers : another Occluders of the same frame to project onto instead (``--groups``:
    the faces that may receive), or None.  threads : chunks traced at once (the result does
    not depend on it).
    """
    from aobake.hits import on_triangle, shading_normals

    built = receivers if receivers is not None else occluders
    faces_of = getattr(built, "faces", None)  # a backend over a subset of the faces
    n = len(low_points)
    hit = np.zeros(n, dtype=bool)
    back = np.zeros(n, dtype=bool)
    prim = np.full(n, -1, dtype=np.int64)
    points = np.empty((n, 3))
    bary = np.zeros((n, 3))
    normals = np.zeros((n, 3))
    distance = np.zeros(n)
    reach = np.empty(n)

    def block(lo):
        """Rows lo .. lo + PROJECT_CHUNK - 1, every step on the block (its temporaries stay
        small: whole-array ones of millions of rows cost more in page faults than in
        arithmetic), each row from its own inputs alone."""
        rows = slice(lo, min(n, lo + PROJECT_CHUNK))
        low, cage = low_points[rows], cage_points[rows]
        unit, length = normalize(low - cage)
        length = length[:, 0]
        reach[rows] = length
        points[rows] = low
        origins = built.to_local(cage).astype(np.float32)
        # 2 L in local units, rounded up by one float32 step so a hit at the far end stays in.
        tmax = np.nextafter((2.0 * length * built.scale).astype(np.float32),
                            np.float32(np.inf))
        cast = length > 0  # no cage ray: a miss
        directions = unit[cast].astype(np.float32)
        t, found = built.backend.intersect(origins[cast], directions, tmax[cast])
        found = found.astype(np.int64)
        if faces_of is not None:  # back to the scene's face indices
            found = np.where(found >= 0, faces_of[np.maximum(found, 0)], -1)
        cutout = getattr(built, "cutout", None)
        if cutout is not None:  # --alpha-cutout: the first opaque texel of those faces
            tc, pc = cutout.intersect(origins[cast], directions, tmax[cast])
            nearer = (pc >= 0) & ((found < 0) | (tc < t))
            t = np.where(nearer, tc, t)
            found = np.where(nearer, cutout.scene_faces[np.maximum(pc, 0)], found)
        where = np.flatnonzero(cast)[found >= 0]
        t, found = t[found >= 0], found[found >= 0]
        index = lo + where
        hit[index] = True
        prim[index] = found
        if not len(where):
            return
        u, c = unit[where], cage[where]
        # Embree's hit (float32, in the local frame) put back on its triangle in float64, as
        # the camera target does with its first hits.
        rough = c + (t.astype(np.float64) / built.scale)[:, None] * u
        on, b = on_triangle(high, found, rough)
        points[index], bary[index] = on, b
        ng = high.face_normals[found]
        back[index] = np.einsum("ij,ij->i", ng, u) > 0
        normals[index] = shading_normals(high, found, b, ng)
        # The height above the low surface: L minus how far along the ray the point lies.
        distance[index] = length[where] - np.einsum("ij,ij->i", on - c, u)

    starts = range(0, n, PROJECT_CHUNK)
    if threads > 1 and len(starts) > 1:
        with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="aobake-project") as pool:
            list(pool.map(block, starts))
    else:
        for lo in starts:
            block(lo)
    return Projection(hit, back, prim, bary, points, normals, distance, reach)
