"""What a tracing backend is, and the registry the CLI's ``--backend`` reads.

A backend is built once per bake from the scene's triangles in the tracer's local
frame: rebased on the per-axis median of the vertices (far-from-origin scenes keep their
float32 precision) and scaled by a power of two so the scene spans [-1, 1) (tiny
and huge scenes stay inside float32's range):

    Backend(vertices (v, 3) float64 local, faces (f, 3) int64, face_normals (f, 3) float64
            unit, step float local units)

and answers four queries, each on origins (n, 3) float32 (rebased), directions
(n, 3) float32 unit and tmax (scalar or (n,) float32), all in local units, returning
(n,) arrays:

* ``occluded`` : bool, any hit with t in (0, tmax] (AO and bent normals: the
  cheapest query there is).
* ``distance`` : float32 distance to the nearest hit, inf on a miss (obscurance).
* ``front_occluded`` / ``front_distance`` : the same, but back-face hits (ray
  travelling along the face normal) are stepped through by ``step`` and do not
  count (``--backfaces ignore``).

A backend implements ``occluded``, ``distance`` and ``intersect``;
:class:`TriangleBackend` derives the front-face queries from ``intersect``.  A new
backend is one module with such a class plus one line in ``BACKENDS``
(``aobake/backends/__init__.py``).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

#: back faces stepped through before a ray counts as blocked where it is
MAX_BACKFACE_STEPS = 64


class Backend(Protocol):
    name: str

    def occluded(self, origins, directions, tmax) -> np.ndarray: ...

    def distance(self, origins, directions, tmax) -> np.ndarray: ...

    def front_occluded(self, origins, directions, tmax) -> np.ndarray: ...

    def front_distance(self, origins, directions, tmax) -> np.ndarray: ...


class TriangleBackend:
    """Front-face queries from a closest-hit ``intersect`` (subclasses provide it).

    ``intersect(origins, directions, tmax (n,) float32) -> (t (n,) float32, prim (n,) int)``
    with ``prim = -1`` where nothing is hit within tmax.
    """

    def __init__(self, face_normals, step: float):
        # kept as given (the scene's own float64 rows: no copy); each hit's row is rounded to
        # float32 as it is read, the bits a float32 copy of the whole array would give.  Or a
        # function that gives them, called at the first front-face query: a bake that asks
        # none (AO without --backfaces ignore) never holds them (24 bytes a triangle).
        self._face_normals = face_normals if callable(face_normals) \
            else np.asarray(face_normals)
        self._step = np.float32(step)

    def face_normals(self) -> np.ndarray:
        """(f, 3) the face normals of the backend's triangles (made now if given as a
        function, and kept)."""
        if callable(self._face_normals):
            self._face_normals = np.asarray(self._face_normals())
        return self._face_normals

    def intersect_normals(self, origins, directions, tmax):
        """``intersect`` and the face normal of each hit, (k, 3) float32 (any row on a miss):
        the front-face test's (a backend whose faces are not one array, Embree instances,
        computes them per hit)."""
        t, prim = self.intersect(origins, directions, tmax)
        return t, prim, self.face_normals()[np.maximum(prim, 0)].astype(np.float32)

    def front_distance(self, origins, directions, tmax) -> np.ndarray:
        """(n,) float32 distance to the nearest front-face hit; inf if none within tmax."""
        n = len(origins)
        result = np.full(n, np.inf, dtype=np.float32)
        travelled = np.zeros(n, dtype=np.float32)
        tmax = np.broadcast_to(np.asarray(tmax, dtype=np.float32), (n,))
        active = np.arange(n)
        org = origins.copy()
        for _ in range(MAX_BACKFACE_STEPS):
            if not len(active):
                break
            # A ray that stepped past a back face within one step of tmax has no length
            # left: a zero (not negative) limit, which every backend treats as a miss.
            remaining = np.maximum(tmax[active] - travelled[active], np.float32(0))
            t, prim, normals = self.intersect_normals(org[active], directions[active],
                                                      remaining)
            hit = prim >= 0
            facing = np.einsum("ij,ij->i", normals, directions[active])
            front = hit & (facing <= 0)
            result[active[front]] = travelled[active[front]] + t[front]
            back = hit & ~front
            # Step just past the back face and continue the same ray.
            adv = t[back] + self._step
            travelled[active[back]] += adv
            org[active[back]] += adv[:, None] * directions[active[back]]
            active = active[back]
        # Rays still crossing back faces after many steps: treat as blocked there.
        result[active] = travelled[active]
        return result

    def front_occluded(self, origins, directions, tmax) -> np.ndarray:
        return np.isfinite(self.front_distance(origins, directions, tmax))
