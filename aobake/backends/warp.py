"""NVIDIA Warp: GPGPU ray queries on a CUDA device where there is one, on the CPU otherwise
(``--backend warp``; the ``warp`` extra: ``pip install 'aobake[warp]'``).

The same samplers, ray generation and estimators as every backend: only the ray queries
run in Warp, one GPU (or CPU) thread per ray.  The triangles' bounds go into a ``wp.Bvh``
(SAH); a query walks it with ``wp.bvh_query_capsule`` and tests each candidate with the
watertight ray/triangle test of Woop, Benthin and Wald (JCGT 2013) written here as a
``wp.func``.  ``occluded`` stops at the first hit, ``distance`` and ``intersect`` keep the
nearest (shrinking the walk's limit as they go); the front-face queries of ``--backfaces
ignore`` come from ``intersect`` (:class:`TriangleBackend`).  Geometry and rays are
float32 in the tracer's local frame, as for Embree.

Why not ``wp.Mesh`` with ``wp.mesh_query_ray`` / ``wp.mesh_query_ray_anyhit`` (Warp's own
mesh queries, about as fast here): their BVH boxes are the triangles' exact bounds under a
float32 slab test with no slack, so a ray through an edge two triangles share can miss both
boxes -- from inside a closed 16x16-per-side cube 92 of 10754 rays aimed at its edges and
vertices escaped, 19 of 17922 from inside an icosphere (Embree robust: 0 and 5; the float64
reference: 0).  Here every box is grown by a few ulps of the farthest coordinate the ray's
box test meets (``pads``), and an edge's sign is exact (float32 where it is sure, float64
where it is not: ``edge``), so the same edge seen from its two triangles gives opposite
signs: none escaped (``tests/test_warp_backend.py``).  A hit has ``0 <= t <= tmax`` (Warp's
own keep ``t < max_t``), and of faces hit at the same t the lowest index wins, whatever
order the walk meets them in.

t = 0 counts, as on Embree (the contract of ``aobake.backends.base`` and the reference say
``0 < t``), and t is Embree's ``n . (a - o) / n . d`` with the face's float32 normal, not
Woop's sheared sum, so an origin lying on a face (a vertex where a box rests on the floor:
608 of the still life's 19745) is blocked by it, as on Embree, rather than by the rounding
of a t that should be 0 (with Woop's t and ``0 < t`` those vertices read AO ~0.9 against
Embree's 0; with these rules 16 differ, by at most 11 rays of 64).

Each ray's answer depends on that ray alone (no shared state), so results are bit-identical
for any thread count and chunk size on one device.  A CUDA device and the CPU may differ
in the last bit of a distance (their compilers contract different multiply-adds); the
report's ``parameters.warp_device`` says which ran.

Warp is imported the first time a backend is built, never by ``import aobake``; where it
is not installed, building one is an InputError naming the extra.
"""

# no ``from __future__ import annotations``: Warp reads the kernels' annotations as objects
import importlib.util
import logging
import threading

import numpy as np

from aobake.backends.base import TriangleBackend
from aobake.errors import InputError

log = logging.getLogger(__name__)

#: the refusal where Warp is not installed
NEEDS_EXTRA = "--backend warp needs the warp extra: pip install 'aobake[warp]'"

_LOCK = threading.Lock()
_LOADED: dict = {}


def unavailable() -> str | None:
    """Why ``--backend warp`` cannot run here (the message to show), or None if it can.
    Looks for the package without importing it (importing Warp takes ~0.5 s)."""
    try:
        found = importlib.util.find_spec("warp") is not None
    except (ImportError, ValueError):
        found = False
    return None if found else NEEDS_EXTRA


def _warp():
    """(warp module, kernels dict): imported, initialised and compiled once per process."""
    with _LOCK:
        if _LOADED:
            return _LOADED["wp"], _LOADED["kernels"]
        reason = unavailable()
        if reason is not None:
            raise InputError(reason)
        try:
            import warp as wp
        except (ImportError, OSError) as error:  # installed but broken (a shared library)
            raise InputError(f"{NEEDS_EXTRA} (importing warp failed: {error})") from error
        from aobake.outputs.image import quiet_stderr

        # The library is quiet: Warp's banner and module-load lines are INFO; its C code
        # writes a CUDA-driver warning to the process's stderr on machines without one.
        wp.config.log_level = wp.LOG_WARNING
        with quiet_stderr() as said:
            wp.init()
        for line in said:
            log.debug("warp: %s", line)
        _LOADED["wp"], _LOADED["kernels"] = wp, _kernels(wp)
        return _LOADED["wp"], _LOADED["kernels"]


def _kernels(wp) -> dict:
    """The two queries as Warp kernels, one thread per ray, over a ``wp.Bvh`` of the
    triangles' bounds and the triangles' corners.

    origins, directions (n,) vec3 local; limits (n,) float32 tmax; pads (n,) float32 the
    slack every box is grown by for this ray (``pads``); hit (n,) uint8 1 where blocked;
    t (n,) float32 inf on a miss; face (n,) int32 -1 on a miss."""

    @wp.func
    def edge(ax: float, ay: float, bx: float, by: float):
        """ax by - ay bx with its exact sign: float32 where the sign is sure, else float64.

        A float32 a b - c d (rounded products, a rounded difference, perhaps contracted
        into a multiply-add) is off by at most 2^-23 (|a b| + |c d|) plus 2^-126 when the
        device flushes subnormals; twice that is the guard band.  Inside it the products
        are exact in float64 and the difference rounds once, so its sign is exact.  The
        same edge seen from its two triangles gives exactly opposite signs: a ray through
        it meets one of them (watertight)."""
        p = ax * by
        q = ay * bx
        e = p - q
        if wp.abs(e) > (wp.abs(p) + wp.abs(q)) * 2.384185791015625e-07 + 2.350988701644575e-38:
            return e
        return wp.float32(wp.float64(ax) * wp.float64(by) - wp.float64(ay) * wp.float64(bx))

    @wp.func
    def triangle(o: wp.vec3, d: wp.vec3, kx: int, ky: int, kz: int, sx: float, sy: float,
                 a: wp.vec3, b: wp.vec3, c: wp.vec3):
        """Distance along the ray to triangle abc, or -1 on a miss.  Inside: the watertight
        test of Woop, Benthin and Wald (JCGT 2013) in the ray's shear frame (kx, ky, kz;
        sx, sy), edges counted as inside (a ray through an edge or a vertex hits);
        degenerate triangles and rays in their plane never hit.  t: n . (a - o) / n . d
        with the float32 normal n = (b - a) x (c - a), Embree's: exactly 0 for an origin on
        an axis-aligned face, where the sheared sum leaves rounding of either sign."""
        pa = a - o
        pb = b - o
        pc = c - o
        ax = pa[kx] - sx * pa[kz]
        ay = pa[ky] - sy * pa[kz]
        bx = pb[kx] - sx * pb[kz]
        by = pb[ky] - sy * pb[kz]
        cx = pc[kx] - sx * pc[kz]
        cy = pc[ky] - sy * pc[kz]
        u = edge(cx, cy, bx, by)
        v = edge(ax, ay, cx, cy)
        w = edge(bx, by, ax, ay)
        if (u < 0.0 or v < 0.0 or w < 0.0) and (u > 0.0 or v > 0.0 or w > 0.0):
            return -1.0
        det = u + v + w
        if det == 0.0:
            return -1.0
        ng = wp.cross(b - a, c - a)
        den = wp.dot(ng, d)
        if den == 0.0:
            return -1.0
        return wp.dot(ng, pa) / den

    @wp.func
    def frame(d: wp.vec3):
        """The ray's shear axes (kx, ky, kz): kz its largest axis, kx ky the others
        (swapped when d[kz] < 0 to keep the winding)."""
        kz = int(0)
        if wp.abs(d[1]) > wp.abs(d[kz]):
            kz = 1
        if wp.abs(d[2]) > wp.abs(d[kz]):
            kz = 2
        kx = (kz + 1) % 3
        ky = (kx + 1) % 3
        if d[kz] < 0.0:
            swap = kx
            kx = ky
            ky = swap
        return wp.vec3i(kx, ky, kz)

    @wp.kernel(enable_backward=False)
    def occluded(bvh: wp.uint64, corners: wp.array2d(dtype=wp.vec3),
                 origins: wp.array(dtype=wp.vec3), directions: wp.array(dtype=wp.vec3),
                 limits: wp.array(dtype=wp.float32), pads: wp.array(dtype=wp.float32),
                 hit: wp.array(dtype=wp.uint8)):
        i = wp.tid()
        o = origins[i]
        d = directions[i]
        tmax = limits[i]
        hit[i] = wp.uint8(0)
        if tmax <= 0.0:  # a zero limit is a miss (t = 0 included), as on every backend
            return
        k = frame(d)
        sz = 1.0 / d[k[2]]
        sx = d[k[0]] * sz
        sy = d[k[1]] * sz
        query = wp.bvh_query_capsule(bvh, o, d, pads[i])
        f = int(0)
        while wp.bvh_query_next(query, f, tmax):
            t = triangle(o, d, k[0], k[1], k[2], sx, sy, corners[f, 0], corners[f, 1],
                         corners[f, 2])
            if t >= 0.0 and t <= tmax:
                hit[i] = wp.uint8(1)
                break

    @wp.kernel(enable_backward=False)
    def nearest(bvh: wp.uint64, corners: wp.array2d(dtype=wp.vec3),
                origins: wp.array(dtype=wp.vec3), directions: wp.array(dtype=wp.vec3),
                limits: wp.array(dtype=wp.float32), pads: wp.array(dtype=wp.float32),
                t_out: wp.array(dtype=wp.float32), face_out: wp.array(dtype=wp.int32)):
        i = wp.tid()
        o = origins[i]
        d = directions[i]
        best = limits[i]
        t_out[i] = wp.inf
        face_out[i] = -1
        if best <= 0.0:  # a zero limit is a miss (t = 0 included), as on every backend
            return
        k = frame(d)
        sz = 1.0 / d[k[2]]
        sx = d[k[0]] * sz
        sy = d[k[1]] * sz
        face = int(-1)
        query = wp.bvh_query_capsule(bvh, o, d, pads[i])
        f = int(0)
        # the limit only shrinks (boxes beyond it are never revisited); a box entered
        # exactly at it is still visited, so of faces hit at one t the lowest index wins,
        # whatever order the traversal meets them in
        while wp.bvh_query_next(query, f, best):
            t = triangle(o, d, k[0], k[1], k[2], sx, sy, corners[f, 0], corners[f, 1],
                         corners[f, 2])
            if t >= 0.0 and t <= best:
                if t < best or face < 0 or f < face:
                    best = t
                    face = f
        if face >= 0:
            t_out[i] = best
            face_out[i] = face

    return {"occluded": occluded, "nearest": nearest}


def default_device(wp) -> str:
    """``cuda:0`` where Warp sees a CUDA device, else ``cpu``."""
    return "cuda:0" if wp.is_cuda_available() else "cpu"


#: the slack every box is grown by, in float32 ulps of the farthest coordinate a ray's
#: box test meets (its origin's, or the scene's 1): the slab test's rounding is a few ulps
PAD_ULPS = 16

#: triangles per BVH leaf (bunny, CPU, occlusion of rays from its surface: 1 leaf 0.32,
#: 2 0.38, 4 0.40, 8 0.41 Mrays per CPU second; the nearest hit 0.21 .. 0.34)
LEAF_SIZE = 4


def pads(origins: np.ndarray) -> np.ndarray:
    """(n,) float32 the slack (local units) each ray's boxes are grown by, so the float32
    slab test never skips a box the ray touches: PAD_ULPS ulps of max(|origin|_inf, 1) + 2
    (the farthest a box entry of a ray from that origin into the [-1, 1] scene lies)."""
    reach = np.abs(origins).max(axis=1, initial=0.0).astype(np.float64) + 2.0
    return (PAD_ULPS * np.finfo(np.float32).eps * reach).astype(np.float32)


class WarpBackend(TriangleBackend):
    """A Warp BVH of the scene's triangles (see ``aobake.backends.base``).

    device : None (a CUDA device where Warp sees one, else the CPU), or a Warp device name
    ("cpu", "cuda:0": the benchmarks pin one).  ``robust`` is accepted for Embree's sake and
    changes nothing: the traversal is conservative and the triangle test watertight.
    """

    name = "warp"
    unavailable = staticmethod(unavailable)

    def __init__(self, vertices, faces, face_normals, step, robust: bool = True,
                 device: str | None = None):
        wp, self._kernels = _warp()
        super().__init__(face_normals, step)
        self._wp = wp
        self.device = device or default_device(wp)
        self._cpu = wp.get_device(self.device).is_cpu
        local = np.asarray(vertices, dtype=np.float64).astype(np.float32)
        corners = np.ascontiguousarray(local[np.asarray(faces, dtype=np.int64)])  # (f, 3, 3)
        self._corners = wp.array(corners, dtype=wp.vec3, device=self.device)      # (f, 3) vec3
        # the triangles' exact float32 bounds; each query grows them by its pad
        self._lowers = wp.array(np.ascontiguousarray(corners.min(axis=1)), dtype=wp.vec3,
                                device=self.device)
        self._uppers = wp.array(np.ascontiguousarray(corners.max(axis=1)), dtype=wp.vec3,
                                device=self.device)
        # SAH on every device: the same tree wherever it runs (the answers do not depend on
        # the tree: ties go to the lowest face index)
        self._bvh = wp.Bvh(self._lowers, self._uppers, constructor="sah", leaf_size=LEAF_SIZE)
        # CPU launches run on the calling thread (the tracer's pool gives the parallelism);
        # one CUDA device takes one query at a time from this process
        self._gpu_lock = None if self._cpu else threading.Lock()
        # compile and load the kernels now, on one thread, not inside the first chunk
        probe = np.zeros((1, 3), dtype=np.float32)
        self.occluded(probe, np.array([[0, 0, 1]], dtype=np.float32), np.float32(1))
        self.intersect(probe, np.array([[0, 0, 1]], dtype=np.float32), np.float32(1))

    def described(self) -> dict:
        """The report's parameters: ``warp_device`` (``cpu``, or ``cuda:0 (its name)``) and
        ``warp_version``."""
        where = self.device
        if not self._cpu:
            where = f"{where} ({self._wp.get_device(self.device).name})"
        return {"warp_device": where, "warp_version": self._wp.config.version}

    def _launch(self, kernel, origins, directions, tmax, outputs):
        """Run ``kernel`` over the rays: on the CPU on numpy's memory (no copies), on CUDA
        through device copies.  outputs : numpy arrays filled in place."""
        wp = self._wp
        n = len(origins)
        if n == 0:
            return
        origins = np.ascontiguousarray(origins, dtype=np.float32)
        limit = np.maximum(np.broadcast_to(np.asarray(tmax, dtype=np.float32), (n,)),
                           np.float32(0))  # a zero (or negative) limit is a miss
        arrays = [(origins, wp.vec3), (np.ascontiguousarray(directions, dtype=np.float32), wp.vec3),
                  (np.ascontiguousarray(limit), wp.float32), (pads(origins), wp.float32)]
        if self._cpu:
            inputs = [wp.array(a, dtype=t, device="cpu", copy=False) for a, t in arrays]
            outs = [wp.array(o, device="cpu", copy=False) for o in outputs]
            wp.launch(kernel, dim=n, inputs=[self._bvh.id, self._corners, *inputs, *outs],
                      device="cpu")
            return
        with self._gpu_lock:
            inputs = [wp.array(a, dtype=t, device=self.device) for a, t in arrays]
            outs = [wp.empty(len(o), dtype=wp.dtype_from_numpy(o.dtype), device=self.device)
                    for o in outputs]
            wp.launch(kernel, dim=n, inputs=[self._bvh.id, self._corners, *inputs, *outs],
                      device=self.device)
            for o, d in zip(outputs, outs):
                o[:] = d.numpy()

    def occluded(self, origins, directions, tmax) -> np.ndarray:
        """(n,) bool: a hit within [0, tmax] (t = 0: the origin on a face, as Embree)."""
        hit = np.zeros(len(origins), dtype=np.uint8)
        self._launch(self._kernels["occluded"], origins, directions, tmax, [hit])
        return hit.view(bool)

    def distance(self, origins, directions, tmax) -> np.ndarray:
        """(n,) float32 nearest-hit distance; inf where nothing is hit within tmax."""
        return self.intersect(origins, directions, tmax)[0]

    def intersect(self, origins, directions, tmax):
        """(t (n,) float32, inf on a miss; prim (n,) int32, -1 on a miss) of the nearest hit
        within tmax; of faces hit at the same t, the lowest index."""
        n = len(origins)
        t = np.full(n, np.inf, dtype=np.float32)
        prim = np.full(n, -1, dtype=np.int32)
        self._launch(self._kernels["nearest"], origins, directions, tmax, [t, prim])
        return t, prim
