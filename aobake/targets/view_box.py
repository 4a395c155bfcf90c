"""``--pixel-filter box`` with the joint estimator (``--box-sampling joint``, the default for
the ray-traced method): each pixel's value estimates the mean AO over its area as a
renderer does, with its samples' positions in the pixel and their AO rays' directions
stratified together and traced in bulk.

Per pixel, ``--replicates`` R independent replicates of m AO rays (n = R m: ``--rays``
rounded as the sampler rounds a point's rays).  A replicate's rays leave the hits of m / r
positions in the pixel, r = ``rays_per_position`` (4 for sobol and stratified, fewer where
a replicate would get fewer than ``MIN_POSITIONS`` positions; 1 for random, whose samples
must stay i.i.d.): the rays of position q are rays q r .. q r + r - 1, each leaving the
position's hit about the geometric normal there turned to face the eye, in the direction
its sample gives, warped by ``--weighting`` as every ray of aobake
(``aobake.samplers.joint``: the positions one stratified set, the directions the ray-traced
method's own samples of one replicate of m, paired by a random shuffle of the positions).
Each value is a pure function of (seed, pixel, replicate, index) through the one hash
(streams ``STREAM_JOINT``, ``STREAM_JOINT_DIRECTIONS``, ``STREAM_JOINT_BOUNCE``), and the
pixels are traced in blocks whose size depends on n alone, each pixel's sums taken in the
same order in every block (pieces of a pixel with more than ``BLOCK_RAYS`` rays folded in
order): the image is the same, bit for bit, for any thread count, chunk size or executor.

Why r = 4 rays per position: on the still life at 160x90 the per-pixel RMSE of r = 1, 2, 4
and 8 differs by less than 10% at 256 to 4096 rays per pixel (r = 16 is up to 20% worse
below 1024), while a position (a closest-hit ray, its surface point, its frame) costs more
than an AO ray: r = 4 took half the CPU time of r = 1; docs/conventions.md, "The pixel
filter", has the measurements.

Cost per AO ray: one occlusion query (closest-hit for obscurance; a path for -q
indirect), 1/r of a closest-hit primary ray, and the rays' arithmetic compiled, with the
GIL released so that the threads' blocks overlap: the positions and the camera rays
through them (``aobake._kernels.pixel_rays``, sobol), the hits, offsets and AO rays
(``aobake._kernels.box_rays``, sobol and random; else ``fill_rays`` one call per position
slot, else numpy: the same bits); the sums in numpy over whole blocks.  No per-position
sample point, chunk or per-point statistics.  (Measured, still life 160x90, 256 rays,
one thread: the numpy of the primary rays and of the hits took ~130 of 380 ms, and two
threads 0.32 s where one took 0.40 s: the GIL.)

The estimate is the ratio estimator over the part of the pixel that sees the scene, as the
positions estimator's (``aobake.targets.view.pool``): value = sum_g Y_g / sum_g C_g (Y_g
the sum of replicate g's ray values over its positions that hit a baked face, C_g their
rays), stderr sqrt(sum_g (Y_g - v C_g)^2 / (R (R - 1) Cbar^2)) with R - 1 degrees of
freedom; with ``--sampler random`` (n i.i.d. samples, one ray per position) the spread of
the covered samples' values, C - 1 degrees of freedom; the interval's rule of three over
the covered positions (``pool``).  ``coverage`` is the fraction of the pixel's positions
whose primary ray hits the scene.  The G-buffer is the centre ray's hit, else the covered
position nearest the centre (ties: the lower position index, g times the positions per
replicate plus q).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aobake import stats
from aobake.constants import AXES, OFFSET_ULPS
from aobake.quantities import QUANTITIES
from aobake.rng import hash_key
from aobake.samplers import joint as joint_samples
from aobake.samplers import sample_set
from aobake.samplers.base import replicate_keys
from aobake.warp import WEIGHTINGS, cos_sin_2pi

#: hash streams of the joint samples' positions, of their paths' bounces (-q indirect)
#: and of their directions, distinct from every other stream of aobake
STREAM_JOINT = 0x5EED_0027
STREAM_JOINT_BOUNCE = 0x5EED_0028
STREAM_JOINT_DIRECTIONS = 0x5EED_0029
#: AO rays traced at once (a block of whole pixels, or a piece of one pixel's rays beyond
#: it): arrays of a few MB (measured: 2^16 a little faster than 2^13-2^15, as fast as
#: 2^17); a constant, never derived from the threads, so that each pixel's sums are taken
#: in the same order in every run
BLOCK_RAYS = 1 << 16
#: AO rays per position (sobol, stratified): the most, where a replicate has that many
RAYS_PER_POSITION = 4
#: the fewest positions a replicate shares its rays among: fewer rays, and each position
#: casts fewer (one position per replicate with 4 rays made a replicate's mean a mixture of
#: a pixel's parts, and the t interval over 4 of them covered a step's mean in 80% of
#: pixels; tests/test_view_box_stratified.py)
MIN_POSITIONS = 4
#: the fewest positions per slot (on average over a block) the compiled ray generator is
#: called for, one call per slot (fewer: numpy builds the rays, the same bits)
KERNEL_POSITIONS = 16
#: the compiled ray generator's code of each weighting (aobake/_rays.c's ``weighting``: 0
#: cosine, 1 uniform; tests/test_view_box_stratified.py checks its rays against numpy's)
WEIGHTING_CODES = {"cosine": 0, "uniform": 1}
_FAR = np.float32(3.0e38)
#: |n . d| below which a primary ray is taken for grazing its triangle: its hit is then
#: Embree's distance, not the plane's
_GRAZING = 1e-9


@dataclass(frozen=True)
class Joint:
    """The joint estimator of a box-filtered view: ``groups`` replicates of ``per_group``
    AO rays per pixel (``sampler``'s split of ``--rays``), ``rays_per_position`` of them
    from each position's hit; i.i.d. for ``--sampler random``."""

    sampler: str
    groups: int
    per_group: int
    iid: bool
    grid: tuple
    rays_per_position: int

    name = "box"
    box = True
    estimator = "joint"

    @classmethod
    def of(cls, config) -> "Joint":
        samples = sample_set(config.sampler, config.rays, config.replicates)
        r = 1  # the largest power of two <= RAYS_PER_POSITION that leaves enough positions
        while not samples.iid and 2 * r <= RAYS_PER_POSITION and samples.m % (2 * r) == 0 \
                and samples.m // (2 * r) >= MIN_POSITIONS:
            r *= 2
        return cls(samples.name, samples.groups, samples.m, samples.iid, samples.grid, r)

    @property
    def rays(self) -> int:
        """AO rays per pixel."""
        return self.groups * self.per_group

    @property
    def per_replicate(self) -> int:
        """Positions per replicate."""
        return self.per_group // self.rays_per_position

    @property
    def positions(self) -> int:
        """Positions (primary rays) per pixel."""
        return self.groups * self.per_replicate

    @property
    def position_grid(self) -> tuple:
        """(nx, ny) the stratified sampler's grid of a replicate's positions."""
        from aobake.samplers.stratified import grid

        return grid(self.per_replicate) if self.sampler == "stratified" else (0, 0)

    @property
    def gbuffer(self) -> str:
        return ("the hit of the ray through the pixel's centre; where it sees nothing and "
                "a position does, the covered position nearest the centre; empty where no "
                "position sees the scene")

    def record(self, rays_per_position: int | None = None) -> dict:
        """The camera record's ``pixel_footprint`` (the positions estimator's keys, and
        ``estimator``)."""
        how = {"sobol": "Owen-scrambled Sobol nets, one of the positions and one of the "
                        "directions (a position's rays an aligned block of its points), "
                        "paired by a random shuffle of the positions",
               "stratified": "a jittered grid of the positions and one of the directions, "
                             "its cells in a random order",
               "random": "i.i.d. positions and directions, one ray per position"}
        r = self.rays_per_position
        where = (f"{self.rays} AO rays per pixel from {self.positions} positions "
                 f"({r} ray{'s' if r > 1 else ''} from each position's hit): "
                 + (how["random"] if self.iid else
                    f"{self.groups} independent replicates of {self.per_replicate} "
                    f"positions and {self.per_group} rays, {how[self.sampler]}"))
        stderr = ("the spread of the covered samples' values (n - 1 degrees of freedom, n "
                  "the covered samples)" if self.iid else
                  "the spread of the replicates' ratio sum(values) / covered rays "
                  "(linearised: sqrt(sum_g (Y_g - v C_g)^2 / (G (G - 1) Cbar^2)), G - 1 "
                  "degrees of freedom)")
        return {"estimator": "joint", "positions": self.positions, "groups": self.groups,
                "grid": list(self.position_grid) if self.sampler == "stratified" else None,
                "iid": self.iid, "rays_per_position": r, "where": where,
                "value": "the mean over the AO rays of the covered positions: the mean of "
                         "the AO over the part of the pixel that sees the scene (a "
                         "renderer's AO with alpha, unpremultiplied: times coverage is the "
                         "premultiplied value)",
                "coverage": "the fraction of the positions whose primary rays hit the scene",
                "stderr": stderr, "gbuffer": self.gbuffer}


def receiving_faces(scene, config) -> np.ndarray | None:
    """(f,) bool the faces of ``scene`` that are baked (not ``--occluder-only``), or None
    when every face is: the selection ``aobake.groups.apply`` made, matched again on the
    scene it made (whose names are those of the faces it kept)."""
    patterns = tuple(config.occluder_only or ())
    if not patterns:
        return None
    from aobake import groups

    occluder_only = np.zeros(len(scene.faces), dtype=bool)
    for pattern in patterns:
        occluder_only |= groups.match(scene, pattern)
    return ~occluder_only if occluder_only.any() else None


class _Context:
    """What every block of a view's joint samples reads (built once per view)."""

    def __init__(self, scene, config, built, cam, joint: Joint, receiving):
        from aobake.backends.union import query_name

        self.scene, self.config, self.built, self.cam, self.joint = (scene, config, built,
                                                                       cam, joint)
        self.key = hash_key(config.seed, STREAM_JOINT)
        self.bounce_key = hash_key(config.seed, STREAM_JOINT_BOUNCE)
        self.direction_key = hash_key(config.seed, STREAM_JOINT_DIRECTIONS)
        # the directions of a replicate's rays are the ray-traced method's own samples of
        # one replicate of m rays (aobake.samplers, aobake.rays): built by the compiled ray
        # generator where it has the case (sobol, random), else by numpy, the same bits
        self.samples = sample_set(joint.sampler, joint.per_group, 1)
        from aobake import _native

        compiled = _native.kernels()
        self.kernels = compiled if joint.sampler in ("sobol", "random") else None
        self.weighting_code = WEIGHTING_CODES.get(config.weighting)
        if self.weighting_code is None:
            self.kernels = None
        self.compiled = False  # set where the kernel built rays
        # the primary rays of sobol positions, compiled (``aobake._kernels.pixel_rays``,
        # the numpy below bit for bit) where their net is one table for every pixel
        self.pixel_kernel, self.net = None, None
        # the AO rays from the primary hits, compiled (``aobake._kernels.box_rays``: ``hits``
        # and ``_ao_rays`` below, bit for bit) where the ray generator has the case and,
        # for sobol, the replicate's whole net is one table
        self.box_kernel = None
        if self.kernels is not None and (joint.sampler == "random"
                                         or len(self.samples.table) >= joint.per_group):
            self.box_kernel = compiled
        if compiled is not None and joint.sampler == "sobol" \
                and joint.per_replicate <= joint_samples.CACHED_NET:
            self.pixel_kernel = compiled
            self.net = np.ascontiguousarray(
                np.stack(joint_samples.net_reversed(joint.per_replicate), axis=1))
        self.eye = np.asarray(cam.eye, dtype=np.float64)
        self.eye32 = built.to_local(self.eye[None, :]).astype(np.float32)
        self.half_h = cam.tan_half_fov
        self.half_w = self.half_h * cam.aspect
        self.right, self.up_vector, self.forward = (np.asarray(v, dtype=np.float64) for v in
                                                    (cam.right, cam.up, cam.forward))
        self.basis = np.ascontiguousarray(np.stack([self.right, self.up_vector, self.forward]))
        # per face: the unit normal, the plane's distance along it from the eye
        # (n . (v0 - eye): a ray's hit is eye + (w / n.d) d) and the ray offset's scale
        normals = np.asarray(scene.face_normals, dtype=np.float64)
        v0 = scene.vertices[scene.faces[:, 0]]
        areas = scene.areas()
        self.faces = np.empty((len(normals), 5))
        self.faces[:, :3] = normals
        self.faces[:, 3] = np.einsum("ij,ij->i", normals, v0 - self.eye)
        self.faces[:, 4] = np.sqrt(2.0 * areas) * built.scale
        self.ground_size = math.sqrt(2.0 * float(np.median(areas))) * built.scale
        self.up = AXES.index(config.up_axis)
        self.receiving = receiving
        self.quantities = [QUANTITIES[q] for q in config.quantities]
        self.max_distance = config.resolve_max_distance(built.diagonal)
        self.tmax = np.float32(min(self.max_distance * built.scale, 3.0e38))
        self.query = query_name("obscurance" in config.quantities, config.backfaces)
        self.tau = config.resolve_tau(built.diagonal) / built.scale  # per local unit
        self.warp = WEIGHTINGS[config.weighting]

    def reachable(self) -> np.ndarray | None:
        """(P,) bool: the pixels whose footprint some triangle's projection may overlap, a
        superset of the pixels any primary ray hits; None where every pixel is to be traced
        (a ground plane, or a triangle reaching the eye's plane).

        Why: a ray through a pixel that no triangle's projection overlaps misses, and a
        miss costs Embree about what a hit does (about half the pixel stage where most of
        the image is background); a pixel left out gets the sums all misses give (zeros),
        so the results are the same bits.  Conservative: each triangle's projected bounding
        box (from float64 world coordinates) grown by a margin of a pixel and more, far
        beyond the float32 rays' and Embree's own rounding (their directions' relative
        error, ~1e-7, is ~1e-7 w / half_w pixels)."""
        cam, built = self.cam, self.built
        if built.ground is not None:
            return None
        rel = np.asarray(self.scene.vertices, dtype=np.float64) - self.eye
        z = rel @ self.forward
        if not np.all(np.isfinite(z)):
            return None
        faces = self.scene.faces
        # per face, column by column (a reduction over axis 1 of length 3 is numpy's slow case)
        near = np.finfo(np.float64).eps * 64 * float(np.abs(rel).max())
        ahead = [z[faces[:, c]] > near for c in range(3)]
        front = ahead[0] & ahead[1] & ahead[2]
        # triangles wholly behind the eye's plane are never hit (d . forward > 0); one
        # reaching it projects without bound: trace everything
        if np.any((ahead[0] | ahead[1] | ahead[2]) & ~front):
            return None
        z = np.where(z > near, z, 1.0)
        x = ((rel @ self.right / z) / self.half_w + 1.0) * (cam.width / 2.0)
        y = (1.0 - (rel @ self.up_vector / z) / self.half_h) * (cam.height / 2.0)
        corners = [faces[front, c] for c in range(3)]
        xs, ys = [x[c] for c in corners], [y[c] for c in corners]
        margin = 1.0 + 1e-4 * max(cam.width / self.half_w, cam.height / self.half_h)
        x0 = np.floor(np.minimum(np.minimum(xs[0], xs[1]), xs[2]) - margin)
        x1 = np.floor(np.maximum(np.maximum(xs[0], xs[1]), xs[2]) + margin)
        y0 = np.floor(np.minimum(np.minimum(ys[0], ys[1]), ys[2]) - margin)
        y1 = np.floor(np.maximum(np.maximum(ys[0], ys[1]), ys[2]) + margin)
        w, h = cam.width, cam.height
        inside = (x1 >= 0) & (x0 <= w - 1) & (y1 >= 0) & (y0 <= h - 1)
        x0, x1 = (np.clip(v[inside], 0, w - 1).astype(np.int64) for v in (x0, x1))
        y0, y1 = (np.clip(v[inside], 0, h - 1).astype(np.int64) for v in (y0, y1))
        # the boxes' union by a 2-D difference array: +1 / -1 at their corners, summed
        stride = w + 1
        size = (h + 1) * stride
        plus = np.bincount(np.concatenate([y0 * stride + x0, (y1 + 1) * stride + x1 + 1]),
                           minlength=size)
        minus = np.bincount(np.concatenate([y0 * stride + x1 + 1, (y1 + 1) * stride + x0]),
                            minlength=size)
        count = (plus - minus).reshape(h + 1, stride).cumsum(axis=0).cumsum(axis=1)
        return (count[:h, :w] > 0).reshape(-1)

    def directions(self, pixels: np.ndarray, ux: np.ndarray, uy: np.ndarray) -> np.ndarray:
        """(N, 3) float64 unit world directions through positions (ux, uy) (N,) of pixels
        ``pixels`` (N,) int64 (``camera.directions_through``'s arithmetic, written per
        element: a row's bits do not depend on the rows beside it)."""
        cam = self.cam
        row, column = np.divmod(pixels, cam.width)
        vx = ((column + ux) * (2.0 / cam.width) - 1.0) * self.half_w
        vy = (1.0 - (row + uy) * (2.0 / cam.height)) * self.half_h
        d = np.empty((len(vx), 3))
        for axis in range(3):  # view (vx, vy, -1) -> world: vx right + vy up + forward
            d[:, axis] = (vx * self.right[axis] + vy * self.up_vector[axis]) \
                + self.forward[axis]
        norm = np.sqrt((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2])
        d /= norm[:, None]
        return d

    def primary(self, pixels: np.ndarray, keys: np.ndarray, q0: int, count: int):
        """Slots q0 .. q0 + count - 1 of every replicate of ``pixels`` (k,) int64, whose
        replicate keys are ``keys`` (k, R) uint64: (where (k R count, 2) float64 each position
        in its pixel, directions (k R count, 3) float64 the unit ray through it, float32
        the same rounded), rows pixel-major, then replicate, then slot."""
        joint = self.joint
        if self.pixel_kernel is not None:
            n = keys.size * count
            where, directions = np.empty((n, 2)), np.empty((n, 3))
            directions32 = np.empty((n, 3), dtype=np.float32)
            cam = self.cam
            self.pixel_kernel.pixel_rays(
                np.ascontiguousarray(pixels, dtype=np.int64), np.ascontiguousarray(keys),
                self.net, joint.groups, q0, count, joint.per_replicate, cam.width,
                cam.height, 2.0 / cam.width, 2.0 / cam.height, self.half_w, self.half_h,
                self.basis, where, directions, directions32)
            self.compiled = True  # (the report's kernels: ray generation ran compiled)
            return where, directions, directions32
        where = joint_samples.positions(joint.sampler, keys, joint_samples.seeds(keys), q0,
                                        count, joint.per_replicate, joint.position_grid)
        where = where.reshape(-1, 2)  # (k R count, 2), pixel-major, then replicate, then q
        owner = np.repeat(pixels, joint.groups * count)
        directions = self.directions(owner, where[:, 0], where[:, 1])
        return where, directions, directions.astype(np.float32)

    def first_hits(self, directions: np.ndarray, directions32: np.ndarray | None = None):
        """(t (N,) float32 local, prim (N,) int64, ground (N,) bool) of primary rays
        ``directions`` (N, 3) float64 (``directions32``: the same as float32, if made)."""
        if directions32 is None:
            directions32 = directions.astype(np.float32)
        origins = np.broadcast_to(self.eye32, directions32.shape)
        return self.built.nearest(origins, directions32, _FAR)

    def ao_rays(self, directions, t, prim, keys, slots):
        """``hits`` and ``_ao_rays`` of h positions in one compiled pass
        (``aobake._kernels.box_rays``): (origins (h r, 3) float32, directions (h r, 3)
        float32), the rays of position j rows j r .. j r + r - 1.  directions (h, 3)
        float64, t (h,) float32, prim (h,) int64: the positions' primary hits; keys (h,)
        uint64 their replicates' direction keys; slots (h,) int64 their slots."""
        built, joint = self.built, self.joint
        r = joint.rays_per_position
        h = len(t)
        out_o = np.empty((h * r, 3), dtype=np.float32)
        out_d = np.empty((h * r, 3), dtype=np.float32)
        plane = built.ground is not None
        sobol = joint.sampler == "sobol"
        self.box_kernel.box_rays(
            np.ascontiguousarray(directions, dtype=np.float64),
            np.ascontiguousarray(t, dtype=np.float32),
            np.ascontiguousarray(prim, dtype=np.int64), self.faces, self.eye,
            np.ascontiguousarray(built.center, dtype=np.float64), float(built.scale),
            self.up if plane else -1, float(built.ground["height"]) if plane else 0.0,
            float(self.ground_size), float(self.config.ray_offset), float(OFFSET_ULPS),
            np.ascontiguousarray(keys, dtype=np.uint64),
            np.ascontiguousarray(slots, dtype=np.int64),
            self.samples.table if sobol else np.zeros((0, 2), dtype=np.uint32),
            2 if sobol else 0, self.weighting_code, r, joint.per_group, out_o, out_d)
        self.compiled = True
        return out_o, out_d

    def hits(self, directions, t, prim, ground):
        """Where primary rays ``directions`` (h, 3) float64 hit (``first_hits``' t, prim,
        ground): (local (h, 3) float64 the point in the tracer's frame, ng (h, 3) the
        geometric normal facing the eye, sizes (h,) the ray offset's scale, local units).

        The point is on the hit triangle's plane in float64 (the ray's intersection with
        it; Embree's float32 distance where the ray grazes the plane), on the ground
        plane's height for the plane."""
        built = self.built
        h = len(t)
        mesh = prim >= 0
        face = self.faces[np.where(mesh, prim, 0)]  # (h, 5) one gather
        ng = face[:, :3]
        dn = (directions[:, 0] * ng[:, 0] + directions[:, 1] * ng[:, 1]) \
            + directions[:, 2] * ng[:, 2]
        embree = t.astype(np.float64) / built.scale
        with np.errstate(divide="ignore", invalid="ignore"):
            along = np.where(np.abs(dn) > _GRAZING, face[:, 3] / dn, embree)
        along = np.where(np.isfinite(along) & (along > 0), along, embree)
        sizes = face[:, 4]
        if not mesh.all():
            plane = ~mesh
            axis = self.up
            height = built.ground["height"]
            along[plane] = (height - self.eye[axis]) / directions[plane, axis]
            ng[plane] = 0.0
            ng[plane, axis] = 1.0
            dn[plane] = directions[plane, axis]
            sizes[plane] = self.ground_size
        points = self.eye[None, :] + along[:, None] * directions
        if not mesh.all():
            points[~mesh, self.up] = built.ground["height"]
        flip = np.where(dn > 0, -1.0, 1.0)  # the side the eye sees
        ng *= flip[:, None]
        local = (points - built.center) * built.scale
        del h
        return local, ng, sizes


def _offsets(local: np.ndarray, sizes: np.ndarray, fraction: float) -> np.ndarray:
    """``aobake.offsets.point_offsets`` of points with known sizes (the same values)."""
    magnitude = np.maximum(np.maximum(np.abs(local[:, 0]), np.abs(local[:, 1])),
                           np.abs(local[:, 2])) + sizes
    floor = OFFSET_ULPS * np.spacing(magnitude.astype(np.float32)).astype(np.float64)
    return np.maximum(floor, fraction * sizes)


def _ao_rays(ctx: _Context, local, ng, sizes, keys: np.ndarray, slots: np.ndarray, r: int):
    """The AO rays of h covered positions: (origins (h r, 3) float32, directions (h r, 3)
    float32, position (h,) int64: the rays of position ``position[j]`` are rows j r ..
    j r + r - 1).

    local, ng, sizes : ``_Context.hits``' of the positions; keys (h,) uint64 the direction
    keys of their replicates; slots (h,) int64 each one's position index q in its
    replicate: its rays are rays q r .. q r + r - 1 of the replicate's m, sample j of the
    ray-traced method's sampler of m rays (one replicate) on the replicate's key (random:
    one ray per position, on a key of its own).  The compiled ray generator
    (``aobake._kernels.fill_rays``) builds them a slot at a time where it can; the numpy
    formulation below is the same arithmetic, bit for bit (tested)."""
    offsets = _offsets(local, sizes, ctx.config.ray_offset)
    origins = (local + offsets[:, None] * ng).astype(np.float32)
    joint, samples = ctx.joint, ctx.samples
    if joint.sampler == "random":  # one ray per position: its own key, sample 0
        keys = joint_samples.hashes_at(keys, slots[:, None])[:, 0]
        slots = np.zeros_like(slots)
    h = len(origins)
    # one kernel call per slot: where a slot holds few positions (a few pixels per block:
    # thousands of rays per pixel) the calls cost more than numpy (the same bits)
    spread = int(slots.max()) + 1 - int(slots.min()) if h else 1
    if ctx.kernels is not None and h >= KERNEL_POSITIONS * spread:
        ctx.compiled = True  # (what the report's kernels say ran)
        order = np.argsort(slots, kind="stable")  # a slot's positions together
        slots, keys = slots[order], np.ascontiguousarray(keys[order])
        origins, normals = origins[order], np.ascontiguousarray(ng[order])
        bounds = np.flatnonzero(np.diff(slots)) + 1
        out_o = np.empty((h * r, 3), dtype=np.float32)
        out_d = np.empty((h * r, 3), dtype=np.float32)
        m = samples.m if joint.sampler == "sobol" else 1
        for a, b in zip(np.concatenate([[0], bounds]), np.concatenate([bounds, [h]])):
            j0 = int(slots[a]) * r if joint.sampler == "sobol" else 0
            table = samples.table_for(j0, r) if joint.sampler == "sobol" \
                else np.zeros((0, 2), dtype=np.uint32)
            ctx.kernels.fill_rays(origins[a:b], normals[a:b], keys[a:b], table,
                                  samples.kernel, ctx.weighting_code, 0, 0, b - a, 1, m, j0,
                                  r, out_o[a * r:b * r], out_d[a * r:b * r])
        return out_o, out_d, order
    index = slots[:, None] * r + np.arange(r)[None, :]
    u = joint_samples.directions(joint.sampler, keys, index, joint.per_group, joint.grid)
    radius, z = ctx.warp(u[..., 0])  # (h, r)
    c, s = cos_sin_2pi(u[..., 1])
    x, y = radius * c, radius * s
    # the frame of each normal (``aobake.warp.frames``, Duff et al. 2017), per component
    nx, ny, nz = (ng[:, a, None] for a in range(3))
    sign = np.where(nz >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    tangent = (1.0 + sign * nx * nx * a, sign * b, -sign * nx)
    bitangent = (b, sign + ny * ny * a, -ny)
    normal = (nx, ny, nz)
    rays = np.empty(x.shape + (3,), dtype=np.float32)
    for axis in range(3):
        rays[..., axis] = (x * tangent[axis] + y * bitangent[axis]) + z * normal[axis]
    return np.repeat(origins, r, axis=0), rays.reshape(-1, 3), np.arange(h)


def _item(ctx: _Context, pixels: np.ndarray, i0: int, count: int, gather: np.ndarray) -> dict:
    """Rays i0 .. i0 + count - 1 (a multiple of r each) of every replicate of ``pixels``
    (k,) int64, and their positions: per pixel and replicate the sums of each quantity's
    ray values (``y``: name -> (k, R)) and the rays cast (``c`` (k, R)); per pixel the
    positions whose primary ray hits (``hits`` (k,)); for i.i.d. samples each quantity's
    squared deviations about the piece's mean (``m2``); and for the pixels ``gather``
    (k,) bool (centre ray missed) their covered position nearest the centre (``near``:
    pixel, d2, index, u)."""
    joint, built = ctx.joint, ctx.built
    groups, r = joint.groups, joint.rays_per_position
    k = len(pixels)
    q0, per = i0 // r, count // r  # positions of the item, per replicate
    keys = replicate_keys(ctx.key, pixels, groups)
    where, directions, directions32 = ctx.primary(pixels, keys, q0, per)
    owner = np.repeat(pixels, groups * per)
    t, prim, ground = ctx.first_hits(directions, directions32)
    hit = np.isfinite(t)
    out = {"hits": hit.reshape(k, groups * per).sum(axis=1), "near": None}
    if gather.any():
        want = np.flatnonzero(hit & np.repeat(gather, groups * per))
        if len(want):
            d2 = np.square(where[want, 0] - 0.5) + np.square(where[want, 1] - 0.5)
            within = want % (groups * per)  # (g, q) of the item: position g P + q0 + q
            index = (within // per) * joint.per_replicate + q0 + within % per
            who = owner[want]
            order = np.lexsort((index, d2, who))
            first = np.ones(len(order), dtype=bool)
            first[1:] = who[order][1:] != who[order][:-1]
            chosen = order[first]
            out["near"] = {"pixel": who[chosen], "d2": d2[chosen], "index": index[chosen],
                           "u": where[want][chosen]}
    traced = hit
    if ctx.receiving is not None:
        traced = hit.copy()
        on_mesh = np.flatnonzero(hit & (prim >= 0))
        traced[on_mesh] = ctx.receiving[prim[on_mesh]]
    cast = np.flatnonzero(traced)
    n_rays = k * groups * count
    values = {q.name: np.zeros(n_rays) for q in ctx.quantities}
    if len(cast):
        # the covered positions' rays: replicate (pixel, g) = cast div per, position q0 +
        # cast mod per (the uncovered ones' samples are not drawn)
        replicate = cast // per
        directions_keys = replicate_keys(ctx.direction_key, pixels, groups).reshape(-1)
        if ctx.box_kernel is not None:  # hits, offsets and rays in one compiled pass
            origins, rays = ctx.ao_rays(directions[cast], t[cast], prim[cast],
                                        directions_keys[replicate], q0 + cast % per)
            order = np.arange(len(cast))
        else:
            local, ng, sizes = ctx.hits(directions[cast], t[cast], prim[cast], ground[cast])
            origins, rays, order = _ao_rays(ctx, local, ng, sizes, directions_keys[replicate],
                                            q0 + cast % per, r)
        occluded, distance = built.trace(ctx.query, origins, rays, ctx.tmax)
        cast_in_order = cast[order]
        ray_index = ((q0 + cast_in_order % per) * r)[:, None] + np.arange(r)[None, :]
        rows = (cast_in_order[:, None] * r + np.arange(r)[None, :]).reshape(-1)
        for q in ctx.quantities:
            if q.name == "ao":
                v = np.logical_not(occluded).astype(np.float64)
            elif q.name == "obscurance":
                from aobake.quantities.obscurance import rho

                v = rho(distance, ctx.tau).astype(np.float64)
            else:  # indirect: the path beyond each AO ray's hit
                from aobake.paths import path_values

                bounce = replicate_keys(ctx.bounce_key, pixels, groups).reshape(-1)
                hashes = joint_samples.hashes_at(bounce[cast_in_order // per],
                                                 ray_index).reshape(-1)
                v = path_values(built, ctx.scene, hashes, origins, rays, ctx.tmax,
                                ctx.config.albedo, ctx.config.bounces, ctx.config.ray_offset)
            values[q.name][rows] = v
    mask = np.repeat(traced, r).reshape(k, groups, count)
    counts = mask.sum(axis=2).astype(np.float64)
    out["c"], out["y"], out["m2"] = counts, {}, {}
    for q in ctx.quantities:
        full = values[q.name].reshape(k, groups, count)
        sums = full.sum(axis=2)
        out["y"][q.name] = sums
        if joint.iid:
            mean = sums / np.maximum(counts, 1)
            deviation = np.where(mask, full - mean[..., None], 0.0)
            out["m2"][q.name] = np.square(deviation).sum(axis=2)
    return out


def items(joint: Joint, n_pixels: int) -> list:
    """The work of a view: (first pixel, last pixel + 1, i0, count) blocks of whole pixels
    (``BLOCK_RAYS`` rays at most), or pieces of one pixel's rays where one pixel has more
    (i0 and count multiples of r); a function of (the rays, the pixels) alone."""
    per_pixel = joint.rays
    if per_pixel <= BLOCK_RAYS:
        block = max(1, BLOCK_RAYS // per_pixel)
        return [(a, min(n_pixels, a + block), 0, joint.per_group)
                for a in range(0, n_pixels, block)]
    piece = 1 << (max(1, BLOCK_RAYS // joint.groups).bit_length() - 1)
    piece = max(piece, joint.rays_per_position)  # a power of two: a multiple of r
    m = joint.per_group
    return [(p, p + 1, i0, min(piece, m - i0)) for p in range(n_pixels)
            for i0 in range(0, m, piece)]


def _reachable_only(ctx: _Context, pixels, reachable, i0: int, count: int, gather) -> dict:
    """``_item`` of ``pixels`` (k,) with the rays of the pixels not ``reachable`` (k,) bool
    left uncast: their sums are those of rays that all miss (zeros), the same bits."""
    groups, names = ctx.joint.groups, [q.name for q in ctx.quantities]
    k = len(pixels)
    out = {"hits": np.zeros(k, dtype=np.int64), "near": None, "c": np.zeros((k, groups)),
           "y": {name: np.zeros((k, groups)) for name in names},
           "m2": {name: np.zeros((k, groups)) for name in names} if ctx.joint.iid else {}}
    if not reachable.any():
        return out
    part = _item(ctx, pixels[reachable], i0, count, gather[reachable])
    out["hits"][reachable] = part["hits"]
    out["near"] = part["near"]
    out["c"][reachable] = part["c"]
    for key in ("y", "m2"):
        for name, value in part[key].items():
            out[key][name][reachable] = value
    return out


def trace(scene, config, built, cam, joint: Joint, threads: int, centre_hit: np.ndarray,
          receiving=None, cull: bool = True) -> dict:
    """Every pixel's sums over all its rays (``_item``'s): y name -> (P, R), c (P, R), hits
    (P,), m2 name -> (P, R) for i.i.d. samples; ``near``: pixel -> (2,) the position of the
    covered position nearest the centre of each pixel whose centre ray missed; and the
    ``context``.  ``cull``: leave uncast the rays of pixels no triangle can reach
    (``_Context.reachable``; the same sums: False only to test that)."""
    from aobake.trace import run_chunks

    n_pixels = cam.height * cam.width
    ctx = _Context(scene, config, built, cam, joint, receiving)
    work_items = items(joint, n_pixels)
    gather = ~np.asarray(centre_hit, dtype=bool)
    groups = joint.groups
    names = [q.name for q in ctx.quantities]
    y = {name: np.zeros((n_pixels, groups)) for name in names}
    m2 = {name: np.zeros((n_pixels, groups)) for name in names} if joint.iid else {}
    c = np.zeros((n_pixels, groups))
    hits = np.zeros(n_pixels, dtype=np.int64)
    best: dict = {}
    pending: dict = {}
    state = {"next": 0}

    def fold(i, part):
        a, b = work_items[i][:2]
        if joint.iid:  # Chan et al.'s pairwise update, piece by piece
            na, nb = c[a:b], part["c"]
            both = (na > 0) & (nb > 0)
            safe = np.maximum(na + nb, 1)
            for name in names:
                delta = part["y"][name] / np.maximum(nb, 1) - y[name][a:b] / np.maximum(na, 1)
                extra = np.where(both, np.square(delta) * na * nb / safe, 0.0)
                m2[name][a:b] = m2[name][a:b] + part["m2"][name] + extra
        for name in names:
            y[name][a:b] += part["y"][name]
        c[a:b] += part["c"]
        hits[a:b] += part["hits"]
        near = part["near"]
        if near is not None:
            for p, d2, index, u in zip(near["pixel"].tolist(), near["d2"].tolist(),
                                       near["index"].tolist(), near["u"]):
                if p not in best or (d2, index) < best[p][:2]:
                    best[p] = (d2, index, u)

    reachable = ctx.reachable() if cull else None

    def work(i):
        a, b, i0, count = work_items[i]
        pixels = np.arange(a, b, dtype=np.int64)
        if reachable is None or reachable[a:b].all():
            return _item(ctx, pixels, i0, count, gather[a:b])
        return _reachable_only(ctx, pixels, reachable[a:b], i0, count, gather[a:b])

    def land(i, part):
        pending[i] = part
        while state["next"] in pending:  # in item order, whatever the arrival order
            fold(state["next"], pending.pop(state["next"]))
            state["next"] += 1

    run_chunks(len(work_items), work, land, max(1, int(threads)))
    return {"y": y, "c": c, "hits": hits, "m2": m2,
            "near": {p: value[2] for p, value in best.items()}, "context": ctx}


def nearest_hits(ctx: _Context, near: dict):
    """The primary hits of the chosen positions ``near`` (pixel -> (2,)): (pixels (h,)
    int64 ascending, directions (h, 3) float64, t (h,) float64 scene units, prim (h,),
    ground (h,)), the same rays as the samples'."""
    pixels = np.array(sorted(near), dtype=np.int64)
    u = np.array([near[p] for p in pixels.tolist()], dtype=np.float64).reshape(-1, 2)
    directions = ctx.directions(pixels, u[:, 0], u[:, 1])
    t, prim, ground = ctx.first_hits(directions)
    return pixels, directions, t.astype(np.float64) / ctx.built.scale, prim, ground


def pool(config, joint: Joint, sums: dict, covered: np.ndarray, diagonal: float):
    """The covered pixels' fields (name -> (k,) float64, pixel order) and rays (k,) int64
    from ``trace``'s sums; ``covered`` (k,) int64 the pixels some position hits.

    As the positions estimator's ``pool``: the ratio estimator's stderr from the replicates
    (``stats.ratio_spread``; i.i.d.: the rays' spread), and the interval's rule of three
    over the pixel's covered *positions*, not its rays. Why positions: a replicate's
    positions are a stratified set, and an edge that crosses the pixel along one of its
    strata (an axis-aligned step) leaves each replicate with one of two counts on either
    side, so the replicates may all agree and their spread miss the positions' error (up to
    the step's height over the positions per replicate); the floor h0 over positions covers
    that, as it covers a sliver none of the positions landed on. (Over rays it did not: a
    step at 35% of the pixel's width, the default 256 rays, 84% coverage; over
    positions, tests/test_view_box_stratified.py.)"""
    c = sums["c"][covered]
    counted = c.sum(axis=1)  # the rays of the covered positions that cast
    blind = counted == 0  # covered pixels none of whose positions cast rays
    rays_seen = np.maximum(counted, 1)
    places = np.maximum(counted / joint.rays_per_position, 1.0)  # their positions
    exact = config.resolve_max_distance(diagonal) == 0
    per_pixel = counted.astype(np.int64)
    fields = {}
    for quantity in config.quantities:
        q = QUANTITIES[quantity]
        names = [q.value.name, q.error.name] + [f.name for f in (q.interval or ())]
        y = sums["y"][quantity][covered]
        mean = y.sum(axis=1) / rays_seen
        if joint.iid:
            dof = counted - 1
            se = np.sqrt(sums["m2"][quantity][covered].sum(axis=1) / np.maximum(dof, 1)
                         / rays_seen)
        else:
            se, dof = stats.ratio_spread(y, c, mean)
        error = stats.pooled_error_bars(mean, se, dof, places, per_pixel, exact,
                                        config.confidence)
        columns = (mean,) + tuple(error)
        nothing = (0.5, 0.5, 0.0, 1.0)  # no information: a pixel whose positions cast none
        for name, array, blank in zip(names, columns, nothing):
            fields[name] = np.where(blind, blank, array)
    return fields, per_pixel
