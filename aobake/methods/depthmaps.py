"""AO baked from depth maps (``--method depthmaps``): the GPU bake of the studios before ray
tracing was cheap (Whitehurst's "sphere of lights", 2003; GPU Gems ch. 17's precomputation).

K directions w_k over the sphere (``directions``: a spherical Fibonacci lattice, rotated as a
whole by --seed); per direction one orthographic depth map of the scene, looking along -w_k;
every point's visibility along w_k by a depth compare against its map (nearest texel, a
slope-scaled bias); the value

    A = sum_k V_k(p) W_k(p) / sum_k W_k(p),   W_k = max(0, n . w_k) (cosine weighting) or
                                              [n . w_k > 0] (uniform)

1 = every direction above the horizon open, 0 = every one blocked.  The normalisation by the
weights the point actually has makes an open point exactly 1 whatever K.  The bent normal is
the normalised sum_k V_k W_k w_k (the surface normal when nothing is open).  A point with a
zero normal, or with no direction above its horizon (K tiny), gets the no-information value
of ``aobake.quantities.ao`` (0.5; the normal as bent normal).

Cost O(K x (triangles + points)): each direction draws the mesh once, then one compute pass
reads each point's texel; the sums stay on the GPU and are read back once
(``depthmaps_gl``).  Not O(points x triangles): the maps are shared by every point.

Its error is deterministic, from three sources measured apart in docs/depthmaps.md:
- K: the directions are a quadrature of the hemisphere's integral.  Every point uses the same
  K directions, so the errors of nearby points are correlated (bands, not noise) and a mean
  over points does not average them away: no per-point stderr is claimed, ``error_bars`` is
  False, and ``aobake compare`` against the ray-traced truth is its measure;
- the map resolution N: an occluder is located to a texel (2 rho / N wide, rho the scene's
  bounding-sphere radius);
- the bias b (texels): a point is open along w_k when the map's height at its texel is at
  most its own plus b s / (n . w_k), s the texel width; occluders in a slab of height b s
  above the point's tangent plane are missed (contact shadows thin out), and b < 1/sqrt 2
  lets a flat surface shadow itself ("acne").

A depth map keeps the first surface from the light, not the first occluder from the point,
so a finite ``max_distance`` is refused (``capabilities``: depth peeling with L layers would
answer it at L times the cost, up to a depth complexity of L; not implemented).  The ground
plane is exact and free: a direction going down is blocked for every point above the plane.

The GL context runs in a child process (``aobake.child``), one per piece of at most
``CHILD_POINTS`` points (each piece draws the K maps again); the first child is started
ahead when the method is prepared.
"""

from __future__ import annotations

import importlib.util
import math
import weakref
from dataclasses import asdict

import numpy as np

from aobake import child, rng
from aobake.errors import AobakeError, InputError
from aobake.methods.base import refuse_ray_settings
from aobake.records import Estimates
from aobake.settings.depthmaps import DepthmapsOptions
from aobake.vectors import defined, normalize

#: the no-information value of ``aobake.quantities.ao`` (the midpoint: nothing is known)
NO_INFORMATION_AO = 0.5
#: the most points per child: each child draws the K maps again, so pieces are large; the
#: point buffers take 80 bytes a point (with bent normals), 80 MiB at this size
CHILD_POINTS = 1 << 20
#: the seed's stream for the lattice's rotation (``aobake.rng``)
STREAM_DIRECTIONS = 0x5EED_0026
#: the map's half width over the bounding sphere's radius: nothing of the scene touches the
#: map's edge or the depth range's ends
MARGIN = 1.0 + 2.0**-10
#: time limit of one child: base + per direction x (triangles, texels, points).  Measured on
#: llvmpipe on a loaded 2-core machine (docs/depthmaps.md): 0.4-1.4e-6 s per triangle,
#: ~2e-8 s per texel, ~1.5e-7 s per point, each per direction; the limit is 7-25x that,
#: plus 30 s (Python's start, the context, the upload: as the hemicube's child), so only a
#: hung driver reaches it (twice, with the retry).
TIMEOUT_BASE_S = 30.0
TIMEOUT_PER_TRIANGLE_S = 1e-5
TIMEOUT_PER_TEXEL_S = 3e-7
TIMEOUT_PER_POINT_S = 1e-6
#: width of the renderer description kept per point (``extras["depthmaps_renderer"]``)
_RENDERER_CHARS = 128


class DepthmapsError(AobakeError):
    """The OpenGL child could not render: no moderngl, no GL 4.3 context, a driver crash or
    hang.  The message says which and what to install."""


#: The GL child (imports ``depthmaps_gl``: numpy and moderngl, not the packages' __init__).
#: Read at call time, so a test can swap in a stand-in.
WORKER = child.worker("depthmaps", "aobake.methods.depthmaps_gl", "render",
                      warm_up="import moderngl\n")
PROBE = child.worker("depthmaps-probe", "aobake.methods.depthmaps_gl", "probe")

_INSTALL = ("--method depthmaps needs moderngl and an EGL driver with OpenGL 4.3 (compute "
            "shaders): pip install 'aobake[gl]' (and, on Debian, apt-get install libegl1 "
            "libegl-mesa0 libgbm1 libgl1-mesa-dri)")


def available(limit: float = 60.0) -> tuple[bool, str]:
    """(True, renderer) when a child can make a GL 4.3 context with compute shaders and
    float64, else (False, why): what the tests skip on."""
    if importlib.util.find_spec("moderngl") is None:
        return False, "moderngl is not installed (pip install 'aobake[gl]')"
    try:
        out = child.run(PROBE, {"none": np.zeros(0)}, limit, attempts=1)
    except child.Failed as exc:
        return False, f"no OpenGL 4.3 context with compute shaders: {exc.line}"
    except child.ChildError as exc:
        return False, f"no OpenGL 4.3 context: {exc}"
    return True, f"{out['renderer']} | {out['gl_version']}"


# ------------------------------------------------------------------ the directions

def fibonacci(k: int) -> np.ndarray:
    """(k, 3) float64 unit: the spherical Fibonacci lattice, z_i = 1 - (2 i + 1) / k (k
    strata of equal area in z, one point each) at azimuth 2 pi frac(i phi^-1) (the golden
    angle between neighbours, so no two strata line up)."""
    i = np.arange(k, dtype=np.float64)
    z = 1.0 - (2.0 * i + 1.0) / k
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    # frac(i / phi) from integers: i (phi - 1) mod 1 with phi - 1 = 1 / phi
    turn = np.mod(i * ((math.sqrt(5.0) - 1.0) / 2.0), 1.0)
    phi = 2.0 * math.pi * turn
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def rotation(seed: int) -> np.ndarray:
    """(3, 3) float64: a uniformly random rotation, a pure function of ``seed`` (Shoemake's
    unit quaternion from three uniforms of ``aobake.rng``, stream STREAM_DIRECTIONS)."""
    u = np.array([float(rng.hash_uniform(seed, STREAM_DIRECTIONS, np.zeros(1), d)[0])
                  for d in range(3)])
    a, b = math.sqrt(1.0 - u[0]), math.sqrt(u[0])
    x, y = a * math.sin(2 * math.pi * u[1]), a * math.cos(2 * math.pi * u[1])
    z, w = b * math.sin(2 * math.pi * u[2]), b * math.cos(2 * math.pi * u[2])
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def directions(k: int, seed: int) -> np.ndarray:
    """(k, 3) float64 unit: the K directions of a bake, the Fibonacci lattice rotated by the
    seed's rotation (every seed an equally good lattice; every point of a bake shares it)."""
    out, _ = normalize(fibonacci(int(k)) @ rotation(int(seed)).T)
    return out


def map_axes(w: np.ndarray) -> np.ndarray:
    """(k, 2, 3) float64: each direction's map axes (e1, e2), completing w to a right-handed
    frame (``aobake.warp.frames``)."""
    from aobake.warp import frames

    e1, e2 = frames(w)
    return np.stack([e1, e2], axis=1)


def map_sphere(local: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre (3,) float64, half width H) of every map, from the used vertices (v, 3) in the
    local frame: the bounding box's centre and MARGIN x the largest distance from it."""
    center = 0.5 * (local.min(axis=0) + local.max(axis=0))
    radius = float(np.sqrt(np.square(local - center).sum(axis=1).max()))
    return center, max(radius, 1e-30) * MARGIN


def traced(occluders, points: np.ndarray, normals: np.ndarray, w: np.ndarray,
           weighting: str = "cosine", sizes: np.ndarray | None = None,
           ray_offset: float | None = None) -> np.ndarray:
    """(n,) float64: the same K-direction estimate with exact visibility, each point's K rays
    traced from the ray-traced method's origins (``aobake.offsets.point_offsets``): what
    depthmaps converges to as N grows and b falls, so that the error of the directions alone
    and of the maps alone can be measured apart.  points, normals (n, 3) scene units, unit
    normals; w (K, 3) unit; sizes (n,) scene units | None; occluders ``aobake.occluders``."""
    from aobake.offsets import point_offsets
    from aobake.settings.rays import DEFAULT_RAY_OFFSET

    normals = np.asarray(normals, dtype=np.float64)
    local = occluders.to_local(points)
    offsets = point_offsets(local, None if sizes is None else sizes * occluders.scale,
                            DEFAULT_RAY_OFFSET if ray_offset is None else ray_offset)
    origins = (local + offsets[:, None] * normals).astype(np.float32)
    cos = normals @ w.T  # (n, K)
    weight = np.where(cos > 0, cos if weighting == "cosine" else 1.0, 0.0)
    open_ = np.zeros(len(points))
    for k in range(len(w)):
        live = weight[:, k] > 0
        if not live.any():
            continue
        d = np.broadcast_to(w[k].astype(np.float32), (int(live.sum()), 3))
        blocked, _ = occluders.trace("occluded", origins[live], np.ascontiguousarray(d),
                                     np.float32(np.inf))
        open_[live] += weight[live, k] * ~blocked
    total = weight.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(total > 0, open_ / total, NO_INFORMATION_AO)


# ------------------------------------------------------------------ the method

def local_frame(scene, occluders) -> tuple[np.ndarray, float]:
    """(center (3,) float64, scale) of the tracer's local frame: the occluders' when given
    (the bake's), else made as ``aobake.occluders.build`` makes it (the per-axis median of
    the vertices; a power of two that brings the scene within [-1, 1])."""
    if occluders is not None:
        return np.asarray(occluders.center, dtype=np.float64), float(occluders.scale)
    lo, hi = scene.bounds
    center = np.median(scene.vertices[np.unique(scene.faces)], axis=0)
    reach = float(np.maximum(np.abs(hi - center), np.abs(lo - center)).max())
    return center, 2.0 ** -math.frexp(reach)[1]


class DepthmapsMethod:
    """AO (and bent normals) from K shared depth maps drawn in an OpenGL child: one
    deterministic value per point, no rays, no stderr."""

    name = "depthmaps"
    casts_rays = False

    def __init__(self, vertices, faces, center, scale, options: DepthmapsOptions,
                 weighting: str, seed: int, quantities: tuple, ground):
        """vertices (v, 3) float32 local units ((world - center) * scale, scale a power of
        two), faces (f, 3) int64, ground (axis index, local height) | None."""
        self.vertices, self.faces = vertices, faces
        self.center, self.scale = center, scale
        self.options = options
        self.weighting, self.seed = weighting, int(seed)
        self.quantities = tuple(quantities)
        self.ground = ground
        used = np.zeros(len(vertices), dtype=bool)
        used[faces.ravel()] = True
        self.map_center, self.half = map_sphere(vertices[used].astype(np.float64))
        self.texel = 2.0 * self.half / options.depthmaps_resolution  # local units
        self.w = directions(options.depthmaps_directions, self.seed)
        self._close = None  # ends the GL child started ahead (``prepare``, ``close``)

    @classmethod
    def prepare(cls, scene, config, occluders, rays_per_point: int,
                compiled: bool | None = None, options: DepthmapsOptions | None = None
                ) -> "DepthmapsMethod":
        """Once per scene: the mesh in the local frame (the occluders' when given), the
        directions, the maps' sphere, and a GL child started ahead.  Reads
        ``config.quantities`` (ao, bent_normal), ``weighting``, ``seed``, ``ground_plane``
        and ``up_axis`` and the depthmaps section; refuses a finite ``max_distance``,
        ``backfaces = ignore`` and occluders beside the mesh (``--low-occludes``)."""
        wanted = tuple(config.quantities)
        other = [q for q in wanted if q not in ("ao", "bent_normal")]
        if other or not wanted:
            raise InputError(f"--method depthmaps estimates ao and bent_normal only, got "
                             f"quantities {', '.join(wanted)}")
        distance = config.max_distance
        if isinstance(distance, str) or math.isfinite(distance):
            raise InputError(f"--max-distance {distance}: --method depthmaps sees the whole "
                             "scene (a depth map keeps the first surface from the light, not "
                             "the first occluder from the point)")
        if getattr(config, "backfaces", "occlude") != "occlude":
            raise InputError("--backfaces ignore: --method depthmaps draws every face into "
                             "its maps (back faces occlude)")
        if getattr(scene, "extra_occluders", ()):
            raise InputError("--low-occludes: --method depthmaps draws the scene's own faces "
                             "only")
        refuse_ray_settings("depthmaps", config)
        if importlib.util.find_spec("moderngl") is None:
            raise DepthmapsError(_INSTALL)
        if options is None:
            options = DepthmapsOptions.of(config)
        faces = np.asarray(scene.faces, dtype=np.int64)
        occluding = getattr(scene, "occluding", None)
        if occluding is not None:
            faces = faces[np.asarray(occluding, dtype=bool)]
        if not len(faces):
            raise InputError(f"{scene.source}: no triangles for --method depthmaps to draw")
        center, scale = local_frame(scene, occluders)
        local = (np.asarray(scene.vertices, dtype=np.float64) - center) * scale
        unused = np.ones(len(local), dtype=bool)
        unused[faces.ravel()] = False
        local[unused] = 0.0  # as the occluders: a far-off unused vertex cannot overflow
        ground = None
        if config.ground_plane:
            from aobake.constants import AXES

            axis = AXES.index(config.up_axis)
            if occluders is not None and occluders.ground is not None:
                height = occluders.ground["height"]
            else:
                height = float(scene.bounds[0][axis])
            ground = (axis, (height - center[axis]) * scale)
        method = cls(local.astype(np.float32), faces, center, scale, options,
                     config.weighting, config.seed, wanted, ground)
        worker = WORKER
        ahead = child.prestart(worker)
        if ahead is not None:
            method._close = weakref.finalize(method, child.discard, worker, ahead)
        return method

    def close(self) -> None:
        """End the GL child started ahead for this method if no estimate took it; idempotent."""
        if self._close is not None:
            self._close()

    def _limit(self, n_points: int) -> float:
        n = self.options.depthmaps_resolution
        per = (TIMEOUT_PER_TRIANGLE_S * len(self.faces) + TIMEOUT_PER_TEXEL_S * n * n
               + TIMEOUT_PER_POINT_S * n_points)
        return TIMEOUT_BASE_S + self.options.depthmaps_directions * per

    def estimate(self, points, threads: int, chunk_rays: int, progress=None) -> Estimates:
        """points : ``SamplePoints`` (points (n, 3), normals (n, 3) unit, zero = no
        information) -> Estimates(fields {"ao": (n,) float64 in [0, 1], 1 = open;
        "bent_normal": (n, 3) float64 unit, with -q bent_normal}, rays None, extras
        {"depthmaps_weight": (n,) float64 the summed weight of the directions above the
        point's horizon (0: none, or not baked), "depthmaps_renderer": (n,) str the GL
        renderer that baked the point ('' where not baked)}).

        The points go to a GL child in pieces of at most CHILD_POINTS, one after another
        (each draws the K maps; llvmpipe's threads: ``threads``); a point's sums are its own
        (its own slot, in direction order), so its value does not depend on its piece.
        ``chunk_rays`` is not used."""
        p = np.asarray(points.points, dtype=np.float64)
        nrm = np.asarray(points.normals, dtype=np.float64)
        n = len(p)
        ao = np.full(n, NO_INFORMATION_AO)
        bent = nrm.copy()
        weight = np.zeros(n)
        renderer = np.full(n, "", dtype=f"<U{_RENDERER_CHARS}")
        index = np.flatnonzero(defined(nrm)) if n else np.zeros(0, dtype=np.int64)
        with_bent = "bent_normal" in self.quantities
        pieces = max(1, -(-len(index) // CHILD_POINTS))
        bounds = np.linspace(0, len(index), pieces + 1).astype(np.int64)
        done = 0
        for k in range(pieces if len(index) else 0):
            sel = index[bounds[k]:bounds[k + 1]]
            local = (p[sel] - self.center) * self.scale
            inside = np.zeros(len(sel), dtype=bool)
            if self.ground is not None:  # below the plane once lifted by the bias's height
                axis, height = self.ground
                lifted = local[:, axis] + self.options.depthmaps_bias * self.texel \
                    * nrm[sel, axis]
                inside = lifted < height
            out = self._run(self._inputs(local, nrm[sel], inside, threads, with_bent),
                            len(sel))
            total = out["total"]
            has = total > 0
            with np.errstate(invalid="ignore", divide="ignore"):
                ao[sel] = np.where(has, out["open"] / total, NO_INFORMATION_AO)
            weight[sel] = total
            if with_bent:
                unit, length = normalize(out["bent"])
                bent[sel] = np.where(length > 0, unit, nrm[sel])
            renderer[sel] = f"{out['renderer']} | {out['gl_version']}"[:_RENDERER_CHARS]
            done += len(sel)
            if progress is not None:
                progress(done, len(index))
        fields = {"ao": ao}
        if with_bent:
            fields["bent_normal"] = bent
        fields = {q: fields[q] for q in self.quantities}
        return Estimates(fields, None, {"depthmaps_weight": weight,
                                        "depthmaps_renderer": renderer})

    def _inputs(self, local, normals, inside, threads, with_bent: bool) -> dict:
        o = self.options
        ground_axis = -1 if self.ground is None else self.ground[0]
        return dict(vertices=self.vertices, faces=self.faces, center=self.map_center,
                    half=np.float64(self.half), resolution=o.depthmaps_resolution,
                    directions=self.w.astype(np.float32),
                    axes=map_axes(self.w).astype(np.float32),
                    points=np.asarray(local, dtype=np.float32),
                    normals=np.asarray(normals, dtype=np.float32), inside=inside,
                    bias=np.float64(o.depthmaps_bias * self.texel), weighting=self.weighting,
                    ground_axis=ground_axis, bent=with_bent, threads=max(1, int(threads)))

    def _run(self, inputs: dict, n_points: int) -> dict:
        """The GL child's outputs; its failures as DepthmapsError."""
        limit = self._limit(n_points)
        try:
            return child.run(WORKER, inputs, limit)
        except child.TimedOut:
            raise DepthmapsError(f"the OpenGL child did not draw {len(self.w)} depth maps of "
                                 f"{len(self.faces)} triangles for {n_points} points in "
                                 f"{limit:.0f} s, twice") from None
        except child.Crashed as exc:
            raise DepthmapsError(f"the OpenGL child {exc.how} drawing depth maps") from None
        except child.Failed as exc:
            raise DepthmapsError(f"the OpenGL child failed: {exc.line} ({_INSTALL})") from None

    def record(self, estimates: Estimates) -> dict:
        """The report's ``parameters``: every setting used, the texel and the bias's height
        in scene units, the maps' sphere, the renderer."""
        baked = estimates.extras["depthmaps_renderer"] != ""
        weight = estimates.extras["depthmaps_weight"]
        renderers = sorted(set(estimates.extras["depthmaps_renderer"][baked].tolist()))
        o = self.options
        parameters = {
            "method": self.name, **asdict(o),
            "weighting": self.weighting, "seed": self.seed,
            "directions_rule": "spherical Fibonacci lattice rotated by the seed (shared by "
                               "every point)",
            "map_radius": self.half / self.scale,
            "texel": self.texel / self.scale,
            "bias_height": o.depthmaps_bias * self.texel / self.scale,
            "bias_rule": "open when map height <= own height + bias_height / (n . w); "
                         "nearest texel",
            "ground_plane": self.ground is not None,
            "points_baked": int(np.count_nonzero(baked)),
            "points_without_directions": int(np.count_nonzero(baked & (weight <= 0))),
            "renderer": renderers[0] if len(renderers) == 1 else renderers or None,
            "error": "deterministic: directions (shared by every point: correlated across "
                     "points), map resolution and bias (docs/depthmaps.md); no stderr",
        }
        return {"parameters": parameters}

    def error_quantities(self) -> list:
        """None: an approximation has no error bar (its error is what ``aobake compare``
        measures against the ray-traced truth)."""
        return []

    def kernel_stages(self) -> dict:
        return {}
