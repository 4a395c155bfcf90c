"""The ray-traced method (``--method rays``): the reference every other method is scored by.

Its parts: samplers (``aobake.samplers``: u in [0,1)^2 per point), warps (``aobake.warp``:
u -> hemisphere direction and pdf), ray generation (``aobake.rays``), backends
(``aobake.backends``, through the scene's occluders), quantities
(``aobake.quantities``: estimate + stderr + interval), the tracer that drives them
over chunks on threads (``aobake.trace``), ``--tolerance``'s two stages
(``aobake.adaptive``) and ``refit`` (``aobake.refit``: kept distances re-estimated).
"""

from __future__ import annotations

import numpy as np

from aobake import adaptive
from aobake.errors import InputError
from aobake.offsets import OffsetFold, PointOffsets, offset_summary
from aobake.records import BlockSizes, Estimates
from aobake.trace import Tracer

#: the most bytes of kept ray distances a bake may hold (float32: 4 bytes per ray)
MAX_KEPT_BYTES = 4 << 30


class RaysMethod:
    """Cosine- (or uniformly-) weighted hemisphere rays per point, with honest error bars."""

    name = "rays"
    casts_rays = True

    def __init__(self, tracer: Tracer):
        self.tracer = tracer
        self.config = tracer.config

    @classmethod
    def prepare(cls, scene, config, occluders, rays_per_point: int,
                compiled: bool | None = None) -> "RaysMethod":
        """Once per scene: the sample set, ray generator and query, on ``occluders``.
        compiled : use the compiled kernels (None: as this thread's ``_native.kernels()``)."""
        return cls(Tracer(scene, config, occluders, rays=rays_per_point, compiled=compiled))

    @property
    def compiled(self) -> bool:
        return self.tracer.kernels is not None

    def check_points(self, n_points: int) -> None:
        """Refuse --keep-distances up front when the distances would not fit."""
        if not self.config.keep_distances:
            return
        rays = self.tracer.samples.rays
        need = 4 * n_points * rays
        if need > MAX_KEPT_BYTES:
            raise InputError(f"keeping every ray's distance needs {need / 2**30:.1f} GiB "
                             f"({n_points} points x {rays} rays x 4 bytes); the limit is "
                             f"{MAX_KEPT_BYTES / 2**30:.0f} GiB: use fewer rays")

    def estimate(self, points, threads: int, chunk_rays: int, progress=None) -> Estimates:
        """points : ``SamplePoints`` (points, normals, ids, sizes) -> Estimates (fields,
        rays (n,) int32, extras: ``ray_offset``, ``ray_distances``, with --tolerance
        ``final_rays`` and ``capped``)."""
        if self.config.tolerance is None:
            return self.tracer.estimate(points.points, points.normals, points.ids, threads,
                                        chunk_rays, progress, sizes=points.sizes)
        if isinstance(points.sizes, BlockSizes) and len(points.points):
            # a set's instances: an instance's stages at a time, nothing held for every point
            return adaptive.estimate_blocks(self.tracer, points, threads, chunk_rays, progress,
                                            self.folds(points))
        # (its stages index the sizes of the points each stage casts more rays for: the array)
        sizes = None if points.sizes is None else np.asarray(points.sizes, dtype=np.float64)
        return adaptive.estimate(self.tracer, points.points, points.normals, points.ids,
                                 threads, chunk_rays, progress, sizes)

    def folds(self, plan) -> dict:
        """The extras a split of ``plan`` (``SamplePoints``) folds as its parts land
        (``records.Merged``) rather than merging per point: where the plan's sizes are made a
        block at a time (``records.BlockSizes``: a set's instances), the ray offsets
        (``offsets.OffsetFold``: made again for the report, as an unsplit bake's are) and
        with --tolerance the final counts (``adaptive.Tally``: the report's counts)."""
        if not isinstance(plan.sizes, BlockSizes):
            return {}
        tracer = self.tracer

        def offsets(counted):
            return PointOffsets(plan.points, plan.normals, plan.sizes, tracer.center,
                                tracer.scale, self.config.ray_offset, counted)

        folds = {"ray_offset": OffsetFold(offsets)}
        if self.config.tolerance is not None:  # the final counts, into the report's tally
            tally = adaptive.Tally(tracer)
            folds.update(final_rays=tally, capped=tally)
        return folds

    def record(self, estimates: Estimates) -> dict:
        """The report's ``parameters`` (and ``tolerance``) from the merged estimates."""
        offsets = offset_summary(estimates.extras["ray_offset"], estimates.rays)
        record = {"parameters": {"method": self.name, **self.tracer.parameters(offsets)}}
        if self.config.tolerance is not None:
            record["tolerance"] = adaptive.summary(self.tracer, estimates)
        return record

    def error_quantities(self) -> list:
        """The quantities whose (value, stderr) the report's error summary covers."""
        return self.tracer.quantities

    def kernel_stages(self) -> dict:
        return self.tracer.kernel_stages()

    def kept(self, estimates: Estimates, mapping: np.ndarray) -> dict:
        """--keep-distances: the NPZ's ``ray_distances`` (p, R m) float32 and ``ray_point``
        (n,) int32 (the row of each result point)."""
        if "ray_distances" not in estimates.extras:
            return {}
        distances = estimates.extras["ray_distances"]
        return {"ray_distances": distances.reshape(len(distances), -1),
                "ray_point": np.asarray(mapping, dtype=np.int32)}
