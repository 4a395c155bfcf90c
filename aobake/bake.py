"""The one place that wires the stages together.

scene -> sample points (targets) -> rays -> trace -> estimate -> result (+ report)

Nothing here draws random numbers or depends on scheduling: each point's rays
are a pure function of (seed, point id, sample id), so results are
bit-identical for any thread count and chunk size.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from aobake.backends.embree import EmbreeOccluder, PlaneOccluder
from aobake.config import AXES, BakeConfig
from aobake.estimators import estimate, no_information
from aobake.rays import RayGenerator
from aobake.samplers import sample_set
from aobake.scene import Scene, load_scene
from aobake.trace import default_threads, run_chunks
from aobake.warp import WEIGHTINGS

log = logging.getLogger(__name__)

#: rays per chunk handed to one ``run()``: Embree's 2-thread scaling flattens out from ~64k.
DEFAULT_CHUNK_RAYS = 65536

#: conventions written into every output's metadata.
CONVENTIONS = {
    "ao": "cosine-weighted visibility (1/pi) int V(w) cos dw: 1 = fully open, 0 = fully occluded",
    "max_distance": "a hit beyond the max distance is a miss",
    "obscurance": "(1/pi) int rho(L) cos dw with rho(L) = 1 - exp(-tau L); a miss counts rho = 1",
    "bent_normal": "normalised mean of the unoccluded sample directions; the surface normal if none",
    "stderr": "one standard error of the Monte-Carlo estimate",
}


@dataclass
class BakeResult:
    """Per-point results; fields not asked for are None.

    positions : (n, 3) float64, faces : (f, 3) int64 | None (None for bake_points),
    normals : (n, 3) float64 (the normals the hemispheres were built on),
    ao, ao_stderr, obscurance, obscurance_stderr : (n,) float64,
    bent_normal : (n, 3) float64, rays : (n,) int32 rays cast per point,
    report : dict (configuration, parameters used, statistics, versions).
    """

    positions: np.ndarray
    faces: np.ndarray | None
    normals: np.ndarray
    rays: np.ndarray
    ao: np.ndarray | None = None
    ao_stderr: np.ndarray | None = None
    obscurance: np.ndarray | None = None
    obscurance_stderr: np.ndarray | None = None
    bent_normal: np.ndarray | None = None
    report: dict = field(default_factory=dict)

    def fields(self) -> dict:
        """Per-point arrays that were computed, keyed as in the NPZ/PLY/GLB outputs."""
        names = ("normals", "ao", "ao_stderr", "obscurance", "obscurance_stderr", "bent_normal", "rays")
        return {name: getattr(self, name) for name in names if getattr(self, name) is not None}


def morton_order(points: np.ndarray) -> np.ndarray:
    """(n,) int64 permutation sorting ``points`` (n, 3) along a Z-order curve (ray coherence)."""
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    lo, hi = points.min(axis=0), points.max(axis=0)
    q = ((points - lo) / np.where(hi > lo, hi - lo, 1.0) * 1023).astype(np.uint64)
    code = np.zeros(len(points), dtype=np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable")


class Tracer:
    """A scene prepared for tracing under one configuration (the resolved parameters live here)."""

    def __init__(self, scene: Scene, config: BakeConfig):
        self.scene, self.config = scene, config
        diagonal = scene.diagonal
        if not math.isfinite(diagonal) or diagonal <= 0:
            raise ValueError(f"{scene.source}: scene has zero extent")
        self.diagonal = diagonal
        lo, hi = scene.bounds
        # Rebase on the bbox centre before the float32 cast (far-from-origin scenes).
        self.center = 0.5 * (lo + hi)
        self.offset = config.ray_offset * diagonal
        self.max_distance = config.resolve_max_distance(diagonal)
        self.tau = config.resolve_tau(diagonal)
        self.samples = sample_set(config.sampler, config.rays, config.seed)
        self.generator = RayGenerator(self.samples, config.weighting, config.seed)
        self.max_weight = WEIGHTINGS[config.weighting][2]
        self.need_distance = "obscurance" in config.quantities
        self.occluders = [EmbreeOccluder(scene.vertices, scene.faces, scene.face_normals,
                                         self.center, step=self.offset)]
        if config.ground_plane:
            axis = AXES.index(config.up_axis)
            self.ground_height = float(lo[axis])
            self.occluders.append(PlaneOccluder(axis, self.ground_height - self.center[axis]))
        self.query = ("front_" if config.backfaces == "ignore" else "") + (
            "distance" if self.need_distance else "occluded")

    def parameters(self) -> dict:
        """Every parameter actually used, in scene units, for the report."""
        params = {
            "max_distance": self.max_distance,
            "tau": self.tau,
            "ray_offset": self.offset,
            "rays_per_point": self.samples.rays,
            "replicates": self.samples.groups,
            "stderr_method": "per-ray variance (iid)" if self.samples.iid
            else f"spread of {self.samples.groups} randomised replicates",
            "query": self.query,
            "rebase_center": self.center.tolist(),
            "diagonal": self.diagonal,
        }
        if self.config.ground_plane:
            params["ground_plane"] = {"axis": self.config.up_axis, "height": self.ground_height}
        return params

    def _trace(self, origins: np.ndarray, directions: np.ndarray):
        """origins/directions (n, 3) float32 -> (occluded (n,) bool, distance (n,) float32 | None)."""
        tmax = np.float32(min(self.max_distance, 3.0e38))
        if self.need_distance:
            distance = None
            for occluder in self.occluders:
                d = getattr(occluder, self.query)(origins, directions, tmax)
                distance = d if distance is None else np.minimum(distance, d)
            return np.isfinite(distance), distance
        occluded = None
        for occluder in self.occluders:
            o = getattr(occluder, self.query)(origins, directions, tmax)
            occluded = o if occluded is None else occluded | o
        return occluded, None

    def estimate_chunk(self, points: np.ndarray, normals: np.ndarray, ids: np.ndarray) -> dict:
        """points (k, 3) float64, normals (k, 3) float64 unit, ids (k,) int64 -> estimates dict."""
        origins = points + self.offset * normals - self.center
        rays = self.generator.rays(origins, normals, ids)
        k, groups, m, _ = rays.directions.shape
        flat_dirs = rays.directions.reshape(-1, 3)
        flat_orgs = np.repeat(rays.origins, groups * m, axis=0)
        occluded, distance = self._trace(flat_orgs, flat_dirs)
        shape = (k, groups, m)
        return estimate(self.config.quantities, rays.directions, rays.weight,
                        occluded.reshape(shape),
                        None if distance is None else distance.reshape(shape),
                        self.samples, self.tau, self.max_weight, normals)

    def estimate(
        self,
        points: np.ndarray,
        normals: np.ndarray,
        ids: np.ndarray,
        threads: int | None = None,
        chunk_rays: int = DEFAULT_CHUNK_RAYS,
        progress: Callable[[int, int], None] | None = None,
    ) -> tuple[dict, np.ndarray]:
        """Estimates for all points (n, 3) with normals (n, 3) and ids (n,) int64.

        Points whose normal is zero are not traced (0 rays, no-information estimate).
        Returns (dict of (n,) / (n, 3) float64 arrays, rays (n,) int32).
        """
        n = len(points)
        normals = np.asarray(normals, dtype=np.float64)
        valid = np.flatnonzero(np.linalg.norm(normals, axis=1) > 0.5)
        order = valid[morton_order(points[valid])]
        per_chunk = max(1, int(chunk_rays) // self.samples.rays)
        n_chunks = -(-len(order) // per_chunk)
        out = no_information(self.config.quantities, normals, self.max_weight)
        rays = np.zeros(n, dtype=np.int32)
        rays[valid] = self.samples.rays

        def work(i):
            sel = order[i * per_chunk:(i + 1) * per_chunk]
            return sel, self.estimate_chunk(points[sel], normals[sel], ids[sel])

        def land(i, result):
            sel, values = result
            for name, array in values.items():
                out[name][sel] = array

        done = [0]

        def tick(i):
            done[0] += min(per_chunk, len(order) - i * per_chunk)
            if progress:
                progress(done[0], len(order))

        run_chunks(n_chunks, work, land, threads or default_threads(), tick)
        return out, rays


def _summary(values: dict, rays: np.ndarray) -> dict:
    """Mean and 95th-percentile standard error per quantity over sampled points."""
    sampled = rays > 0
    stats = {}
    for name in ("ao", "obscurance"):
        if name in values and sampled.any():
            stats[name] = {
                "mean": float(values[name][sampled].mean()),
                "stderr_mean": float(values[name + "_stderr"][sampled].mean()),
                "stderr_p95": float(np.percentile(values[name + "_stderr"][sampled], 95)),
            }
    return stats


def versions() -> dict:
    """Versions of aobake and the libraries whose behaviour decides the numbers."""
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in ("aobake", "embreex", "trimesh", "numpy"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "unknown"
    return out


def _config(config: BakeConfig | None, options: dict) -> BakeConfig:
    if config is None:
        return BakeConfig(**options)
    if options:
        from dataclasses import replace

        return replace(config, **options)
    return config


def _report(kind, scene, tracer, config, n_points, rays, values, wall, threads, chunk_rays, warnings):
    cast = int(rays.astype(np.int64).sum())
    return {
        "aobake_report": 1,
        "target": kind,
        "config": config.to_dict(),
        "conventions": CONVENTIONS,
        "scene": scene.stats(),
        "parameters": tracer.parameters(),
        "points": int(n_points),
        "points_sampled": int(np.count_nonzero(rays)),
        "rays_cast": cast,
        "wall_time_s": wall,
        "rays_per_second": cast / wall if wall > 0 else None,
        "threads": threads,
        "chunk_rays": int(chunk_rays),
        "error": _summary(values, rays),
        "warnings": list(scene.warnings) + warnings,
        "versions": versions(),
    }


def bake(
    mesh,
    config: BakeConfig | None = None,
    *,
    threads: int | None = None,
    chunk_rays: int = DEFAULT_CHUNK_RAYS,
    progress: Callable[[int, int], None] | None = None,
    **options,
) -> BakeResult:
    """Bake per-vertex quantities of ``mesh`` (a path, trimesh mesh/scene or Scene).

    ``options`` are BakeConfig fields (quantities=("ao", "obscurance"), rays=256,
    max_distance="10%", seed=0, ...).  Returns a :class:`BakeResult` whose arrays
    line up with ``result.positions`` (the scene's vertices, in file order).
    """
    config = _config(config, options)
    start = time.perf_counter()
    scene = load_scene(mesh, config.normals)
    tracer = Tracer(scene, config)
    # Vertices that share position and normal get the same point id, hence the same
    # samples and identical values (no noise seam where a file splits vertices at UV seams).
    keys = np.concatenate([scene.vertices, scene.vertex_normals], axis=1)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    threads = threads or default_threads()
    values, rays = tracer.estimate(scene.vertices[first], scene.vertex_normals[first],
                                   first.astype(np.int64), threads, chunk_rays, progress)
    values = {name: array[inverse] for name, array in values.items()}
    rays = rays[inverse]
    wall = time.perf_counter() - start
    warnings = []
    unsampled = int(np.count_nonzero(rays == 0))
    if unsampled:
        warnings.append(f"{unsampled} vertices have no defined normal (unreferenced or only on "
                        "zero-area faces): not sampled, no-information values")
    report = _report("vertices", scene, tracer, config, len(scene.vertices), rays, values, wall,
                     threads, chunk_rays, warnings)
    for message in warnings:
        log.warning(message)
    return BakeResult(scene.vertices, scene.faces, scene.vertex_normals, rays,
                      report=report, **_named(values))


def bake_points(
    mesh,
    points,
    normals,
    config: BakeConfig | None = None,
    *,
    point_ids=None,
    threads: int | None = None,
    chunk_rays: int = DEFAULT_CHUNK_RAYS,
    progress: Callable[[int, int], None] | None = None,
    **options,
) -> BakeResult:
    """Evaluate arbitrary query points against ``mesh``: reference values where you need them.

    points : (n, 3) float, normals : (n, 3) float (normalised here; zero = not sampled),
    point_ids : (n,) int64 sample-stream ids (default 0..n-1).  The points are
    offset along their normals by the configured ray offset, like vertices.
    """
    config = _config(config, options)
    start = time.perf_counter()
    scene = load_scene(mesh, config.normals)
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (n, 3), got {points.shape}")
    if normals.shape != points.shape:
        raise ValueError(f"normals must be {points.shape}, got {normals.shape}")
    if not (np.isfinite(points).all() and np.isfinite(normals).all()):
        raise ValueError("points and normals must be finite")
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.where(length > 0, normals / np.where(length > 0, length, 1.0), 0.0)
    ids = np.arange(len(points), dtype=np.int64) if point_ids is None else np.asarray(point_ids, np.int64)
    if ids.shape != (len(points),):
        raise ValueError(f"point_ids must be ({len(points)},), got {ids.shape}")
    tracer = Tracer(scene, config)
    threads = threads or default_threads()
    values, rays = tracer.estimate(points, normals, ids, threads, chunk_rays, progress)
    wall = time.perf_counter() - start
    report = _report("points", scene, tracer, config, len(points), rays, values, wall,
                     threads, chunk_rays, [])
    return BakeResult(points, None, normals, rays, report=report, **_named(values))


def _named(values: dict) -> dict:
    return {name: array for name, array in values.items()}
