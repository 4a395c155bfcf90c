"""Embree instances: every unique mesh committed once as a child scene, each placement an
instance geometry of it (``aobake._embree.instances``), traced as one top-level scene.

Built by ``aobake.occluders`` from a scene's ``Instances`` (``aobake.instances``) when the
compiled binding traces (``aobake.backends.native``); the acceleration structures then
hold the unique triangles plus one box per instance, whatever the number of placements.
It answers the queries of ``aobake.backends.base`` in the tracer's local frame, as the
triangle backends do: ``occluded`` through the same occlusion packets, ``distance`` and
``intersect`` one ray at a time.  A hit's ``prim`` is its triangle in the flattened
numbering (the instance's first face in the concatenation of every instance's faces, in
instance order, plus the triangle in its mesh): with every instance baked, the scene's
own face index.

Precision: Embree maps each ray into the instance's mesh frame in float32 (each mesh is
stored rebased on its own median and scaled by a power of two, so its coordinates keep
float32's precision whatever its origin); hits differ from the flattened scene's only for
rays grazing an edge, which the tests measure against the flattened bake's error bars.
"""

from __future__ import annotations

import numpy as np

from aobake.backends.base import TriangleBackend
from aobake.constants import RAY_FAR

_FAR = np.float32(RAY_FAR)


def available() -> bool:
    """True where the compiled binding traces (embreex has no instances)."""
    from aobake.backends.native import binding

    return binding() is not None


class InstancedEmbree(TriangleBackend):
    """One committed top-level scene of Embree instances (see the module docstring).

    instances : ``aobake.instances.Instances``; center (3,) float64, scale float: the
    tracer's local frame; step : local units stepped past a back face; robust : Embree's
    robust traversal."""

    name = "embree"

    def __init__(self, instances, center, scale: float, step: float, robust: bool = True):
        from aobake.backends.native import binding, packet_width
        from aobake.instances import local_placements
        from aobake.scene import face_normals

        found = binding()
        if found is None:
            raise RuntimeError("Embree instances need aobake._embree (not built or not opened)")
        self._native = found[0]
        self._width, source = packet_width(found[1])
        chosen = {"native": "Embree's native width on this CPU"}.get(source, source)
        self.binding = (f"aobake._embree instances (occlusion in packets of {self._width}: "
                        f"{chosen})")
        meshes, mesh_of, transforms, linear, mesh_faces = local_placements(
            instances, np.asarray(center, dtype=np.float64), float(scale))
        self._handle = self._native.instances(
            [(v, len(v), f, len(f)) for v, f in meshes], mesh_of, transforms, bool(robust))
        self._step = np.float32(step)
        self._face_normals = None  # per hit instead: intersect_normals
        # each mesh's face normals (in its own frame: the same directions as in mesh units)
        self._mesh_normals = np.concatenate([face_normals(v, f) for v, f in instances.meshes])
        self._mesh_faces = mesh_faces
        self._mesh = np.asarray(instances.mesh, dtype=np.int64)
        # a normal maps by the inverse transpose of its instance's 3x3 part: faces a mirrored
        # placement reverses (Scene.dump's flip) then face the way the flattened ones do
        with np.errstate(all="ignore"):
            inverse = np.linalg.inv(np.where(mesh_of[:, None, None] >= 0, linear, np.eye(3)))
        self._normal_maps = np.ascontiguousarray(np.transpose(inverse, (0, 2, 1)))
        counts = np.diff(mesh_faces)[self._mesh]
        self._first_face = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)

    @staticmethod
    def _tfar(tmax, n):
        tfar = np.empty(n, dtype=np.float32)
        tfar[:] = np.minimum(tmax, _FAR)
        return tfar

    def occluded(self, origins, directions, tmax) -> np.ndarray:
        """(n,) bool: a hit within (0, tmax]."""
        hit = np.empty(len(origins), dtype=bool)
        self._native.occluded(self._handle, _f32(origins), _f32(directions),
                              self._tfar(tmax, len(origins)), hit, self._width)
        return hit

    def _hits(self, origins, directions, tfar):
        """(t (n,) float32, prim (n,) int32 the triangle in its mesh, instance (n,) int32),
        -1 for both on a miss; a hit is a primitive at t strictly short of tfar."""
        n = len(origins)
        t = np.empty(n, dtype=np.float32)
        prim = np.empty(n, dtype=np.int32)
        instance = np.empty(n, dtype=np.int32)
        self._native.intersect_instanced(self._handle, _f32(origins), _f32(directions), tfar,
                                         t, prim, instance)
        hit = (prim >= 0) & (t < tfar)
        return t, np.where(hit, prim, -1), np.where(hit, instance, -1)

    def distance(self, origins, directions, tmax) -> np.ndarray:
        """(n,) float32 nearest-hit distance; inf where nothing is hit within tmax."""
        tfar = self._tfar(tmax, len(origins))
        t, prim, _ = self._hits(origins, directions, tfar)
        return np.where(prim >= 0, t, np.float32(np.inf))

    def intersect(self, origins, directions, tmax):
        """(t (n,) float32, prim (n,) int64 in the flattened numbering, -1 on a miss)."""
        t, prim, instance = self._hits(origins, directions, self._tfar(tmax, len(origins)))
        hit = prim >= 0
        flat = np.where(hit, self._first_face[np.maximum(instance, 0)] + prim, -1)
        return t, flat

    def intersect_normals(self, origins, directions, tmax):
        """``intersect`` with each hit's face normal in the local frame (k, 3), unnormalised
        (the front-face test reads its sign against the direction only)."""
        t, prim, instance = self._hits(origins, directions, self._tfar(tmax, len(origins)))
        hit = prim >= 0
        where = np.maximum(instance, 0)
        faces = self._mesh_faces[self._mesh[where]] + np.maximum(prim, 0)
        normals = np.einsum("nij,nj->ni", self._normal_maps[where], self._mesh_normals[faces])
        flat = np.where(hit, self._first_face[where] + prim, -1)
        return t, flat, normals


def _f32(rows) -> np.ndarray:
    """(n, 3) float32 C-contiguous (the compiled queries read raw rows)."""
    return np.ascontiguousarray(rows, dtype=np.float32)
