"""The one place that wires the stages together.

scene -> sample points (targets) -> rays -> trace -> estimate -> result (+ report)

Nothing here draws random numbers or depends on scheduling: each point's rays
are a pure function of (seed, point id, sample id), so results are
bit-identical for any thread count and chunk size.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from aobake.backends.embree import EmbreeOccluder, PlaneOccluder
from aobake.config import AXES, BakeConfig
from aobake.estimators import estimate, no_information
from aobake.rays import KERNEL as RAY_KERNEL
from aobake.rays import RayGenerator
from aobake.samplers import sample_set
from aobake.scene import Scene, load_scene
from aobake.trace import default_threads, run_chunks

log = logging.getLogger(__name__)

#: rays per chunk handed to one ``run()``: Embree's 2-thread scaling flattens out from ~64k,
#: and larger chunks amortise the per-chunk numpy work (measured: 64k 6.8, 128k 7.3 Mrays/s).
DEFAULT_CHUNK_RAYS = 131072

#: conventions written into every output's metadata (``conventions(weighting)``).
CONVENTIONS = {
    "ao": "cosine-weighted visibility (1/pi) int V(w) cos dw: 1 = fully open, 0 = fully occluded",
    "max_distance": "a hit beyond the max distance is a miss",
    "obscurance": "(1/pi) int rho(L) cos dw with rho(L) = 1 - exp(-tau L); a miss counts rho = 1",
    "bent_normal": "normalised mean of the unoccluded sample directions; the surface normal if none",
    "bent_normal_stderr": "angular standard error of the bent normal in radians (delta method); "
                          "pi/2 when nothing escapes or there is no spread to measure",
    "stderr": "one standard error of the Monte-Carlo estimate",
}

#: what changes with ``--weighting uniform`` (libigl's and xNormal's convention)
_UNIFORM = {
    "ao": "uniform-weighted visibility (1/2pi) int V(w) dw (the open fraction of the "
          "hemisphere's solid angle): 1 = fully open, 0 = fully occluded",
    "obscurance": "(1/2pi) int rho(L) dw with rho(L) = 1 - exp(-tau L); a miss counts rho = 1",
    "bent_normal": "normalised uniform-measure mean of the unoccluded directions; the surface "
                   "normal if none",
}


def conventions(weighting: str = "cosine") -> dict:
    """The conventions of a bake with this weighting (cosine: CONVENTIONS)."""
    return {**CONVENTIONS, **(_UNIFORM if weighting == "uniform" else {})}


@dataclass
class BakeResult:
    """Per-point results; fields not asked for are None.

    positions : (n, 3) float64, faces : (f, 3) int64 | None (None for bake_points),
    normals : (n, 3) float64 (the normals the hemispheres were built on),
    ao, ao_stderr, obscurance, obscurance_stderr : (n,) float64,
    bent_normal : (n, 3) float64, bent_normal_stderr : (n,) float64 radians,
    rays : (n,) int32 rays cast per point,
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
    bent_normal_stderr: np.ndarray | None = None
    report: dict = field(default_factory=dict)

    def fields(self) -> dict:
        """Per-point arrays that were computed, keyed as in the NPZ/PLY/GLB outputs."""
        names = ("normals", "ao", "ao_stderr", "obscurance", "obscurance_stderr", "bent_normal",
                 "bent_normal_stderr", "rays")
        return {name: getattr(self, name) for name in names if getattr(self, name) is not None}


def _spread_bits(q: np.ndarray) -> np.ndarray:
    """(n,) uint32 of 10-bit ints -> their bits moved to positions 0, 3, 6, ... (uint32)."""
    q = q & np.uint32(0x3FF)
    for shift, mask in ((16, 0x030000FF), (8, 0x0300F00F), (4, 0x030C30C3), (2, 0x09249249)):
        q = (q | (q << np.uint32(shift))) & np.uint32(mask)
    return q


def morton_order(points: np.ndarray) -> np.ndarray:
    """(n,) int64 permutation sorting ``points`` (n, 3) along a Z-order curve (ray coherence).

    10 bits per axis; ties keep their input order.  Sorting (code << 32 | index) as
    one uint64 key is a stable argsort at the cost of a plain sort (~5x cheaper),
    which matters for lightmaps with millions of sample points.
    """
    n = len(points)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    code = np.zeros(n, dtype=np.uint32)
    for axis in range(3):  # column by column: a (n, 3) reduction over axis 0 is ~2x slower
        x = points[:, axis]
        lo, hi = x.min(), x.max()
        q = ((x - lo) * (1023.0 / (hi - lo) if hi > lo else 0.0)).astype(np.uint32)
        code |= _spread_bits(q) << np.uint32(axis)
    if n >= 2**32:  # pragma: no cover - beyond any texture budget
        return np.argsort(code, kind="stable")
    key = (code.astype(np.uint64) << np.uint64(32)) | np.arange(n, dtype=np.uint64)
    key.sort()
    return (key & np.uint64(0xFFFFFFFF)).astype(np.int64)


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
            "ray_kernel": RAY_KERNEL,
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
        occluded, distance = self._trace(rays.origins, rays.directions.reshape(-1, 3))
        shape = (k, groups, m)
        return estimate(self.config.quantities, rays.directions,
                        occluded.reshape(shape),
                        None if distance is None else distance.reshape(shape),
                        self.samples, self.tau, normals)

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
        out = no_information(self.config.quantities, normals)
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
    if "bent_normal_stderr" in values and sampled.any():
        se = values["bent_normal_stderr"][sampled]
        stats["bent_normal"] = {"stderr_mean_rad": float(se.mean()),
                                "stderr_p95_rad": float(np.percentile(se, 95))}
    return stats


def versions() -> dict:
    """Versions of aobake and the libraries whose behaviour decides the numbers."""
    return dict(_versions())


@functools.lru_cache(maxsize=1)
def _versions() -> dict:
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


def _report(kind, scene, tracer, config, n_points, rays, values, wall, threads, chunk_rays, warnings,
            cast=None):
    """The bake's report dict.  ``cast``: rays actually traced when points shared samples
    (default: the sum of ``rays``)."""
    cast = int(rays.astype(np.int64).sum()) if cast is None else int(cast)
    return {
        "aobake_report": 1,
        "target": kind,
        "config": config.to_dict(),
        "conventions": conventions(config.weighting),
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
    keys = np.ascontiguousarray(np.concatenate([scene.vertices, scene.vertex_normals], axis=1))
    # Rows as opaque 48-byte records: a 1-D unique is ~3x faster than unique(axis=0).
    rows = keys.view(np.dtype((np.void, keys.itemsize * keys.shape[1]))).ravel()
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    threads = threads or default_threads()
    values, rays = tracer.estimate(scene.vertices[first], scene.vertex_normals[first],
                                   first.astype(np.int64), threads, chunk_rays, progress)
    traced = int(rays.astype(np.int64).sum())  # before copying to vertices that share samples
    values = {name: array[inverse] for name, array in values.items()}
    rays = rays[inverse]
    wall = time.perf_counter() - start
    warnings = []
    unsampled = int(np.count_nonzero(rays == 0))
    if unsampled:
        warnings.append(f"{unsampled} vertices have no defined normal (unreferenced or only on "
                        "zero-area faces): not sampled, no-information values")
    report = _report("vertices", scene, tracer, config, len(scene.vertices), rays, values, wall,
                     threads, chunk_rays, warnings, cast=traced)
    for message in warnings:
        log.warning(message)
    return BakeResult(scene.vertices, scene.faces, scene.vertex_normals, rays,
                      report=report, **values)


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
    return BakeResult(points, None, normals, rays, report=report, **values)


# --------------------------------------------------------------------------- texels

#: default lightmap settings (what the CLI offers as defaults too)
DEFAULT_RESOLUTION = 1024
DEFAULT_PADDING = 8
DEFAULT_TEXEL_SAMPLES = 4
#: largest image side accepted
MAX_RESOLUTION = 16384
#: rough bytes held per texel sample (sample record, point, normal, estimates): for the memory check
_BYTES_PER_SAMPLE = 320


@dataclass
class Atlas:
    """The mesh a lightmap belongs to, split so each vertex has one atlas UV.

    positions : (m, 3) float64, normals : (m, 3) float64, faces : (f, 3) int64,
    uv : (m, 2) float64 atlas UVs (OBJ convention), base_uv : (m, 2) float64 |
    None the mesh's own UVs when a new atlas was made for a mesh that had them,
    source_vertex : (m,) int64 index of each vertex in the input scene,
    new : bool True when the atlas was made by xatlas (the mesh must be written out),
    materials : list | None the input's materials (see Scene.materials), kept in GLBs,
    face_material : (f,) int64 | None each face's material,
    charts : int | None number of charts of a new atlas.
    """

    positions: np.ndarray
    normals: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    base_uv: np.ndarray | None
    source_vertex: np.ndarray
    new: bool
    materials: list | None = None
    face_material: np.ndarray | None = None
    charts: int | None = None


@dataclass
class TexelResult:
    """A baked lightmap.

    channels : name -> (H, W) float32 images after gutter dilation ('ao', 'ao_stderr',
    'obscurance', 'obscurance_stderr', 'bent_normal.X/.Y/.Z', 'bent_normal_stderr', 'rays',
    'coverage'),
    row 0 = top of the image (v near 1), texel centres at u = (c + 0.5) / W,
    v = 1 - (r + 0.5) / H; covered : (H, W) bool texels with surface samples;
    atlas : Atlas; report : dict.
    """

    channels: dict
    covered: np.ndarray
    atlas: Atlas
    report: dict


def parse_resolution(value) -> tuple[int, int]:
    """'N' or 'WxH' (or an int / pair) -> (width, height); ValueError on nonsense."""
    if isinstance(value, str):
        parts = value.lower().split("x")
        if len(parts) not in (1, 2) or not all(p.strip().isdigit() for p in parts):
            raise ValueError(f"resolution must be N or WxH, got {value!r}")
        dims = [int(p) for p in parts]
    elif isinstance(value, (int, np.integer)):
        dims = [int(value)]
    else:
        dims = [int(v) for v in value]
    width, height = (dims[0], dims[0]) if len(dims) == 1 else dims
    if width < 1 or height < 1:
        raise ValueError(f"resolution must be at least 1x1, got {width}x{height}")
    return width, height


def check_texture_budget(width: int, height: int, texel_samples: int) -> int:
    """Refuse absurd sizes with the memory they would need; returns the estimate in bytes."""
    need = width * height * (texel_samples * _BYTES_PER_SAMPLE + 64)
    if max(width, height) > MAX_RESOLUTION:
        raise ValueError(f"resolution {width}x{height} is larger than {MAX_RESOLUTION} per side "
                         f"(it would need about {need / 2**30:.1f} GiB)")
    try:
        import os

        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        total = None
    if total and need > total // 2:
        raise ValueError(f"resolution {width}x{height} with {texel_samples} samples per texel needs "
                         f"about {need / 2**30:.1f} GiB, more than half of this machine's "
                         f"{total / 2**30:.1f} GiB")
    return need


def _split_corners(*corner_indices):
    """Unique combinations of per-corner indices.

    corner_indices : k arrays (f, 3) int64.  Returns (keys (m, k) int64, faces (f, 3) int64).
    """
    stacked = np.stack([c.reshape(-1) for c in corner_indices], axis=1)
    keys, inverse = np.unique(stacked, axis=0, return_inverse=True)
    return keys, inverse.reshape(-1, 3)


def _make_atlas(scene: Scene, unwrap: str, width: int, height: int, padding: int,
                texel_samples: int, seed: int, threads: int, warnings: list, timings: dict):
    """Choose the UVs to bake into (the mesh's own when valid, else a fresh xatlas atlas)
    and rasterise them.

    Returns (atlas, bake_uv (t, 2), bake_faces_uv (f, 3), uv_check or None, samples).
    Fills ``timings`` with uv_check_s, unwrap_s and raster_s.
    """
    from aobake.errors import InputError
    from aobake.targets.texels import check_uvs, rasterize
    from aobake.targets.unwrap import unwrap as xatlas_unwrap

    def raster(uv, faces_uv):
        clock = time.perf_counter()
        samples = rasterize(uv, faces_uv, width, height, texel_samples, seed, threads=threads)
        timings["raster_s"] = time.perf_counter() - clock
        return samples

    check = samples = None
    timings.update(uv_check_s=0.0, unwrap_s=0.0)
    if scene.faces_uv is not None:
        corners = scene.uv[scene.faces_uv]
        in_range = bool(np.all((corners >= 0.0) & (corners <= 1.0)))
        if unwrap == "never" or (unwrap == "auto" and in_range):
            # Likely baked as they are: the bake's own rasterisation gives the overlap
            # count too (texel-centre coverage), so the check costs no extra pass.
            samples = raster(scene.uv, scene.faces_uv)
            clock = time.perf_counter()
            check = check_uvs(scene.uv, scene.faces_uv, width, height, shared=samples.shared)
        else:  # not baked as they are: a texel-centre (K = 1) pass for the report is enough
            clock = time.perf_counter()
            check = check_uvs(scene.uv, scene.faces_uv, width, height)
        timings["uv_check_s"] = time.perf_counter() - clock
    if unwrap == "never":
        if scene.faces_uv is None:
            raise InputError(f"{scene.source}: mesh has no UVs and --no-unwrap was given")
        if not check.valid:
            warnings.append(f"{scene.source}: baking into the mesh's own UVs although {check.message}")
    use_own = scene.faces_uv is not None and unwrap != "always" and (check.valid or unwrap == "never")
    if use_own:
        keys, faces = _split_corners(scene.faces, scene.faces_uv)
        atlas = Atlas(scene.vertices[keys[:, 0]], scene.vertex_normals[keys[:, 0]], faces,
                      scene.uv[keys[:, 1]], None, keys[:, 0], new=False, materials=scene.materials,
                      face_material=scene.face_material)
        return atlas, scene.uv, scene.faces_uv, check, samples
    if scene.faces_uv is not None and unwrap == "auto":
        warnings.append(f"{scene.source}: the mesh's UVs cannot be baked ({check.message}); "
                        "made a new atlas with xatlas")
    if samples is not None:  # rasterising the rejected own UVs was part of checking them
        timings["uv_check_s"] += timings.pop("raster_s")
    if width != height:
        warnings.append(f"{scene.source}: xatlas packs square layouts: the new atlas uses the "
                        f"top-left {min(width, height)}x{min(width, height)} of the "
                        f"{width}x{height} image")
    clock = time.perf_counter()
    unwrapped = xatlas_unwrap(scene.vertices, scene.faces, (width, height), padding)
    timings["unwrap_s"] = time.perf_counter() - clock
    if not np.array_equal(unwrapped.vmapping[unwrapped.faces], scene.faces):
        raise RuntimeError("xatlas changed the face order")  # the texel->face mapping relies on it
    if scene.faces_uv is not None:
        keys, faces = _split_corners(unwrapped.faces, scene.faces_uv)
        base_uv = scene.uv[keys[:, 1]]
    else:
        keys, faces = _split_corners(unwrapped.faces)
        base_uv = None
    source = unwrapped.vmapping[keys[:, 0]]
    atlas = Atlas(scene.vertices[source], scene.vertex_normals[source], faces,
                  unwrapped.uv[keys[:, 0]], base_uv, source, new=True,
                  materials=scene.materials if base_uv is not None else None,
                  face_material=scene.face_material if base_uv is not None else None,
                  charts=unwrapped.charts)
    return atlas, unwrapped.uv, unwrapped.faces, check, raster(unwrapped.uv, unwrapped.faces)


def bake_texels(
    mesh,
    config: BakeConfig | None = None,
    *,
    resolution=DEFAULT_RESOLUTION,
    padding: int = DEFAULT_PADDING,
    texel_samples: int = DEFAULT_TEXEL_SAMPLES,
    unwrap: str = "auto",
    bent_space: str = "object",
    threads: int | None = None,
    chunk_rays: int = DEFAULT_CHUNK_RAYS,
    progress: Callable[[int, int], None] | None = None,
    **options,
) -> TexelResult:
    """Bake a UV lightmap of ``mesh``.

    resolution : N or (W, H) or 'WxH'; padding : texels of gutter dilation;
    texel_samples : surface positions per texel (stratified-jittered over the
    covered part of the texel); ``rays`` is per texel, split over its samples
    (each casts ceil(rays / texel_samples)); unwrap : 'auto' (own UVs when valid, else
    xatlas) | 'always' | 'never'; bent_space : 'object' | 'tangent'.
    ``options`` are BakeConfig fields, as for :func:`bake`.
    """
    from aobake.post import dilate
    from aobake.targets.texels import splat, surface_points

    config = _config(config, options)
    width, height = parse_resolution(resolution)
    if int(padding) != padding or padding < 0:
        raise ValueError(f"padding must be a non-negative integer, got {padding}")
    if int(texel_samples) != texel_samples or texel_samples < 1:
        raise ValueError(f"texel samples must be a positive integer, got {texel_samples}")
    if unwrap not in ("auto", "always", "never"):
        raise ValueError(f"unwrap must be auto, always or never, got {unwrap!r}")
    if bent_space not in ("object", "tangent"):
        raise ValueError(f"bent space must be object or tangent, got {bent_space!r}")
    check_texture_budget(width, height, texel_samples)
    timings = {}
    start = clock = time.perf_counter()
    scene = load_scene(mesh, config.normals)
    # --rays is per texel: each of its K surface samples casts ceil(rays / K).
    from dataclasses import replace

    tracer = Tracer(scene, replace(config, rays=-(-config.rays // int(texel_samples))))
    timings["load_s"] = time.perf_counter() - clock

    warnings: list = []
    phases: dict = {}
    atlas, bake_uv, bake_faces_uv, check, samples = _make_atlas(
        scene, unwrap, width, height, padding, texel_samples, config.seed,
        threads or default_threads(), warnings, phases)
    timings["uv_check_s"] = phases["uv_check_s"]
    timings["unwrap_s"] = phases["unwrap_s"]
    clock = time.perf_counter()
    points, normals, _ = surface_points(scene.vertices, scene.vertex_normals, scene.faces, samples)
    # Rasterising the UVs baked into (a rejected own-UV pass is in uv_check_s) + surface points.
    timings["rasterize_s"] = phases["raster_s"] + time.perf_counter() - clock

    clock = time.perf_counter()
    # Point ids: position in the (texel, sample, face)-sorted sample list, a pure
    # function of the inputs, so texels are reproducible for any threads/chunks.
    ids = np.arange(len(points), dtype=np.int64)
    values, rays = tracer.estimate(points, normals, ids, threads or default_threads(),
                                   chunk_rays, progress)
    timings["trace_s"] = time.perf_counter() - clock

    clock = time.perf_counter()
    traced = rays > 0  # samples on zero-area faces have no normal: left out of the texel means
    sub = samples if traced.all() else _subset(samples, traced)
    count = np.bincount(sub.texel, minlength=width * height).reshape(height, width)
    covered = count > 0
    channels = {}
    for name in ("ao", "obscurance"):
        if name in values:
            channels[name] = splat(sub, values[name][traced])[..., 0]
            # Texel value = mean of its s sample estimates: stderr sqrt(sum se^2) / s.
            var = splat(sub, values[name + "_stderr"][traced] ** 2)[..., 0]
            channels[name + "_stderr"] = np.sqrt(var / np.maximum(count, 1))
    if "bent_normal" in values:
        bent = values["bent_normal"][traced]
        if bent_space == "tangent":
            bent = _to_tangent(scene, bake_uv, bake_faces_uv, sub, normals[traced], bent)
        mean = splat(sub, bent)
        length = np.linalg.norm(mean, axis=-1, keepdims=True)
        mean = np.where(length > 0, mean / np.where(length > 0, length, 1), 0.0)
        for axis, label in enumerate("XYZ"):
            channels[f"bent_normal.{label}"] = mean[..., axis]
        # Angle error of the mean of s sample directions, as for AO: sqrt(sum se^2) / s.
        var = splat(sub, values["bent_normal_stderr"][traced] ** 2)[..., 0]
        channels["bent_normal_stderr"] = np.sqrt(var / np.maximum(count, 1))
    rays_img = np.bincount(sub.texel, weights=rays[traced].astype(np.float64),
                           minlength=width * height).reshape(height, width)
    names = list(channels)
    if names:
        stack = np.stack([channels[n] for n in names], axis=-1)
        stack, filled = dilate(stack, covered, padding)
        for i, name in enumerate(names):
            channels[name] = stack[..., i]
    else:  # pragma: no cover - config always asks for something
        filled = covered
    channels["rays"] = rays_img
    channels["coverage"] = samples.coverage.astype(np.float64) * covered
    channels = {name: np.asarray(image, dtype=np.float32) for name, image in channels.items()}
    timings["splat_dilate_s"] = time.perf_counter() - clock

    wall = time.perf_counter() - start
    shared = int(np.count_nonzero(samples.shared >= 2))
    if shared:
        warnings.append(f"{scene.source}: {shared} texels are shared by overlapping or mirrored "
                        "UV shells; their values average the surfaces that share them")
    report = _report("texels", scene, tracer, config, len(points), rays, values, wall,
                     threads or default_threads(), chunk_rays, warnings)
    report["parameters"]["rays_per_texel_sample"] = report["parameters"].pop("rays_per_point")
    report["texture"] = _texture_stats(channels, covered, filled, shared, width, height,
                                       padding, texel_samples, atlas, check, bent_space)
    report["timings"] = timings
    for message in warnings:
        log.warning(message)
    return TexelResult(channels, covered, atlas, report)


def _subset(samples, keep: np.ndarray):
    from dataclasses import replace

    return replace(samples, texel=samples.texel[keep], face=samples.face[keep],
                   bary=samples.bary[keep], sample=samples.sample[keep],
                   is_fallback=samples.is_fallback[keep])


def _to_tangent(scene, uv, faces_uv, samples, normals, bent):
    """Bent normals (s, 3) -> tangent space of the bake UVs (MikkTSpace-style frames)."""
    from aobake.tangents import to_tangent_space, vertex_tangents

    keys, faces = _split_corners(scene.faces, faces_uv)
    tangents = vertex_tangents(scene.vertices[keys[:, 0]], scene.vertex_normals[keys[:, 0]],
                               uv[keys[:, 1]], faces)
    corner = tangents[faces[samples.face]]  # (s, 3, 4)
    t = np.einsum("sc,scd->sd", samples.bary, corner[..., :3])
    w = np.where(np.einsum("sc,sc->s", samples.bary, corner[..., 3]) < 0, -1.0, 1.0)
    return to_tangent_space(bent, normals, np.concatenate([t, w[:, None]], axis=1))


def _texture_stats(channels, covered, filled, shared, width, height, padding, k, atlas, check,
                   bent_space):
    stats = {
        "width": width,
        "height": height,
        "padding": padding,
        "texel_samples": k,
        "texels_covered": int(covered.sum()),
        "texels_padded": int(np.count_nonzero(filled & ~covered)),
        "texels_shared": shared,
        "atlas": "xatlas" if atlas.new else "mesh UVs",
        "charts": atlas.charts,
        "uv_check": None if check is None else {
            "valid": check.valid, "out_of_range_faces": check.out_of_range_faces,
            "overlapping_texels": check.overlapping_texels, "mirrored_faces": check.mirrored_faces,
            "message": check.message},
        "bent_space": bent_space,
        "convention": "row 0 is the top of the image (v = 1); texel (r, c) centre at "
                      "u = (c + 0.5) / W, v = 1 - (r + 0.5) / H",
    }
    for name in ("ao", "obscurance"):
        if name in channels and covered.any():
            se = channels[name + "_stderr"][covered]
            stats[name + "_stderr"] = {"mean": float(se.mean()), "p50": float(np.median(se)),
                                       "p95": float(np.percentile(se, 95)), "max": float(se.max())}
    return stats
