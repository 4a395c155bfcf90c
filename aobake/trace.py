"""Trace: rays of sample points through a backend, on a thread pool, into estimates.

``Tracer`` holds a scene prepared for one configuration (the resolved
parameters, the backend, the ray generator); :meth:`Tracer.estimate` orders the
points for ray coherence, cuts them into chunks of about ``chunk_rays`` rays,
runs the chunks on threads (the Embree queries release the GIL, numpy in
its large element-wise loops) and lands each chunk's estimates by index, never
by arrival.  Each point's rays are a pure function of (seed, point id, sample
id), so results are bit-identical for any thread count and chunk size.
"""

from __future__ import annotations

import math
import os
import threading
from dataclasses import replace
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from typing import Callable

import numpy as np

from aobake import _native, select
from aobake.backends.union import query_name
from aobake.constants import OFFSET_ULPS
from aobake.offsets import PointOffsets, point_offsets  # noqa: F401  (trace.point_offsets)
from aobake.paths import STREAM_BOUNCE, path_values
from aobake.rng import hash_key
from aobake.samplers.base import inward_key, replicate_keys, sample_hashes
from aobake.records import BlockRows, BlockSizes, Estimates, block_rows
from aobake.quantities import QUANTITIES, Traced
from aobake.rays import RayGenerator
from aobake.samplers import sample_set
from aobake.scene import release_freed_memory
from aobake.vectors import count_defined, defined

#: a freed temporary at least this large has its heap pages handed back at once
#: (``scene.release_freed_memory``): an estimate of a few points (a split's item) trims nothing
TRIM_BYTES = 1 << 24

#: rays per chunk handed to one ``run()``: Embree's 2-thread scaling flattens out from ~64k,
#: and larger chunks amortise the per-chunk numpy work (measured: 64k 6.8, 128k 7.3 Mrays/s).
DEFAULT_CHUNK_RAYS = 131072


def default_threads() -> int:
    """All cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def run_chunks(
    n_chunks: int,
    work: Callable[[int], object],
    land: Callable[[int, object], None],
    threads: int,
    progress: Callable[[int], None] | None = None,
) -> None:
    """Call ``work(i)`` for i in range(n_chunks) on ``threads`` threads and ``land(i, result)``
    on the calling thread.  ``land`` must place results by ``i`` so the outcome does not
    depend on completion order.  ``progress(i)`` is called after each landing.  At most
    ``2 * threads`` chunks are in flight, which bounds memory whatever the number of points.
    """
    if threads <= 1:
        for i in range(n_chunks):
            land(i, work(i))
            if progress:
                progress(i)
        return
    with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="aobake") as pool:
        pending, next_chunk = {}, 0
        try:
            while next_chunk < n_chunks or pending:
                while next_chunk < n_chunks and len(pending) < 2 * threads:
                    pending[pool.submit(work, next_chunk)] = next_chunk
                    next_chunk += 1
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    i = pending.pop(future)
                    land(i, future.result())
                    if progress:
                        progress(i)
        except BaseException:
            for future in pending:
                future.cancel()
            raise


def _spread_bits(q: np.ndarray) -> np.ndarray:
    """(n,) uint32 of 10-bit ints -> their bits moved to positions 0, 3, 6, ... (uint32)."""
    q = q & np.uint32(0x3FF)
    for shift, mask in ((16, 0x030000FF), (8, 0x0300F00F), (4, 0x030C30C3), (2, 0x09249249)):
        q = (q | (q << np.uint32(shift))) & np.uint32(mask)
    return q


def morton_order(points: np.ndarray, kernels=None) -> np.ndarray:
    """(n,) int64 permutation sorting ``points`` (n, 3) along a Z-order curve (ray coherence).

    10 bits per axis; ties keep their input order (a stable sort of packed keys; kernels:
    the compiled module for its radix sort, the same permutation).
    """
    from aobake.rng import stable_argsort

    n = len(points)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    code = np.zeros(n, dtype=np.uint32)
    for axis in range(3):  # column by column: a (n, 3) reduction over axis 0 is ~2x slower
        x = points[:, axis]
        lo, hi = x.min(), x.max()
        q = ((x - lo) * (1023.0 / (hi - lo) if hi > lo else 0.0)).astype(np.uint32)
        code |= _spread_bits(q) << np.uint32(axis)
    return stable_argsort(code, 2**30, kernels)


class Tracer:
    """A scene prepared for tracing under one configuration (the resolved parameters live here).

    rays : rays per point (default ``config.rays``; a lightmap splits its per-texel
    rays over the texel's samples).
    """

    def __init__(self, scene, config, occluders, rays: int | None = None,
                 stage: int = 0, compiled: bool | None = None):
        """occluders : ``aobake.occluders.Occluders`` of ``scene`` (built once per bake),
        rays : rays per point (default ``config.rays``), stage : the key stream (0; 1 for
        ``--tolerance``'s final stage), compiled : use the compiled kernels (default: as
        ``_native.kernels()`` says on the calling thread)."""
        self.scene, self.config, self.occluders = scene, config, occluders
        self.center, self.scale, self.step = occluders.center, occluders.scale, occluders.step
        self.diagonal = occluders.diagonal
        self.max_distance = config.resolve_max_distance(self.diagonal)
        self.tau = config.resolve_tau(self.diagonal)
        self.quantities = [QUANTITIES[name] for name in config.quantities]
        self.samples = sample_set(config.sampler, config.rays if rays is None else rays,
                                  config.replicates)
        # Decided once, on the calling thread, and recorded as decided (report: kernels).
        if compiled is None:
            compiled = _native.kernels() is not None
        self.kernels = _native.kernels() if compiled else None
        if compiled and self.kernels is None:  # asked for by a caller that had them
            self.kernels = _native._compiled
        self.generator = RayGenerator(self.samples, config.weighting, config.seed,
                                      compiled=self.kernels is not None, stage=stage)
        # --keep-distances: every ray's nearest-hit distance is kept (for aobake.refit), so
        # its queries are distance queries whatever the quantities.
        self.need_distance = config.keep_distances or any(q.needs_distance
                                                          for q in self.quantities)
        self.query = query_name(self.need_distance, config.backfaces)
        # -q indirect: every ray's path beyond its first hit, from a key stream of its own
        self.need_paths = any(q.needs_paths for q in self.quantities)
        # -q thickness: rays into the inward hemisphere, from a key stream of their own; a
        # miss counts the cap: the max distance, else the scene's diagonal (no chord of the
        # scene is longer)
        self.need_inward = any(q.needs_inward for q in self.quantities)
        self.cap = self.max_distance if math.isfinite(self.max_distance) else self.diagonal
        self.inward = None
        if self.need_inward:
            self.inward = RayGenerator(self.samples, config.weighting, config.seed,
                                       compiled=self.kernels is not None, stage=stage,
                                       key=inward_key(config.seed, stage))
        self._bounce_key = hash_key(config.seed, STREAM_BOUNCE + 16 * stage)

    @property
    def dof(self) -> int:
        """Degrees of freedom of a point's stderr: n - 1 rays (i.i.d.) or R - 1 replicates."""
        return self.samples.rays - 1 if self.samples.iid else self.samples.groups - 1

    def with_rays(self, rays: int, stage: int) -> "Tracer":
        """The same occluders and settings casting ``rays`` per point from key stream
        ``stage`` (``--tolerance``'s final stage)."""
        return Tracer(self.scene, self.config, self.occluders, rays, stage,
                      compiled=self.kernels is not None)

    def kernel_stages(self) -> dict:
        """stage -> compiled? for the stages this tracer runs (see ``_native.used``)."""
        compiled = self.kernels is not None
        stages = {"ray_generation": self.generator.compiled}
        for q in self.quantities:
            for stage in q.kernels:
                stages[stage] = compiled
        return stages

    def parameters(self, offsets: tuple | None) -> dict:
        """Every parameter actually used, in scene units, for the report; ``offsets``: the
        (min, median, max) ray offset over the traced points (None: nothing traced)."""
        params = {
            "max_distance": self.max_distance,
            "tau": self.tau,
            "ray_offset": None if offsets is None else offsets[1],
            "ray_offset_range": None if offsets is None else [offsets[0], offsets[2]],
            "ray_offset_rule": f"max({self.config.ray_offset:g} x own triangle size, "
                               f"{OFFSET_ULPS} float32 ulps of |local coordinate| + that size); "
                               "query points: the scene's median triangle size",
            "rays_per_point": self.samples.rays,
            "replicates": self.samples.groups,
            "stderr_method": ("per-ray spread (iid)" if self.samples.iid
                              else f"spread of {self.samples.groups} independent replicates")
                             + "; 1/n where the spread is 0",
            "confidence": self.config.confidence,
            "interval_method": "clip(mean -+ sqrt((t se)^2 + h0^2), 0, 1): t Student with "
                               + ("n - 1" if self.samples.iid else f"{self.samples.groups - 1}")
                               + " degrees of freedom (texels: Welch-Satterthwaite over "
                                 "their samples), h0 = 1 - (1 - confidence)^(1/n) (rule of three)",
            "query": self.query,
        }
        if self.need_inward:
            params["thickness_cap"] = self.cap
        params.update(self.occluders.record())
        return params

    def traced(self, points: np.ndarray, normals: np.ndarray, ids: np.ndarray,
               sizes: np.ndarray | None = None, j0: int = 0, count: int | None = None,
               offsets_out: np.ndarray | None = None) -> Traced:
        """Trace samples j0 .. j0 + count - 1 (default all) of every replicate of k points.

        points (k, 3) float64, normals (k, 3) float64 unit, ids (k,) int64, sizes (k,) float64
        own triangle sizes | None; offsets_out (k,) float64 | None written with the origin
        offsets used (local units)."""
        # Into the backend's frame first, then offset: the offset is then exact relative to
        # the float32 grid the backend sees, however far from the origin and at any scale.
        local = (points - self.center) * self.scale
        offsets = point_offsets(local, None if sizes is None else sizes * self.scale,
                                self.config.ray_offset)
        if offsets_out is not None:
            offsets_out[:] = offsets
        origins = local + offsets[:, None] * normals
        rays = self.generator.rays(origins, normals, ids, j0, count)
        k, groups, m, _ = rays.directions.shape
        tmax = np.float32(min(self.max_distance * self.scale, 3.0e38))
        occluded, distance = self.occluders.trace(self.query, rays.origins,
                                                  rays.directions.reshape(-1, 3), tmax)
        shape = (k, groups, m)
        path = None
        if self.need_paths:
            keys = replicate_keys(self._bounce_key, ids, groups)
            hashes = sample_hashes(keys, j0, m).reshape(-1)
            path = path_values(self.occluders, self.scene, hashes, rays.origins,
                               rays.directions.reshape(-1, 3), tmax, self.config.albedo,
                               self.config.bounces, self.config.ray_offset).reshape(shape)
        inward = None
        if self.need_inward:
            inward = self._inward(local, offsets, normals, ids, j0, count, tmax).reshape(shape)
        return Traced(rays.directions, occluded.reshape(shape),
                      None if distance is None else distance.reshape(shape),
                      # distances stay in local units: tau per local unit
                      normals, self.samples.iid, self.tau / self.scale, self.kernels,
                      self.config.confidence, self.max_distance, path, self.config.albedo,
                      inward, self.cap)

    def _inward(self, local, offsets, normals, ids, j0, count, tmax) -> np.ndarray:
        """(k R m,) float64 the inward rays' distances (scene units) to the first surface
        behind each point, a miss counted as the cap.

        The rays start at the point moved inward by its ray offset (the outward rays'
        clearance, mirrored) and are measured from there: behind a parallel surface each is
        short by offset / cos, on average 2 x offset (cosine weighting), far below any error
        bar.  (Measured from the point itself along each ray instead, a ray nearly tangent
        at a convex vertex starts outside the mesh and misses: a cap for a chord of 0.)"""
        rays = self.inward.rays(local - offsets[:, None] * normals, -normals, ids, j0, count)
        k, groups, m = rays.directions.shape[:3]
        # any face counts: the far side is seen from inside, its back faces
        _, distance = self.occluders.trace("distance", rays.origins,
                                           rays.directions.reshape(-1, 3), tmax)
        length = distance.astype(np.float64).reshape(k, groups * m) / self.scale
        return np.where(np.isfinite(length), np.minimum(length, self.cap), self.cap)

    def estimate_chunk(self, points: np.ndarray, normals: np.ndarray, ids: np.ndarray,
                       sizes: np.ndarray | None = None) -> dict:
        """points (k, 3) float64, normals (k, 3) float64 unit, ids (k,) int64, sizes (k,) float64
        own triangle sizes | None -> field dict."""
        return self.estimate_traced(self.traced(points, normals, ids, sizes))

    def estimate_traced(self, traced: Traced) -> dict:
        """The field dict of k points' traced rays (all m samples of every replicate)."""
        out = {}
        for q in self.quantities:
            out.update(q.estimate(traced))
        return out

    def no_information(self, normals: np.ndarray) -> dict:
        """Field dict for points that cast no rays (see each quantity's ``no_information``)."""
        out = {}
        for q in self.quantities:
            out.update(q.no_information(normals, cap=self.cap) if q.needs_inward
                       else q.no_information(normals))
        return out

    def estimate(
        self,
        points: np.ndarray,
        normals: np.ndarray,
        ids: np.ndarray,
        threads: int | None = None,
        chunk_rays: int = DEFAULT_CHUNK_RAYS,
        progress: Callable[[int, int], None] | None = None,
        sizes: np.ndarray | None = None,
    ) -> Estimates:
        """Estimates for all points (n, 3) float64 with normals (n, 3) float64 and ids (n,) int64;
        sizes (n,) float64 the size of each point's own triangles (None: unknown).

        Points whose normal is zero are not traced (0 rays, no-information estimate).
        Returns the fields (name -> (n,) / (n, 3) float64), rays (n,) int32 and the extras
        ``ray_offset`` (n,) float64 (scene units; 0 where not traced) and, with
        ``keep_distances``, ``ray_distances`` (n, R, m) float32 local-unit hit distances
        (inf on a miss and for untraced points).  Each point's values depend on that point
        alone, so any split of the points gives the same rows.
        """
        n = len(points)
        streamed = self.samples.piece < self.samples.m
        if isinstance(sizes, BlockSizes) and n:
            if not (streamed or self.config.keep_distances):
                return self._estimate_blocks(points, normals, ids, sizes, threads, chunk_rays,
                                             progress)
            if not self.config.keep_distances:
                return self._stream_blocks(points, normals, ids, sizes, threads, chunk_rays,
                                           progress)
            # (kept distances: the arrays)
            points, ids, sizes = np.asarray(points), np.asarray(ids), np.asarray(sizes)
        normals = np.asarray(normals, dtype=np.float64)
        traced = defined(normals)
        every = bool(traced.all())  # the usual case: no copies of the points, no index
        valid = slice(None) if every else np.flatnonzero(traced)
        del traced
        kept = points if every else points[valid]
        order = morton_order(kept, self.kernels)
        if not every:
            order = valid[order]
        if n < 2**31:  # held while every ray is traced: 4 bytes a point, not 8
            order = order.astype(np.int32)
        if not (every or streamed):
            # the chunks reach the points through ``order``: the copy of the traced points
            # (24 bytes a point) is not held while the values are made and the rays traced
            large = kept.nbytes >= TRIM_BYTES
            del kept
            if large:  # its pages, from the allocator's heap (a small one: not worth a trim)
                release_freed_memory()
        per_chunk = max(1, int(chunk_rays) // self.samples.rays)
        n_chunks = -(-len(order) // per_chunk)
        out = self.no_information(normals)
        rays = np.zeros(n, dtype=np.int32)
        rays[valid] = self.samples.rays
        # The offsets each point uses (local units), kept for the report (not computed twice).
        offsets = np.zeros(n)
        distances = None
        if self.config.keep_distances:
            distances = np.full((n, self.samples.groups, self.samples.m), np.inf,
                                dtype=np.float32)
        extras = {"ray_offset": offsets}
        if distances is not None:
            extras["ray_distances"] = distances
        if streamed:
            if len(kept):
                offsets[valid] = point_offsets(
                    (kept - self.center) * self.scale,
                    None if sizes is None else (sizes if every else sizes[valid]) * self.scale,
                    self.config.ray_offset)
            self._stream(points, normals, ids, sizes, order, out, distances, threads, progress)
            offsets /= self.scale
            return Estimates(out, rays, extras, self.dof)
        del valid  # (where some points are not traced: their index, 8 bytes a point)

        def work(i):
            sel = order[i * per_chunk:(i + 1) * per_chunk]
            used = np.empty(len(sel))
            traced = self.traced(points[sel], normals[sel], ids[sel],
                                 None if sizes is None else sizes[sel], offsets_out=used)
            return (sel, self.estimate_traced(traced),
                    traced.distance if distances is not None else None, used)

        def land(i, result):
            sel, values, distance, used = result
            for name, array in values.items():
                out[name][sel] = array
            if distance is not None:
                distances[sel] = distance
            offsets[sel] = used

        done = [0]

        def tick(i):
            done[0] += min(per_chunk, len(order) - i * per_chunk)
            if progress:
                progress(done[0], len(order))

        run_chunks(n_chunks, work, land, threads or default_threads(), tick)
        offsets /= self.scale  # scene units (a power of two: exact)
        return Estimates(out, rays, extras, self.dof)

    def _estimate_blocks(self, points, normals, ids, sizes, threads, chunk_rays,
                         progress) -> Estimates:
        """:meth:`estimate` for sizes made a block of points at a time (``records.BlockSizes``:
        a set's instances), holding nothing for every point besides the results: each
        block's traced points are put in their own Morton order and cut into chunks; a
        block's order and sizes are made when its first chunk runs and let go when its last
        lands (at most 2 * threads chunks are in flight: a few blocks' worth); the ray
        offsets are not kept (``offsets.PointOffsets`` makes them again where the report
        reads them).  Every point's values depend on that point alone, so tracing the
        blocks' points in this order changes no bit."""
        n = len(points)
        bounds = sizes.bounds
        per_chunk = max(1, int(chunk_rays) // self.samples.rays)
        blocks = len(bounds) - 1
        # each block's traced count, a block's normals at a time (no (n,) mask), and the
        # no-information values of every point (a bent normal's is the normal), a block at
        # a time where the normals are made so (records.BlockRows: a set sharing rows)
        counts = np.zeros(blocks, dtype=np.int64)
        out = None if isinstance(normals, BlockRows) else self.no_information(normals)
        for k in range(blocks):
            rows = block_rows(normals, bounds, k)
            counts[k] = count_defined(rows)
            if isinstance(normals, BlockRows):
                if out is None:
                    out = {name: np.empty((n,) + a.shape[1:], dtype=a.dtype)
                           for name, a in self.no_information(rows[:0]).items()}
                for name, array in self.no_information(rows).items():
                    out[name][bounds[k]:bounds[k + 1]] = array
        first_chunk = np.concatenate([[0], np.cumsum(-(-counts // per_chunk))])
        total = int(counts.sum())
        rays = np.zeros(n, dtype=np.int32)
        counted = select.TopCounts()
        # block -> [its traced points' order (t,) int64, its sizes, chunks left, its points,
        # normals and ids (views, or the rows made once for the block)]
        held: dict = {}
        lock = threading.Lock()

        def block_of(i):
            return int(np.searchsorted(first_chunk, i, side="right")) - 1

        def context(k):
            with lock:  # the first chunk of a block makes its order and sizes, once
                if k not in held:
                    b0 = int(bounds[k])
                    here = [block_rows(array, bounds, k) for array in (points, normals, ids)]
                    valid = np.flatnonzero(defined(here[1]))
                    order = valid[morton_order(here[0][valid], self.kernels)]
                    rays[b0 + valid] = self.samples.rays
                    held[k] = [order, sizes.block(k),
                               int(first_chunk[k + 1] - first_chunk[k]), *here]
                return held[k]

        def work(i):
            k = block_of(i)
            order, block_sizes, _, block_points, block_normals, block_ids = context(k)
            j = i - int(first_chunk[k])
            local = order[j * per_chunk:(j + 1) * per_chunk]
            sel = local + int(bounds[k])
            used = np.empty(len(sel))
            traced = self.traced(block_points[local], block_normals[local], block_ids[local],
                                 block_sizes[local], offsets_out=used)
            used /= self.scale  # scene units (a power of two: exact)
            return k, sel, self.estimate_traced(traced), used

        def land(i, result):
            k, sel, values, used = result
            for name, array in values.items():
                out[name][sel] = array
            counted.add(used)  # the report's offset summary: its first pass, counted here
            held[k][2] -= 1
            if not held[k][2]:
                with lock:
                    del held[k]

        done = [0]

        def tick(i):
            k = block_of(i)
            j = i - int(first_chunk[k])
            done[0] += int(min(per_chunk, counts[k] - j * per_chunk))
            if progress:
                progress(done[0], total)

        run_chunks(int(first_chunk[-1]), work, land, threads or default_threads(), tick)
        offsets = PointOffsets(points, normals, sizes, self.center, self.scale,
                               self.config.ray_offset, counted)
        return Estimates(out, rays, {"ray_offset": offsets}, self.dof)

    def _stream_blocks(self, points, normals, ids, sizes, threads, chunk_rays,
                       progress) -> Estimates:
        """:meth:`estimate` of points whose rays exceed one piece (streamed) where the sizes
        are made a block of points at a time (``records.BlockSizes``): each block's points
        streamed on their own (:meth:`estimate` of the block's rows), their rows landing in
        the result as it ends (``records.Merged``) and their ray offsets counted for the
        report and let go (``offsets.OffsetFold``), so nothing is held for every point
        besides the results.  Every point's values depend on that point alone: the same
        rows as one call on all of them."""
        from aobake.offsets import OffsetFold
        from aobake.records import Merged

        n, bounds = len(points), sizes.bounds

        def remade(counted):
            return PointOffsets(points, normals, sizes, self.center, self.scale,
                                self.config.ray_offset, counted)

        result = Merged(n, {"ray_offset": OffsetFold(remade)})
        for k in range(len(bounds) - 1):
            b0, b1 = int(bounds[k]), int(bounds[k + 1])
            if b1 == b0:
                continue
            step = None if progress is None else (lambda done, count, b0=b0:
                                                  progress(b0 + done, n))
            rows = [np.asarray(block_rows(array, bounds, k)) for array in (points, normals, ids)]
            result.add(b0, b1, self.estimate(*rows, threads, chunk_rays, step,
                                             sizes=sizes.block(k)))
        return result.result()

    def _stream(self, points, normals, ids, sizes, order, out, distances, threads,
                progress) -> None:
        """Points whose rays exceed one piece: each work item traces one piece (samples j0 ..
        j0 + piece - 1 of every replicate) of one point into its quantities' moments, and the
        pieces of a point are folded in piece order (items land out of order; at most the
        2 * threads in flight wait), so memory is bounded by the piece size, never by the ray
        count, and the sums are the same whatever the threads.  Fills ``out`` in place."""
        m, piece = self.samples.m, self.samples.piece
        pieces = -(-m // piece)
        quantities = self.quantities
        pending: dict = {}
        state = {"next": 0, "moments": None, "done": 0}

        def work(i):
            p, j0 = order[i // pieces], (i % pieces) * piece
            sel = slice(p, p + 1)
            traced = self.traced(points[sel], normals[sel], ids[sel],
                                 None if sizes is None else sizes[sel], j0, min(piece, m - j0))
            moments = [q.moments(traced) for q in quantities]
            if distances is None:  # keep only what the fold needs (normals, settings)
                traced = replace(traced, directions=None, occluded=None, distance=None,
                                 inward=None)
            return moments, traced

        def land(i, result):
            pending[i] = result
            while state["next"] in pending:  # fold in item order, whatever the arrival order
                i = state["next"]
                moments, traced = pending.pop(i)
                b = i % pieces
                if distances is not None:
                    j0 = b * piece
                    distances[order[i // pieces], :, j0:j0 + traced.distance.shape[2]] = \
                        traced.distance[0]
                if b == 0:
                    state["moments"] = moments
                else:
                    na, nb = b * piece, min(piece, m - b * piece)
                    state["moments"] = [q.extend(a, new, na, nb)
                                        for q, a, new in zip(quantities, state["moments"], moments)]
                if b == pieces - 1:
                    p = order[i // pieces]
                    for q, moment in zip(quantities, state["moments"]):
                        for name, array in q.finish(moment, traced, m).items():
                            out[name][p] = array[0]
                    state["done"] += 1
                    if progress:
                        progress(state["done"], len(order))
                state["next"] += 1

        run_chunks(len(order) * pieces, work, land, threads or default_threads())
