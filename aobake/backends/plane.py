"""An infinite solid ground plane, intersected analytically (``--ground-plane``)."""

from __future__ import annotations

import numpy as np


class PlaneOccluder:
    """The plane ``x[axis] = height`` (rebased coordinates) bounding a solid half-space below it.

    Intersected analytically in float64 (no huge proxy quad, no precision loss).
    A ray whose origin is on or below the plane starts inside the ground and is
    occluded at distance 0.  It has no back faces: the front-face queries are the plain ones.
    """

    name = "ground_plane"

    def __init__(self, axis: int, height: float):
        self.axis, self.height = axis, float(height)

    def distance(self, origins, directions, tmax) -> np.ndarray:
        o = origins[:, self.axis].astype(np.float64)
        d = directions[:, self.axis].astype(np.float64)
        gap = o - self.height
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d < 0.0, gap / -d, np.inf)
        t = np.where(gap <= 0.0, 0.0, t)
        return np.where(t <= tmax, t, np.inf).astype(np.float32)

    def occluded(self, origins, directions, tmax) -> np.ndarray:
        return np.isfinite(self.distance(origins, directions, tmax))

    front_distance = distance
    front_occluded = occluded
