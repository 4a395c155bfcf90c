"""Where a ray starts: the origin offset along the normal (one rule for every ray a bake
casts: first rays from sample points, bounce rays from hits)."""

from __future__ import annotations

import numpy as np

from aobake.constants import OFFSET_ULPS


def point_offsets(local: np.ndarray, sizes: np.ndarray | None, fraction: float) -> np.ndarray:
    """(n,) float64 origin offsets along the normal, in the tracer's local units.

    local : (n, 3) float64 points in the backend's frame (rebased, scaled by a power of two),
    sizes : (n,) float64 the size of each point's own triangles in the same units (None:
    unknown: the floor alone), fraction : ray_offset.  The offset is ``fraction * size``,
    at least OFFSET_ULPS float32 ulps of the point's largest local coordinate plus its
    triangle size: Embree's float32 hit distances carry the rounding of the triangle's
    vertex coordinates, which reach that far even where the point sits at the origin.
    """
    # Column by column: a max over the short last axis of (n, 3) is ~3x slower (exact either way).
    magnitude = np.maximum(np.maximum(np.abs(local[:, 0]), np.abs(local[:, 1])),
                           np.abs(local[:, 2]))
    if sizes is not None:
        magnitude = magnitude + sizes
    floor = OFFSET_ULPS * np.spacing(magnitude.astype(np.float32)).astype(np.float64)
    if sizes is None:
        return floor
    return np.maximum(floor, fraction * sizes)
