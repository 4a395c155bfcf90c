"""Query-point target: reference values exactly where another implementation needs them."""

from __future__ import annotations

import numpy as np

from aobake.errors import InputError

from aobake.records import BakeResult, Finished, SamplePoints
from aobake.vectors import check_rows, normalize


class PointsTarget:
    """points : (n, 3) float, normals : (n, 3) float (normalised here; zero = not sampled),
    point_ids : (n,) int64 sample-stream ids (default 0..n-1).  The points are offset
    along their normals by the configured ray offset, like vertices."""

    name = "points"

    def __init__(self, points, normals, point_ids=None, point_sizes=None):
        points = check_rows("points", points)
        normals = check_rows("normals", normals, n=len(points))
        if not (np.isfinite(points).all() and np.isfinite(normals).all()):
            raise InputError("points and normals must be finite")
        self.points = points
        self.normals = normalize(normals)[0]
        ids = (np.arange(len(points), dtype=np.int64) if point_ids is None
               else np.asarray(point_ids, np.int64))
        if ids.shape != (len(points),):
            raise InputError(f"point_ids must be ({len(points)},), got {ids.shape}")
        self.ids = ids
        sizes = None
        if point_sizes is not None:
            sizes = np.asarray(point_sizes, dtype=np.float64)
            if sizes.shape != (len(points),) or not (np.isfinite(sizes).all() and
                                                     (sizes >= 0).all()):
                raise InputError(f"point_sizes must be ({len(points)},) finite and >= 0")
        self.sizes = sizes

    def rays_per_point(self, config) -> int:
        return config.rays

    def sample(self, scene, config, occluders, threads, timings, warnings,
               phase=None) -> SamplePoints:
        # A query point's own triangle is unknown: the scene's median triangle size stands in
        # (robust to a few stray triangles), for the offset rule of aobake.trace.point_offsets.
        sizes = self.sizes
        if sizes is None:
            sizes = np.full(len(self.points), float(np.sqrt(2.0 * np.median(scene.areas()))))
        return SamplePoints(self.points, self.normals, self.ids, sizes=sizes)

    def finish(self, scene, config, plan, estimates, timings, warnings) -> Finished:
        values, rays = estimates.fields, estimates.rays
        result = BakeResult(self.points, None, self.normals, rays, values)
        return Finished(result, values, rays, len(self.points))
