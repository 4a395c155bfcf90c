"""Rasterised hemicube AO (``--method hemicube``): each point's hemisphere drawn by a real
rasteriser (OpenGL, through moderngl on a headless EGL context: Mesa's llvmpipe on a CPU
machine, a GPU where there is one).

Per point, the mesh is drawn onto a hemicube: the full front face (looking along the normal)
at R x R pixels and the upper halves of the four side faces at R x R/2, R =
``hemicube_resolution`` (``hemicube_cells`` lays them out).  The eye is the ray-traced
method's ray origin (the point moved along its normal by the ray offset of
``aobake.trace.point_offsets``), the near plane lies at that offset, the far limit is a
sphere of radius max distance (fragments beyond it are discarded; there is no far plane),
and back faces occlude as rays do (``backfaces = ignore`` culls them).  A pixel is blocked
when the ray through its centre meets a triangle within the max distance; AO is the summed
weight of the open pixels:

    A = sum_open w_i / sum_all w_i,   w_i = the pixel's form factor (cosine weighting) or
    its solid angle (uniform), each integrated exactly over the pixel;

1 = every pixel open, 0 = every pixel blocked; a point with a zero normal gets the
no-information value of ``aobake.quantities.ao`` (0.5).

The value is deterministic: its error is the discretisation's (a pixel is all open or all
blocked by its centre), which shrinks about as 1/R (docs/hemicube.md measures it), not a standard
error; no rays are reported.  A pixel whose spherical cap (``hemicube_cells.angular_radius``)
does not meet the occluders' silhouette is exact, so |A - truth| is at most the summed weight
of the pixels the silhouette crosses, which the tests derive for closed-form scenes.

The GL context runs in a child process (``aobake.child``: time limit, retry, a crash becomes
an error here), one context per child; the bake's points go to children in pieces of at
most ``CHILD_POINTS`` (the first child is started ahead, when the method is prepared).
Cost: llvmpipe's geometry work is single-threaded and grows with the triangles drawn,
little with R up to 128.  A mesh of 512 triangles or more is drawn culled
(``hemicube_gl``: per point and face only the runs of triangle clusters that may reach that
face, ~9% of the 5 x triangles on the bunny; the same pixels bit for bit), a smaller one
whole (every triangle five times per point).  docs/hemicube.md measures both: the bunny's
cost per point falls ~5x.  A child starts in ~0.5 s.  Several children run at once on
``threads`` cores, and ``--executor processes`` gives each worker its own.
"""

from __future__ import annotations

import importlib.util
import math
import weakref
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict

import numpy as np

from aobake import child
from aobake.constants import OFFSET_ULPS
from aobake.errors import AobakeError, InputError
from aobake.records import Estimates
from aobake.methods.base import refuse_ray_settings
# the settings record and its limits live apart (read by every config), re-exported here
from aobake.settings.hemicube import (DEFAULT_RESOLUTION, MAX_RESOLUTION,  # noqa: F401
                                             HemicubeOptions)
from aobake.vectors import defined

#: the no-information value of ``aobake.quantities.ao`` (the midpoint: nothing is known)
NO_INFORMATION_AO = 0.5
#: the most points per child process (each child starts Python and makes its own context:
#: ~0.4 s, the work of ~40 points on a 37k-triangle mesh)
CHILD_POINTS = 2048
#: the fewest points that earn a child of their own when a bake has several threads
MIN_CHILD_POINTS = 64
#: time limit of one child: base + per (point x triangle) + per (point x pixel).  Measured
#: on llvmpipe on a loaded 2-core machine: ~4e-7 s per point-triangle (the five faces) and
#: ~6e-8 s per point-pixel (docs/hemicube.md); the limit is 10-15x that plus a base that
#: covers starting Python, making the EGL context (0.4-0.6 s here) and uploading the mesh,
#: 50x over, so only a hung driver reaches it.  The base was 2 minutes: with the retry, a
#: hung driver cost 4 minutes before its error even for 3 points (issue 35); now 1 minute.
TIMEOUT_BASE_S = 30.0
TIMEOUT_PER_POINT_TRIANGLE_S = 4e-6
TIMEOUT_PER_POINT_PIXEL_S = 1e-6
#: width of the renderer description kept per point (``extras["hemicube_renderer"]``)
_RENDERER_CHARS = 128


class HemicubeError(AobakeError):
    """The OpenGL child could not render: no moderngl, no EGL context, a driver crash or
    hang.  The message says which and what to install."""



#: The GL child: it imports ``hemicube_gl`` (numpy, moderngl, ``hemicube_cells``) and not
#: the packages' __init__; a prestarted one has moderngl imported.  Read at call time, so a
#: test can swap in a stand-in.
WORKER = child.worker("hemicube", "aobake.methods.hemicube_gl", "render",
                      warm_up="import moderngl\n")
PROBE = child.worker("hemicube-probe", "aobake.methods.hemicube_gl", "probe")


def available(limit: float = 60.0) -> tuple[bool, str]:
    """(True, renderer) when a child can make an EGL context, else (False, why): what the
    tests skip on and ``.ci/run`` insists on."""
    if importlib.util.find_spec("moderngl") is None:
        return False, "moderngl is not installed (pip install 'aobake[gl]')"
    try:
        out = child.run(PROBE, {"none": np.zeros(0)}, limit, attempts=1)
    except child.ChildError as exc:
        return False, f"no EGL context: {exc}"
    return True, f"{out['renderer']} | {out['gl_version']}"


def _local_frame(scene, occluders):
    """(center (3,), scale) of the tracer's local frame: the occluders' when given (the
    bake's), else made the same way (``aobake.occluders.build``)."""
    if occluders is not None:
        return np.asarray(occluders.center, dtype=np.float64), float(occluders.scale)
    lo, hi = scene.bounds
    center = np.median(scene.vertices[np.unique(scene.faces)], axis=0)
    reach = float(np.maximum(np.abs(hi - center), np.abs(lo - center)).max())
    return center, 2.0 ** -math.frexp(reach)[1]


class HemicubeMethod:
    """Hemicube AO rasterised in an OpenGL child: one deterministic value per point
    (``ao``), no rays, no stderr.  ``options`` (a :class:`HemicubeOptions`) is a class-level
    default until the config carries its own."""

    name = "hemicube"
    casts_rays = False
    options = HemicubeOptions()

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, center: np.ndarray,
                 scale: float, options: HemicubeOptions, weighting: str, max_distance: float,
                 backfaces: str, ray_offset: float):
        """vertices (v, 3) float32 in the local frame ((world - center) * scale, scale a
        power of two), faces (f, 3) int64, max_distance scene units (inf: none), ray_offset
        the fraction of a point's triangle size its eye is lifted by."""
        self.vertices, self.faces = vertices, faces
        self.center, self.scale = center, scale
        self.options = options
        self.resolution = options.hemicube_resolution
        self.weighting, self.backfaces = weighting, backfaces
        self.max_distance = float(max_distance)
        self.ray_offset = float(ray_offset)
        self._close = None  # ends the GL child started ahead (``prepare``, ``close``)

    @classmethod
    def prepare(cls, scene, config, occluders, rays_per_point: int,
                compiled: bool | None = None, options: HemicubeOptions | None = None
                ) -> "HemicubeMethod":
        """Once per scene: the mesh in the local frame, and a GL child started ahead (its
        imports overlap the target's work).  Reads ``config.quantities`` (``ao`` only),
        ``weighting``, ``max_distance``, ``backfaces``, ``ray_offset`` and (once wired)
        ``hemicube_resolution``; refuses a ground plane, ``tolerance`` and
        ``keep_distances`` (both about rays)."""
        if tuple(config.quantities) != ("ao",):
            raise InputError(f"--method hemicube estimates ao only, got quantities "
                             f"{', '.join(config.quantities)}")
        if getattr(config, "ground_plane", False):
            raise InputError("--method hemicube has no ground plane (it draws the mesh's "
                             "triangles)")
        refuse_ray_settings("hemicube", config)
        if importlib.util.find_spec("moderngl") is None:
            raise HemicubeError("--method hemicube needs moderngl and an EGL driver: pip "
                                "install 'aobake[gl]' (and, on Debian, apt-get install "
                                "libegl1 libegl-mesa0 libgbm1 libgl1-mesa-dri)")
        if options is None:  # the config's settings once it carries them, else the class's
            options = HemicubeOptions.of(config, cls.options)
        faces = np.asarray(scene.faces, dtype=np.int64)
        if not len(faces):
            raise InputError(f"{scene.source}: no triangles for --method hemicube to draw")
        center, scale = _local_frame(scene, occluders)
        local = (np.asarray(scene.vertices, dtype=np.float64) - center) * scale
        unused = np.ones(len(local), dtype=bool)
        unused[faces.ravel()] = False
        local[unused] = 0.0  # as the occluders: a far-off unused vertex cannot overflow
        method = cls(local.astype(np.float32), faces, center, scale, options,
                     config.weighting, config.resolve_max_distance(scene.diagonal),
                     getattr(config, "backfaces", "occlude"),
                     getattr(config, "ray_offset", _default_ray_offset()))
        # The child started ahead is this method's until its first estimate takes it: an
        # executor whose workers estimate elsewhere ends it (``close``), and so does the
        # method's collection or the interpreter's exit, whichever comes first.
        worker = WORKER
        ahead = child.prestart(worker)
        if ahead is not None:
            method._close = weakref.finalize(method, child.discard, worker, ahead)
        return method

    def close(self) -> None:
        """End the GL child started ahead for this method if no estimate took it (an
        executor calls it when the estimates are done, or made elsewhere); idempotent."""
        if self._close is not None:
            self._close()

    def _limit(self, n_points: int) -> float:
        pixels = 3 * self.resolution * self.resolution
        return (TIMEOUT_BASE_S + n_points * (TIMEOUT_PER_POINT_TRIANGLE_S * len(self.faces)
                                             + TIMEOUT_PER_POINT_PIXEL_S * pixels))

    def eyes(self, points: np.ndarray, normals: np.ndarray, sizes) -> tuple:
        """(eyes (k, 3) float64 local units, offsets (k,) float64 local units) of points
        (k, 3) scene units with unit normals (k, 3): the ray-traced method's ray origins."""
        from aobake.trace import point_offsets

        local = (points - self.center) * self.scale
        offsets = point_offsets(local, None if sizes is None else sizes * self.scale,
                                self.ray_offset)
        return local + offsets[:, None] * normals, offsets

    def estimate(self, points, threads: int, chunk_rays: int, progress=None) -> Estimates:
        """points : ``SamplePoints`` (points (n, 3), normals (n, 3) unit, zero = no
        information, sizes (n,) | None) -> Estimates(fields {"ao": (n,) float64 in [0, 1]:
        1 = open}, rays None, extras {"ray_offset": (n,) float64 scene units (0 where not
        drawn), "hemicube_renderer": (n,) str the GL renderer that drew the point ('' where
        not drawn)}).

        The points go to GL children in pieces of at most CHILD_POINTS, ``threads`` children
        at a time (each one context, its geometry work on one core; a child is not started
        for fewer than MIN_CHILD_POINTS points); results land by index, and a point's value
        does not depend on its piece or its place in it.  ``chunk_rays`` is not used."""
        from aobake.warp import frames

        p = np.asarray(points.points, dtype=np.float64)
        nrm = np.asarray(points.normals, dtype=np.float64)
        n = len(p)
        ao = np.full(n, NO_INFORMATION_AO)
        offsets = np.zeros(n)
        renderer = np.full(n, "", dtype=f"<U{_RENDERER_CHARS}")
        index = np.flatnonzero(defined(nrm)) if n else np.zeros(0, dtype=np.int64)
        if not len(index):
            return Estimates({"ao": ao}, None, {"ray_offset": offsets,
                                                "hemicube_renderer": renderer})
        sizes = None if points.sizes is None else np.asarray(points.sizes, dtype=np.float64)
        normal = nrm[index]
        eye, offset = self.eyes(p[index], normal, None if sizes is None else sizes[index])
        tangent, bitangent = frames(normal)
        basis = np.stack([tangent, bitangent, normal], axis=1).astype(np.float32)
        offsets[index] = offset / self.scale  # a power of two: exact
        eye, near = eye.astype(np.float32), offset.astype(np.float32)

        children = max(1, min(int(threads), len(index) // MIN_CHILD_POINTS))
        pieces = max(children, -(-len(index) // CHILD_POINTS))
        bounds = np.linspace(0, len(index), pieces + 1).astype(np.int64)
        # llvmpipe's rasteriser threads per child: the cores the children leave
        raster_threads = max(1, int(threads) // children)

        def work(k):
            lo, hi = bounds[k], bounds[k + 1]
            inputs = dict(vertices=self.vertices, faces=self.faces, eyes=eye[lo:hi],
                          frames=basis[lo:hi], near=near[lo:hi], resolution=self.resolution,
                          max_distance=self.max_distance * self.scale,
                          weighting=self.weighting, backfaces=self.backfaces,
                          threads=raster_threads, keep_tiles=False)
            return self._run(inputs, int(hi - lo))

        done = 0
        with ThreadPoolExecutor(max_workers=children,
                                thread_name_prefix="aobake-hemicube") as pool:
            futures = [pool.submit(work, k) for k in range(pieces)]
            try:
                for k, future in enumerate(futures):
                    out = future.result()
                    sel = index[bounds[k]:bounds[k + 1]]
                    ao[sel] = out["ao"]
                    renderer[sel] = \
                        f"{out['renderer']} | {out['gl_version']}"[:_RENDERER_CHARS]
                    done += len(sel)
                    if progress is not None:
                        progress(done, len(index))
            except BaseException:
                for future in futures:
                    future.cancel()
                raise
        return Estimates({"ao": ao}, None, {"ray_offset": offsets,
                                            "hemicube_renderer": renderer})

    def _run(self, inputs: dict, n_points: int) -> dict:
        """The GL child's outputs; its failures as HemicubeError."""
        limit = self._limit(n_points)
        try:
            return child.run(WORKER, inputs, limit)
        except child.TimedOut:
            raise HemicubeError(f"the OpenGL child did not draw {n_points} hemicubes of "
                                f"{len(self.faces)} triangles in {limit:.0f} s, twice") \
                from None
        except child.Crashed as exc:
            raise HemicubeError(f"the OpenGL child {exc.how} drawing hemicubes") from None
        except child.Failed as exc:
            raise HemicubeError(f"the OpenGL child failed: {exc.line} (--method hemicube "
                                "needs moderngl and an EGL driver: pip install "
                                "'aobake[gl]'; on Debian apt-get install libegl1 "
                                "libegl-mesa0 libgbm1 libgl1-mesa-dri)") from None

    def record(self, estimates: Estimates) -> dict:
        """The report's ``parameters``: the resolution and every setting used (max distance
        in scene units), the ray offsets used, pixels per point, the renderer."""
        drawn = estimates.extras["hemicube_renderer"] != ""
        offsets = estimates.extras["ray_offset"][drawn]
        renderers = sorted(set(estimates.extras["hemicube_renderer"][drawn].tolist()))
        r = self.resolution
        parameters = {
            "method": self.name, **asdict(self.options),
            "weighting": self.weighting, "max_distance": self.max_distance,
            "backfaces": self.backfaces,
            "ray_offset": float(np.median(offsets)) if len(offsets) else None,
            "ray_offset_range": ([float(offsets.min()), float(offsets.max())]
                                 if len(offsets) else None),
            "ray_offset_rule": f"eye at the ray origin: max({self.ray_offset:g} x own "
                               f"triangle size, {OFFSET_ULPS} float32 ulps of |local "
                               "coordinate| + that size); near plane at that offset",
            "pixels_per_point": 3 * r * r,
            "pixel_weights": ("exact form factor of each pixel" if self.weighting == "cosine"
                              else "exact solid angle of each pixel")
                             + ", normalised by their sum; a pixel is its centre's ray",
            "far_limit": "sphere of radius max_distance (fragments beyond are discarded)",
            "points_drawn": int(np.count_nonzero(drawn)),
            "renderer": renderers[0] if len(renderers) == 1 else renderers or None,
            "error": "deterministic discretisation error (falls as 1/R; docs/hemicube.md), "
                     "no stderr",
        }
        return {"parameters": parameters}

    def error_quantities(self) -> list:
        """None: an approximation has no error bar (its error is what ``aobake compare``
        measures against the ray-traced truth)."""
        return []

    def kernel_stages(self) -> dict:
        return {}


def _default_ray_offset() -> float:
    from aobake.settings.rays import DEFAULT_RAY_OFFSET

    return DEFAULT_RAY_OFFSET
