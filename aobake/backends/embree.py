"""Embree: float32, rebased coordinates, one-shot queries (the default backend).

``robust`` (``--embree-mode robust``, the default) builds the scene with Embree's robust
flag; ``fast`` without it.  The queries go through ``aobake._embree`` where it was built
(occlusion in packets of Embree's native width on this CPU, 16 lanes with AVX-512 and 8
with AVX2: faster than embreex's one ray at a time, with the same answers;
``aobake.backends.native``) and through embreex otherwise; ``binding`` says which, and the
packet width.

The backend owns float32: the tracer hands it the scene already in its local
frame (rebased on the vertices' median and scaled by a power of two), and
origins in the same frame.  ``occluded`` is Embree's occlusion
(any-hit) query, the cheapest there is; ``distance`` its distance query;
``intersect`` the closest-hit query with the primitive id, which the front-face
queries of ``--backfaces ignore`` need (they cost at least the ~30% more of a
distance query, plus the extra segments).
"""

from __future__ import annotations

import numpy as np

from aobake.constants import RAY_FAR
from aobake.backends.base import TriangleBackend

# embreex reports a miss as tfar unchanged; 1e37 is its own "infinite" default.
_FAR = np.float32(RAY_FAR)


class EmbreeBackend(TriangleBackend):
    """One committed Embree scene of a triangle mesh (see ``aobake.backends.base``)."""

    name = "embree"

    def __init__(self, vertices, faces, face_normals, step, robust: bool = True):
        from aobake.backends.native import binding, packet_width

        super().__init__(face_normals, step)
        native = binding()
        if native is not None:
            self._native = native[0]
            self._width, source = packet_width(native[1])
            # the report's parameters.embree_binding: the width and what chose it
            # (benchmarks/bench_peers.py reads "packets of N" back)
            chosen = {"native": "Embree's native width on this CPU"}.get(source, source)
            self.binding = f"aobake._embree (occlusion in packets of {self._width}: {chosen})"
            # Embree reads both arrays in place (the scene's capsule keeps them): the mesh
            # is held once, also while the BVH is built
            padded = padded_float32(vertices)
            faces32 = np.ascontiguousarray(faces, dtype=np.uint32)
            try:
                self._handle = self._native.scene(padded, len(vertices), faces32, len(faces),
                                                  bool(robust))
            except ValueError:  # a module built before it read arrays in place: it copies
                self._handle = self._native.scene(padded[:-1], len(vertices), faces32,
                                                  len(faces), bool(robust))
            return
        local = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64).astype(np.float32))
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self._native, self.binding = None, "embreex"
        # robust: Embree's RTC_SCENE_FLAG_ROBUST (watertight traversal: no ray slips between
        # two triangles sharing an edge); without it traversal is faster (benchmarks/
        # bench_robust.py measures both and the hits they differ in)
        self._scene = rtcore_scene.EmbreeScene(robust=bool(robust))
        TriangleMesh(self._scene, local, np.ascontiguousarray(faces, dtype=np.int32))
        # Commit now, on one thread, rather than lazily inside the first worker's run().
        probe = np.zeros((1, 3), dtype=np.float32)
        self._scene.run(probe, np.array([[0, 0, 1]], dtype=np.float32), query="OCCLUDED")

    def native_scene(self):
        """(aobake._embree, its scene) when the compiled binding traces, else None (for a
        compiled query beside the ones here: the cut-out march)."""
        return None if self._native is None else (self._native, self._handle)

    @staticmethod
    def _tfar(tmax, n):
        tfar = np.empty(n, dtype=np.float32)
        tfar[:] = np.minimum(tmax, _FAR)
        return tfar

    def occluded(self, origins, directions, tmax) -> np.ndarray:
        """(n,) bool: a hit within (0, tmax]."""
        if self._native is not None:
            hit = np.empty(len(origins), dtype=bool)
            self._native.occluded(self._handle, _f32(origins), _f32(directions),
                                  self._tfar(tmax, len(origins)), hit, self._width)
            return hit
        hit = self._scene.run(origins, directions, dists=self._tfar(tmax, len(origins)),
                              query="OCCLUDED")
        return hit >= 0

    def distance(self, origins, directions, tmax) -> np.ndarray:
        """(n,) float32 nearest-hit distance; inf where nothing is hit within tmax."""
        tfar = self._tfar(tmax, len(origins))
        if self._native is not None:
            t, _ = self._intersect(origins, directions, tfar)
            return np.where(t < tfar, t, np.float32(np.inf))
        limit = tfar.copy()
        t = self._scene.run(origins, directions, dists=tfar, query="DISTANCE")
        return np.where(t < limit, t, np.float32(np.inf))

    def intersect(self, origins, directions, tmax):
        """(t (n,) float32, prim (n,) int32, -1 on a miss) of the nearest hit within tmax."""
        if self._native is not None:
            return self._intersect(origins, directions, self._tfar(tmax, len(origins)))
        out = self._scene.run(origins, directions, dists=self._tfar(tmax, len(origins)),
                              query="INTERSECT", output=True)
        prim, t = out["primID"], out["tfar"]
        hit = (prim >= 0) & (t < np.minimum(tmax, _FAR))
        return t, np.where(hit, prim, -1)

    def _intersect(self, origins, directions, tfar):
        """As embreex's answers: a hit is a primitive at t strictly short of tfar."""
        t = np.empty(len(origins), dtype=np.float32)
        prim = np.empty(len(origins), dtype=np.int32)
        self._native.intersect(self._handle, _f32(origins), _f32(directions), tfar, t, prim)
        return t, np.where((prim >= 0) & (t < tfar), prim, -1)


def padded_rows(n: int) -> np.ndarray:
    """(n, 3) float32 rows to fill, a view of a flat array with one float beyond the last row
    (the padding Embree's 16-byte loads need of a buffer it reads in place): what
    :func:`padded_float32` takes without a copy."""
    flat = np.empty(3 * n + 1, dtype=np.float32)
    flat[-1] = 0.0
    return flat[:-1].reshape(n, 3)


def padded_float32(vertices) -> np.ndarray:
    """(3 v + 1,) float32: the rows of ``vertices`` (v, 3) cast to float32 (the bits of
    ``astype``) and one float of padding; rows from :func:`padded_rows` are returned as
    their flat array, not copied."""
    base = getattr(vertices, "base", None)
    if (isinstance(vertices, np.ndarray) and vertices.dtype == np.float32
            and isinstance(base, np.ndarray) and base.dtype == np.float32 and base.ndim == 1
            and base.size == vertices.size + 1 and vertices.flags.c_contiguous
            and vertices.ctypes.data == base.ctypes.data):
        return base
    rows = padded_rows(len(vertices))
    rows[:] = vertices
    return rows.base


def _f32(rows) -> np.ndarray:
    """(n, 3) float32 C-contiguous (the compiled queries read raw rows)."""
    return np.ascontiguousarray(rows, dtype=np.float32)
