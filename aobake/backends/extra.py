"""An occluder whose hits count only on front faces and beyond a distance from the ray's origin.

A high-to-low bake's low mesh occluding its own bake (``--low-occludes``): every baked point
lies on the source, within the cage's reach of the low surface, and often just under it.
Its rays would leave through the low surface right there.  Two rules keep that surface from
shadowing the points it stands for: a hit counts only on a **front** face (the ray arrives
from outside the low mesh: a point under the low surface leaves it through a back face and
passes), and only **beyond** ``skip`` from the ray's origin (the low surface a point lies
just above, met by the rays that dip below its tangent plane where the two surfaces'
normals differ).  Everything farther and front-facing (another part, a separate plate)
occludes as any face does.
"""

from __future__ import annotations

import numpy as np


class FrontBeyond:
    """``backend`` (a ``TriangleBackend``) answering every query with front-face hits beyond
    ``skip`` (local units) of the ray's origin; queries as ``aobake.backends.base``."""

    name = "front_beyond"

    def __init__(self, backend, skip: float):
        self.backend, self.skip = backend, np.float32(skip)

    def front_distance(self, origins, directions, tmax) -> np.ndarray:
        """(n,) float32 distance of the nearest front-face hit beyond ``skip``; inf if none
        within tmax."""
        if self.skip == 0:
            return self.backend.front_distance(origins, directions, tmax)
        moved = (origins + self.skip * directions).astype(np.float32)
        rest = np.maximum(np.asarray(tmax, dtype=np.float32) - self.skip, np.float32(0))
        rest = np.broadcast_to(rest, (len(origins),)).astype(np.float32)
        t = self.backend.front_distance(moved, directions, rest)
        return np.where(np.isfinite(t), t + self.skip, np.float32(np.inf)).astype(np.float32)

    def front_occluded(self, origins, directions, tmax) -> np.ndarray:
        return np.isfinite(self.front_distance(origins, directions, tmax))

    distance = front_distance
    occluded = front_occluded
