"""The public bake functions and the one place that wires the stages together (``run``).

scene -> sample points (a target) -> rays (a sampler) -> trace (a backend)
-> estimate (quantities) -> result (+ report)

Nothing here draws random numbers or depends on scheduling: each point's rays
are a pure function of (seed, point id, sample id), so results are
bit-identical for any thread count and chunk size.
"""

from __future__ import annotations

import logging
import math
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from dataclasses import replace
from typing import Callable

from aobake import _native, capabilities, groups
from aobake import occluders as occluder_stage
from aobake import report as reports
from aobake.backends.cutout import cutout_faces
from aobake.settings import BakeConfig
from aobake.errors import InputError
from aobake.executors import EXECUTORS, Job
from aobake.executors.base import release
from aobake.methods import METHODS
from aobake.records import BakeResult, TexelResult, ViewResult
from aobake.scene import Scene, load_scene, release_freed_memory
from aobake.targets import TARGETS
from aobake.trace import DEFAULT_CHUNK_RAYS, default_threads

log = logging.getLogger(__name__)


#: targets whose bake does not hold the scene's face normals and areas while it traces
#: (their points are the scene's vertices, or given ones: ``Scene.lean``)
LEAN_TARGETS = ("vertices", "points")


def _timed(function, *args):
    """(function(*args), seconds it took)."""
    clock = time.perf_counter()
    value = function(*args)
    return value, time.perf_counter() - clock


def run(
    config: BakeConfig,
    mesh,
    target,
    *,
    threads: int | None = None,
    chunk_rays: int = DEFAULT_CHUNK_RAYS,
    progress: Callable[[int, int], None] | None = None,
    method: str | None = None,
    executor: str = "threads",
    workers: int | None = None,
    chunk_points: int | None = None,
    scheduler: str | None = None,
    given=(),
):
    """Bake ``mesh`` (a path, trimesh mesh/scene or Scene) at ``target``'s points.

    The one composition root: scene -> occluders -> sample points (the target) -> the
    method's estimates (on the executor) -> the target's result -> the report.

    Returns the target's result (BakeResult or TexelResult) with its report.
    ``threads``, ``chunk_rays``, ``executor`` (``EXECUTORS``: threads | processes | dask),
    ``workers``, ``chunk_points`` and ``scheduler`` (dask: an existing scheduler's address)
    change the speed and memory, never the numbers.  ``given``: the names of the settings
    the caller gave one by one (``capabilities.check``).
    ``method``: ``METHODS`` key; None: the one the config implies (``file`` with
    ``ao_from``, else ``rays``: ``capabilities.implied_method``; ``ao_from`` with another
    method named is a UsageError, as on the command line).  ``progress(done, total)`` is
    called as points are estimated; if it has a ``phase(name)`` attribute, that is called
    as each stage starts ("loading", "unwrapping", "rasterising", "tracing", ...), so a
    long unwrap shows too.
    """
    method = capabilities.implied_method(method, config)
    if method not in METHODS:
        raise InputError(f"unknown method {method!r}; choose from {', '.join(sorted(METHODS))}")
    # what the method and target declare they can do, checked before any file is read
    capabilities.check(method, target.name, config, given)
    if getattr(target, "check", None):
        target.check(config)
    if getattr(target, "uses_method", None):  # a target whose sampling depends on the method
        target.uses_method(method)
    if executor not in EXECUTORS:
        raise InputError(f"unknown executor {executor!r}; choose from "
                         f"{', '.join(sorted(EXECUTORS))}")
    for name, value in (("threads", threads), ("workers", workers),
                        ("chunk_points", chunk_points)):
        if value is not None and not _positive_integer(value):
            raise InputError(f"{name} must be a positive integer (or None), got {value!r}")
    if scheduler is not None and executor != "dask":
        raise InputError("scheduler goes with executor='dask'")
    if isinstance(chunk_rays, bool) or int(chunk_rays) != chunk_rays or chunk_rays < 1:
        raise InputError(f"chunk_rays must be a positive integer, got {chunk_rays}")
    threads = threads or default_threads()
    reports.prefetch_versions()  # for the report; looked up while the bake runs
    phase = getattr(progress, "phase", None) or (lambda name: None)
    timings: dict = {}
    start = clock = time.perf_counter()
    phase("loading")
    # the lightmap's UV set is read where the map is baked into the mesh's own UVs
    scene = load_scene(mesh, config.normals, config.fix_normals,
                       config.uv_set if getattr(target, "name", None) == "texels" else 0,
                       bake=config.bake)
    timings["load_s"] = time.perf_counter() - clock

    warnings: list = []
    selection = groups.Selection(config.exclude, config.receive_only, config.occluder_only)
    if selection:  # what occludes what: faces left out, or only casting, or only baked
        applied = groups.apply(scene, selection)
        scene, target = applied.scene, groups.GroupedTarget(target, applied)
    if config.alpha_cutout:
        if cutout_faces(scene) is None:
            warnings.append(f"{scene.source}: --alpha-cutout: no material has alphaMode MASK "
                            "(with UVs): nothing is cut out")
    extend = getattr(getattr(target, "inner", target), "extend_scene", None)
    if extend is not None:  # occluders beside the scene's faces (a high-to-low low mesh)
        scene = extend(scene, config, timings)
    occluder_stage.check(scene)  # its errors first, not after the target's work
    if target.name in LEAN_TARGETS and not isinstance(mesh, Scene):
        # A per-vertex bake reads the face normals and areas only to make the vertex
        # normals (done at the load), the points' sizes and the report's area: the scene this
        # bake loaded lets them go (32 bytes a triangle while it traces), and whatever reads
        # them later gets them remade, the same bits (Scene.lean).  A Scene the caller
        # passed keeps them: it still holds them itself.
        scene = scene.lean()
        release_freed_memory()  # their pages, from the allocator's heap
    rays_per_point = target.rays_per_point(config)
    compiled = _native.kernels() is not None  # decided once, on this thread
    # The occluders come first: a target may cast primary rays through them (the camera).
    # Their acceleration structure and the method are built on a thread while the target
    # finds its points (a lightmap's unwrap, in a child process, and rasterisation):
    # neither needs the other unless the target asks for the occluders.
    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="aobake-occluders")
    prepared = None
    try:
        building = pool.submit(_native.carried(_timed), occluder_stage.build, scene, config)
        prepared = pool.submit(_native.carried(_timed), _prepare, building, scene, config,
                               method, rays_per_point, compiled)

        def occluders():
            return building.result()[0]

        plan = target.sample(scene, config, occluders, threads, timings, warnings, phase)
        timings["occluders_s"] = building.result()[1]
        the_method, timings["method_s"] = prepared.result()
    except BaseException:
        # a method prepared while the target failed holds what it started (the hemicube's
        # GL child): end it now, not when the method is collected
        if prepared is not None and prepared.done() and not prepared.cancelled() \
                and prepared.exception() is None:
            release(prepared.result()[0])
        raise
    finally:  # an error or interrupt in sample() does not wait for the build
        pool.shutdown(wait=False, cancel_futures=True)
    if hasattr(the_method, "check_points"):
        the_method.check_points(len(plan.points))
    # the sampling's temporaries (a per-vertex bake's row hashes and sort, the areas summed
    # per vertex: ~25 MiB at 1M vertices) stay resident in the allocator's heap under the
    # whole trace unless handed back
    release_freed_memory()
    phase("tracing")
    clock = time.perf_counter()
    job = Job(scene, config, method, rays_per_point, compiled,
              key=f"{id(scene):x}-{time.monotonic_ns():x}")
    extra = {} if scheduler is None else {"scheduler": scheduler}
    try:
        runner = EXECUTORS[executor](workers=workers, chunk_points=chunk_points, **extra)
        estimates = runner.estimate(job, the_method, plan, threads, chunk_rays, progress)
    finally:  # the executor releases it as it returns; a failure before that does not
        release(the_method)
    timings["trace_s"] = time.perf_counter() - clock
    done = target.finish(scene, config, plan, estimates, timings, warnings)
    # what the rest reads of the points (their ids and sizes, 16 bytes a point, are let go
    # before the record and the report make their passes over every point)
    plan_kernels, n_points = plan.kernels, len(plan.points)
    mapping = plan.state if config.keep_distances else None
    del plan
    release_freed_memory()  # (their pages too, and the trace's)
    if not hasattr(getattr(target, "inner", target), "receivers"):
        # (a high-to-low target says it of its low mesh itself)
        dark = groups.dark_warning(estimates, scene.source)
        if dark:
            warnings.append(dark)
    wall = time.perf_counter() - start

    record = the_method.record(estimates)
    report = reports.build(target.name, scene, config, record, the_method, done, wall=wall,
                           threads=threads, chunk_rays=chunk_rays, warnings=warnings,
                           kernels={**the_method.kernel_stages(), **plan_kernels},
                           executor={"name": executor, "workers": workers,
                                     "chunk_points": chunk_points, **extra})
    report.update(done.report)
    # Every target's phases (a lightmap's add unwrap, raster, splat); writing is added by
    # aobake.write to the report file it writes.
    report["timings"] = {**timings, **report.get("timings", {}), "total_s": wall}
    summary = record.get("tolerance")
    if summary is not None:
        report["tolerance"] = summary
        log.info("tolerance %g: %d points met it, %d missed, %d capped at %d rays; %d rays "
                 "(a fixed count for the same worst case: %d)", config.tolerance,
                 summary["points_met"], summary["points_missed"], summary["points_capped"],
                 config.max_rays, summary["rays_total"], summary["fixed_budget_rays"])
    for message in warnings:
        log.warning(message)
    done.result.report = report
    if config.keep_distances and hasattr(the_method, "kept"):
        mapping = mapping if mapping is not None else np.arange(n_points)
        done.result.kept = the_method.kept(estimates, mapping)
    return done.result


def _positive_integer(value) -> bool:
    try:
        return not isinstance(value, bool) and int(value) == value and value >= 1
    except (TypeError, ValueError, OverflowError):
        return False


def _prepare(building, scene, config, method: str, rays_per_point: int, compiled: bool):
    """The method prepared on the occluders (waits for them)."""
    built = building.result()[0]
    return METHODS[method].prepare(scene, config, built, rays_per_point, compiled=compiled)


def _projected(config: BakeConfig, mesh, per: str):
    """(scene, target) of a bake of ``mesh`` per ``per`` ('vertices' | 'texels'): with
    ``config.source`` a high-to-low bake, the source the scene and ``mesh`` the low mesh
    (as ``aobake MESH --from HIGH``); else ``mesh`` and the plain target."""
    if config.source is None:
        return mesh, TARGETS[per]()
    return config.source, projected_target(config, per, mesh)


def projected_target(config: BakeConfig, per: str, low):
    """The high-to-low target storing values per ``per`` ("texels" | "vertices") of the
    low mesh ``low``, shaped by the config's cage settings (``config.source`` is the scene
    it bakes)."""
    return TARGETS[f"projected_{per}"](low, cage_offset=config.cage_offset, cage=config.cage,
                                       low_occludes=config.low_occludes)


def _config(config: BakeConfig | None, options: dict) -> BakeConfig:
    if config is None:
        return BakeConfig(**options)
    return replace(config, **options) if options else config


#: run()'s keywords that change where and how fast, never the numbers (or the method);
#: ``given`` carries the names of the settings a caller gave as keywords
RUN_OPTIONS = ("method", "executor", "workers", "chunk_points", "scheduler", "given")


def _split(options: dict) -> tuple[dict, dict]:
    """(BakeConfig fields, run() keywords) of a bake function's keyword arguments; the
    fields' names go to run() as ``given`` (a setting only another target reads, given as a
    keyword, is refused: ``capabilities.check_settings``)."""
    run_kw = {k: options.pop(k) for k in RUN_OPTIONS if k in options}
    run_kw["given"] = tuple(run_kw.get("given", ())) + tuple(options)
    return options, run_kw


def bake(mesh, config: BakeConfig | None = None, *, threads: int | None = None,
         chunk_rays: int = DEFAULT_CHUNK_RAYS,
         progress: Callable[[int, int], None] | None = None, **options) -> BakeResult:
    """Bake per-vertex quantities of ``mesh`` (a path, trimesh mesh/scene or Scene).

    ``options`` are BakeConfig fields (quantities=("ao", "obscurance"), rays=256,
    max_distance="10%", seed=0, ...).  Returns a :class:`BakeResult` whose arrays
    line up with ``result.positions`` (the scene's vertices, in file order).
    """
    options, run_kw = _split(options)
    config = _config(config, options)
    scene, target = _projected(config, mesh, "vertices")
    return run(config, scene, target, threads=threads,
               chunk_rays=chunk_rays, progress=progress, **run_kw)


def bake_grouped(mesh, target, config: BakeConfig | None = None, *, exclude=(),
                 receive_only=(), occluder_only=(), **run_kw):
    """Bake ``target`` on ``mesh`` with a selection of its faces (``aobake.groups``; ``run``'s
    keywords in ``run_kw``; BakeConfig fields in ``config``): the patterns go into the
    config (its report then reproduces the bake) and ``run`` applies them."""
    options, keywords = _split(dict(run_kw))
    for name in ("threads", "chunk_rays", "progress"):
        if name in options:
            keywords[name] = options.pop(name)
    # the patterns as given: the setting's own check reads a string or a list of them
    config = _config(config, dict(options, exclude=exclude, receive_only=receive_only,
                                  occluder_only=occluder_only))
    return run(config, mesh, target, **keywords)


def bake_points(mesh, points, normals, config: BakeConfig | None = None, *, point_ids=None,
                point_sizes=None,
                threads: int | None = None, chunk_rays: int = DEFAULT_CHUNK_RAYS,
                progress: Callable[[int, int], None] | None = None, **options) -> BakeResult:
    """Evaluate arbitrary query points against ``mesh``: reference values where you need them.

    points : (n, 3) float, normals : (n, 3) float (normalised here; zero = not sampled),
    point_ids : (n,) int64 sample-stream ids (default 0..n-1), point_sizes : (n,) float64
    the size of each point's own triangles (sqrt of twice the area; default: the scene's
    median triangle size).  The points are offset along their normals by the configured
    ray offset, like vertices.
    """
    options, run_kw = _split(options)
    config = _config(config, options)
    target = TARGETS["points"](points, normals, point_ids, point_sizes)
    return run(config, mesh, target, threads=threads, chunk_rays=chunk_rays,
               progress=progress, **run_kw)


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
    options, run_kw = _split(options)
    config = _config(config, options)
    scene, target = _projected(config, mesh, "texels")
    return run(config, scene, target, threads=threads,
               chunk_rays=chunk_rays, progress=progress, **run_kw)


def bake_projected(low, source, config: BakeConfig | None = None, *, per: str = "texels",
                   cage_offset=None, cage=None, low_occludes: bool = False,
                   threads: int | None = None, progress=None, **options):
    """Bake the AO of ``source`` (the high-poly mesh: a path, trimesh mesh or Scene) onto
    ``low``'s UVs (``per="texels"``) or vertices (``per="vertices"``) through a cage
    (``cage_offset`` or ``cage``, see ``aobake.targets.projected``); ``low_occludes``: the
    low mesh occludes too.  ``options`` are BakeConfig fields and ``run``'s keywords
    (method, executor, ...).  ``bake(low, source=HIGH)`` is the same bake from settings."""
    if per not in ("texels", "vertices"):
        raise InputError(f"per must be one of ['texels', 'vertices'], got {per!r}")
    options, run_kw = _split(options)
    target = TARGETS[f"projected_{per}"](low, cage_offset=cage_offset, cage=cage,
                                         low_occludes=low_occludes)
    return run(_config(config, options), source, target, threads=threads,
               progress=progress, **run_kw)


#: what ``bake_view_truths`` adds to a view: the unbounded truth's channels under these names
UNBOUNDED = {"ao": "ao_unbounded", "ao_stderr": "ao_unbounded_stderr",
             "ao_ci_low": "ao_unbounded_ci_low", "ao_ci_high": "ao_unbounded_ci_high",
             "rays": "rays_unbounded"}


def bake_view_truths(mesh, config: BakeConfig | None = None, *, camera=None, look=None,
                     gltf=None, size=(960, 540), fov: float = 40.0, threads: int | None = None,
                     chunk_rays: int = DEFAULT_CHUNK_RAYS, **options) -> ViewResult:
    """The two ray-traced truths a screen-space method is scored against, in one view
    (``aobake view --truths``; docs/screen-space.md): ``ao`` (and its stderr, interval and
    rays) bounded at the screen methods' radius R (``ssao_radius``: what they can see), and
    the same channels of the unbounded AO under the names of ``UNBOUNDED`` (``ao_unbounded``,
    ...), with the G-buffer and the camera of one ``bake_view``.

    Both passes use the same seed, so each pixel's rays are the same directions: the bounded
    value counts the hits nearer than R of the very rays whose every hit the unbounded one
    counts (``ao >= ao_unbounded`` at every pixel, exactly); pixels stay independent of each
    other.  The bounded channels equal ``bake_view(..., max_distance=R)``'s and the unbounded
    ones ``bake_view(..., max_distance=inf)``'s, bit for bit.  Only ``ao`` is baked by the
    ray-tracing method; the report's ``truths`` section says which channel is which.
    """
    options, run_kw = _split(options)
    config = _config(config, options)
    method = capabilities.implied_method(run_kw.get("method"), config)
    if method != "rays":
        raise InputError(f"the truths are ray traced: they go with --method rays, not {method}")
    if tuple(config.quantities) != ("ao",):
        raise InputError(f"the truths are AO: quantities must be ('ao',), got "
                         f"{tuple(config.quantities)}")
    view = dict(gltf=gltf, size=size, fov=fov, threads=threads, chunk_rays=chunk_rays, **run_kw)
    clock = time.perf_counter()
    scene = load_scene(mesh, config.normals, config.fix_normals)  # loaded once for both
    load_s = time.perf_counter() - clock
    bounded = bake_view(scene, replace(config, max_distance=config.ssao_radius), camera=camera,
                        look=look, **view)
    unbounded = bake_view(scene, replace(config, max_distance=math.inf), camera=bounded.camera,
                          **view)
    channels = dict(bounded.channels)
    for name, renamed in UNBOUNDED.items():
        if name in unbounded.channels:
            channels[renamed] = unbounded.channels[name]
    report = dict(bounded.report)
    radius = bounded.report["parameters"]["max_distance"]
    report["truths"] = {
        "bounded": {"max_distance": radius, "ssao_radius": config.ssao_radius,
                    "channels": [n for n in UNBOUNDED if n in bounded.channels],
                    "rays_cast": bounded.report["rays_cast"]},
        "unbounded": {"max_distance": "inf",
                      "channels": [UNBOUNDED[n] for n in UNBOUNDED if n in unbounded.channels],
                      "rays_cast": unbounded.report["rays_cast"],
                      "wall_time_s": unbounded.report["wall_time_s"]},
        "streams": "one seed: each pixel's rays are the same directions in both passes"}
    report["timings"] = {**report["timings"], "load_s": load_s}
    report["wall_time_s"] = (load_s + bounded.report["wall_time_s"]
                             + unbounded.report["wall_time_s"])
    log.info("view truths: bounded at R = %.6g and unbounded, %d + %d rays", radius,
             bounded.report["rays_cast"], unbounded.report["rays_cast"])
    return ViewResult(channels, bounded.covered, report, camera=bounded.camera)


def bake_view(mesh, config: BakeConfig | None = None, *, camera=None, look=None, gltf=None,
              size=(960, 540), fov: float = 40.0, threads: int | None = None,
              chunk_rays: int = DEFAULT_CHUNK_RAYS,
              progress: Callable[[int, int], None] | None = None, **options) -> ViewResult:
    """A camera view of ``mesh``: the G-buffer and the method's values at every pixel's first
    hit (``aobake view``; see ``aobake.targets.view``).

    camera : ``aobake.camera.Camera``, or look : dict(look_from, look_at, up, fov), or gltf :
    (path, camera name | None); none of them: a three-quarter view framing the scene.
    size : (width, height) pixels; fov : vertical degrees (default camera and look-at).
    """
    options, run_kw = _split(options)
    target = TARGETS["view"](camera, look=look, gltf=gltf, size=size, fov=fov)
    return run(_config(config, options), mesh, target, threads=threads, chunk_rays=chunk_rays,
               progress=progress, **run_kw)
