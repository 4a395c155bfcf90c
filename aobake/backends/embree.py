"""Embree through embreex: float32, rebased coordinates, one-shot queries (the default backend).

``robust`` (``--embree-mode robust``, the default) builds the scene with Embree's robust
flag; ``fast`` without it.

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

from aobake.backends.base import TriangleBackend

# embreex reports a miss as tfar unchanged; 1e37 is its own "infinite" default.
_FAR = np.float32(1e37)


class EmbreeBackend(TriangleBackend):
    """One committed Embree scene of a triangle mesh (see ``aobake.backends.base``)."""

    name = "embree"

    def __init__(self, vertices, faces, face_normals, step, robust: bool = True):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        super().__init__(face_normals, step)
        # robust: Embree's RTC_SCENE_FLAG_ROBUST (watertight traversal: no ray slips between
        # two triangles sharing an edge); without it traversal is faster (benchmarks/
        # bench_robust.py measures both and the hits they differ in)
        self._scene = rtcore_scene.EmbreeScene(robust=bool(robust))
        local = np.asarray(vertices, dtype=np.float64).astype(np.float32)
        TriangleMesh(self._scene, local, np.ascontiguousarray(faces, dtype=np.int32))
        # Commit now, on one thread, rather than lazily inside the first worker's run().
        probe = np.zeros((1, 3), dtype=np.float32)
        self._scene.run(probe, np.array([[0, 0, 1]], dtype=np.float32), query="OCCLUDED")

    @staticmethod
    def _tfar(tmax, n):
        tfar = np.empty(n, dtype=np.float32)
        tfar[:] = np.minimum(tmax, _FAR)
        return tfar

    def occluded(self, origins, directions, tmax) -> np.ndarray:
        """(n,) bool: a hit within (0, tmax]."""
        hit = self._scene.run(origins, directions, dists=self._tfar(tmax, len(origins)),
                              query="OCCLUDED")
        return hit >= 0

    def distance(self, origins, directions, tmax) -> np.ndarray:
        """(n,) float32 nearest-hit distance; inf where nothing is hit within tmax."""
        tfar = self._tfar(tmax, len(origins))
        limit = tfar.copy()
        t = self._scene.run(origins, directions, dists=tfar, query="DISTANCE")
        return np.where(t < limit, t, np.float32(np.inf))

    def intersect(self, origins, directions, tmax):
        """(t (n,) float32, prim (n,) int32, -1 on a miss) of the nearest hit within tmax."""
        out = self._scene.run(origins, directions, dists=self._tfar(tmax, len(origins)),
                              query="INTERSECT", output=True)
        prim, t = out["primID"], out["tfar"]
        hit = (prim >= 0) & (t < np.minimum(tmax, _FAR))
        return t, np.where(hit, prim, -1)
