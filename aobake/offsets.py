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


class PointOffsets:
    """(n,) float64 the ray offset each point's rays started at (scene units; 0 where the
    point was not traced), made again a block of points at a time where read, not held:
    the ``ray_offset`` extra of a trace whose sizes are a ``records.BlockSizes``.

    points (n, 3) float64, normals (n, 3) float64 (zero rows: not traced), sizes : the
    ``BlockSizes``, center (3,) float64, scale float (a power of two), fraction : the ray
    offset setting: the tracer's own frame and rule (``Tracer.traced``), element by
    element, so each value is the one that point's rays used, the same bits."""

    dtype = np.dtype(np.float64)
    ndim = 1

    def __init__(self, points, normals, sizes, center, scale: float, fraction: float,
                 counted=None):
        """counted : the offsets' first selection pass (``select.TopCounts``), counted by the
        tracer as it used them, or None (:meth:`summary` then counts them itself)."""
        self.points, self.normals, self.sizes = points, normals, sizes
        self.center, self.scale, self.fraction = center, scale, fraction
        self.counted = counted
        self.shape = (len(points),)

    def __len__(self) -> int:
        return self.shape[0]

    def traced(self, k: int) -> np.ndarray:
        """(t,) float64 the offsets of block k's traced points, in point order."""
        from aobake.vectors import defined

        b0, b1 = int(self.sizes.bounds[k]), int(self.sizes.bounds[k + 1])
        valid = defined(self.normals[b0:b1])
        local = (self.points[b0:b1][valid] - self.center) * self.scale
        used = point_offsets(local, self.sizes.block(k)[valid] * self.scale, self.fraction)
        return used / self.scale  # (a power of two: exact, as the tracer divides)

    def blocks(self):
        """The traced points' offsets, a block at a time (``aobake.select``'s ``blocks``)."""
        for k in range(len(self.sizes.bounds) - 1):
            yield self.traced(k)

    def summary(self) -> tuple | None:
        """(min, median, max) over the traced points, np.min's, np.median's and np.max's
        bits (``aobake.select``); None when no point was traced."""
        from aobake import select

        values, n = select.order_statistics(
            self.blocks, lambda n: [0, n - 1] + ([n // 2] if n % 2 else [n // 2 - 1, n // 2]),
            first=self.counted)
        if n == 0:
            return None
        middle = float(np.median(np.array(values[2:], dtype=np.float64)))
        return values[0], middle, values[1]

    def __array__(self, dtype=None, copy=None):
        from aobake.vectors import defined

        out = np.zeros(len(self))
        for k in range(len(self.sizes.bounds) - 1):
            b0, b1 = int(self.sizes.bounds[k]), int(self.sizes.bounds[k + 1])
            out[b0:b1][defined(self.normals[b0:b1])] = self.traced(k)
        return out if dtype is None else out.astype(dtype)

    def __getitem__(self, key):
        return np.asarray(self)[key]


class OffsetFold:
    """The ``ray_offset`` extra of a split bake's parts (``records.Merged``'s fold) where the
    plan's sizes are made a block at a time: each part's offsets of its traced points
    (``rays > 0``) are counted into the selection's first pass (``select.TopCounts``) and
    let go, and the result is a :class:`PointOffsets` that makes them again where read
    (the same values: the tracer's rule on the same point and size), not an (n,) array.

    make : counted -> the :class:`PointOffsets` of the whole plan."""

    def __init__(self, make):
        from aobake import select

        self.make, self.counted = make, select.TopCounts()

    def add(self, start: int, stop: int, part) -> None:
        offsets = np.asarray(part.extras["ray_offset"], dtype=np.float64)
        self.counted.add(offsets[part.rays > 0])

    def result(self) -> PointOffsets:
        return self.make(self.counted)


def offset_summary(offsets, rays: np.ndarray) -> tuple | None:
    """(min, median, max) ray offset over the points that cast rays (``rays`` (n,) > 0) of
    ``offsets`` (n,) float64 or a :class:`PointOffsets`; None when none did."""
    summary = getattr(offsets, "summary", None)
    if summary is not None:
        return summary()
    traced = rays > 0
    if not traced.any():
        return None
    # (every point traced: the array itself, not a copy of it)
    used = offsets[slice(None) if traced.all() else traced]
    return float(used.min()), float(np.median(used)), float(used.max())
