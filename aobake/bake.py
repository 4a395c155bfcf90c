"""The one place that wires the stages together.

scene -> sample points (a target) -> rays (a sampler) -> trace (a backend)
-> estimate (quantities) -> result (+ report)

Nothing here draws random numbers or depends on scheduling: each point's rays
are a pure function of (seed, point id, sample id), so results are
bit-identical for any thread count and chunk size.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from dataclasses import replace
from typing import Callable

from aobake import _native, adaptive
from aobake import report as reports
from aobake.config import BakeConfig
from aobake.errors import InputError
from aobake.results import BakeResult, TexelResult
from aobake.scene import load_scene
from aobake.targets import PointsTarget, TexelTarget, VertexTarget
from aobake.trace import DEFAULT_CHUNK_RAYS, Tracer, default_threads

log = logging.getLogger(__name__)


def _built_tracer(scene, config, rays: int):
    """(Tracer, seconds its construction took)."""
    clock = time.perf_counter()
    tracer = Tracer(scene, config, rays=rays)
    return tracer, time.perf_counter() - clock


def run(
    config: BakeConfig,
    mesh,
    target,
    *,
    threads: int | None = None,
    chunk_rays: int = DEFAULT_CHUNK_RAYS,
    progress: Callable[[int, int], None] | None = None,
):
    """Bake ``mesh`` (a path, trimesh mesh/scene or Scene) at ``target``'s points.

    Returns the target's result (BakeResult or TexelResult) with its report.
    ``threads`` and ``chunk_rays`` change the speed and memory, never the numbers.
    ``progress(done, total)`` is called as points are traced; if it has a ``phase(name)``
    attribute, that is called as each stage starts ("loading", "unwrapping", "rasterising",
    "tracing", ...), so a long unwrap shows too.
    """
    if getattr(target, "check", None):
        target.check(config)
    if threads is not None and (isinstance(threads, bool) or int(threads) != threads or threads < 1):
        raise InputError(f"threads must be a positive integer (or None: all cores), got {threads}")
    if int(chunk_rays) != chunk_rays or chunk_rays < 1:
        raise InputError(f"chunk_rays must be a positive integer, got {chunk_rays}")
    threads = threads or default_threads()
    reports.prefetch_versions()  # for the report; looked up while the bake runs
    phase = getattr(progress, "phase", None) or (lambda name: None)
    timings: dict = {}
    start = clock = time.perf_counter()
    phase("loading")
    scene = load_scene(mesh, config.normals, config.fix_normals)
    timings["load_s"] = time.perf_counter() - clock

    warnings: list = []
    # The backend's acceleration structure is built on a thread while the target finds its
    # points (a lightmap's unwrap, in a child process, and rasterisation): neither needs
    # the other, and the build (the bunny: ~0.1 s) no longer waits for the loading's end.
    Tracer.check(scene)  # its errors first, not after the target's work
    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="aobake-tracer")
    try:
        building = pool.submit(_native.carried(_built_tracer), scene, config,
                               target.rays_per_point(config))
        plan = target.sample(scene, config, threads, timings, warnings, phase)
        tracer, timings["tracer_s"] = building.result()
    finally:  # an error or interrupt in sample() does not wait for the build
        pool.shutdown(wait=False, cancel_futures=True)
    if config.keep_distances:
        _check_kept(len(plan.points), tracer.samples.rays)
    phase("tracing")
    clock = time.perf_counter()
    if config.tolerance is None:
        values, rays = tracer.estimate(plan.points, plan.normals, plan.ids, threads, chunk_rays,
                                       progress, sizes=plan.sizes)
        adaptive_summary = None
    else:
        values, rays, adaptive_summary = adaptive.estimate(
            tracer, plan.points, plan.normals, plan.ids, threads, chunk_rays, progress,
            plan.sizes)
    timings["trace_s"] = time.perf_counter() - clock
    done = target.finish(scene, config, plan, values, rays, timings, warnings)
    wall = time.perf_counter() - start

    report = reports.build(target.name, scene, tracer, config, points=done.points, rays=done.rays,
                           values=done.values, wall=wall, threads=threads,
                           chunk_rays=chunk_rays, warnings=warnings,
                           kernels={**tracer.kernel_stages(), **plan.kernels}, cast=done.cast)
    if done.rays_key != "rays_per_point":  # what a "point" is for this target
        report["parameters"][done.rays_key] = report["parameters"].pop("rays_per_point")
    report.update(done.report)
    # Every target's phases (a lightmap's add unwrap, raster, splat); writing is added by
    # aobake.write to the report file it writes.
    report["timings"] = {**timings, **report.get("timings", {}), "total_s": wall}
    if adaptive_summary is not None:
        report["tolerance"] = adaptive_summary
        log.info("tolerance %g: %d points met it, %d missed, %d capped at %d rays; %d rays "
                 "(a fixed count for the same worst case: %d)", config.tolerance,
                 adaptive_summary["points_met"], adaptive_summary["points_missed"],
                 adaptive_summary["points_capped"], config.max_rays,
                 adaptive_summary["rays_total"], adaptive_summary["fixed_budget_rays"])
    for message in warnings:
        log.warning(message)
    done.result.report = report
    if config.keep_distances:
        mapping = plan.state if plan.state is not None else np.arange(len(plan.points))
        done.result.kept = {"ray_distances": tracer.distances.reshape(len(plan.points), -1),
                            "ray_point": np.asarray(mapping, dtype=np.int32)}
    return done.result


#: the most bytes of kept ray distances a bake may hold (float32: 4 bytes per ray)
MAX_KEPT_BYTES = 4 << 30


def _check_kept(points: int, rays: int) -> None:
    """Refuse --keep-distances up front when the distances would not fit."""
    need = 4 * points * rays
    if need > MAX_KEPT_BYTES:
        raise InputError(f"keeping every ray's distance needs {need / 2**30:.1f} GiB "
                         f"({points} points x {rays} rays x 4 bytes); the limit is "
                         f"{MAX_KEPT_BYTES / 2**30:.0f} GiB: use fewer rays")


def _config(config: BakeConfig | None, options: dict) -> BakeConfig:
    if config is None:
        return BakeConfig(**options)
    return replace(config, **options) if options else config


def bake(mesh, config: BakeConfig | None = None, *, threads: int | None = None,
         chunk_rays: int = DEFAULT_CHUNK_RAYS,
         progress: Callable[[int, int], None] | None = None, **options) -> BakeResult:
    """Bake per-vertex quantities of ``mesh`` (a path, trimesh mesh/scene or Scene).

    ``options`` are BakeConfig fields (quantities=("ao", "obscurance"), rays=256,
    max_distance="10%", seed=0, ...).  Returns a :class:`BakeResult` whose arrays
    line up with ``result.positions`` (the scene's vertices, in file order).
    """
    return run(_config(config, options), mesh, VertexTarget(), threads=threads,
               chunk_rays=chunk_rays, progress=progress)


def bake_points(mesh, points, normals, config: BakeConfig | None = None, *, point_ids=None,
                threads: int | None = None, chunk_rays: int = DEFAULT_CHUNK_RAYS,
                progress: Callable[[int, int], None] | None = None, **options) -> BakeResult:
    """Evaluate arbitrary query points against ``mesh``: reference values where you need them.

    points : (n, 3) float, normals : (n, 3) float (normalised here; zero = not sampled),
    point_ids : (n,) int64 sample-stream ids (default 0..n-1).  The points are
    offset along their normals by the configured ray offset, like vertices.
    """
    target = PointsTarget(points, normals, point_ids)
    return run(_config(config, options), mesh, target, threads=threads, chunk_rays=chunk_rays,
               progress=progress)


def bake_texels(mesh, config: BakeConfig | None = None, *, threads: int | None = None,
                chunk_rays: int = DEFAULT_CHUNK_RAYS,
                progress: Callable[[int, int], None] | None = None, **options) -> TexelResult:
    """Bake a UV lightmap of ``mesh``.

    Lightmap options are BakeConfig fields too: resolution (N, (W, H) or 'WxH'),
    padding (texels of gutter dilation), texel_samples (surface positions per texel,
    stratified-jittered over the covered part of the texel; ``rays`` is per texel,
    split over them: each casts ceil(rays / texel_samples)), unwrap ('auto': own UVs
    when valid, else xatlas | 'always' | 'never'), bent_space ('object' | 'tangent').
    """
    return run(_config(config, options), mesh, TexelTarget(), threads=threads,
               chunk_rays=chunk_rays, progress=progress)
