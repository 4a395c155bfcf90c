"""Camera target (``aobake view``): primary rays through the pixels, a G-buffer, and the
method's values at the first hits.

``--pixel-filter center`` (the default): one primary ray per pixel centre, no jitter
(``aobake.camera``).  At each first hit the method estimates about the *geometric* normal
turned to face the eye (a two-sided surface seen from either side has AO on the side the
camera sees).  The sample-stream id of a pixel is its index r * W + c, so a pixel's value
equals ``bake_points`` at its hit point with that id and the same seed.

``--pixel-filter box``: the value estimates the mean of the AO over the pixel's area, as a
renderer that averages its samples over the pixel does.  With the ray-traced method and
``--box-sampling joint`` (the default) the target traces every pixel's samples itself:
positions in the pixel and their AO rays' directions stratified together, in bulk
(``aobake.targets.view_box``; the method is handed no points, ``finish`` pools the sums).
Otherwise (``--box-sampling positions``, and every method that casts no rays: the target
is told the method by ``uses_method``) each pixel casts
``--pixel-samples`` primary rays at positions inside it (:class:`Footprint`: R independent
jittered grids, or i.i.d. positions with ``--sampler random``; a pure function of (seed,
pixel, position) through ``aobake.rng``), each position that sees the scene is a sample
point with its own rays (``--rays`` split over the positions; stream id r W + c times the
positions plus the position), and ``finish`` pools them (:func:`pool`): the mean over the
covered positions, ``coverage`` the fraction of positions that see the scene, and a stderr
measured from the positions' spread, so it counts where in the pixel the rays went.  The
G-buffer stays at the pixel's centre (where the centre sees nothing but a position does:
the covered position nearest the centre).

Every channel is float32 (H, W), row 0 = top.  Where ``coverage`` is 0 (the pixel sees
nothing) every channel is 0, except the hardware depths (the cleared depth buffer's
value: 1 for OpenGL and Direct3D, 0 for reversed-Z) and the ids (-1): no inf or NaN in
any output.  Conventions: docs/conventions.md ("Camera views").
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from aobake import camera as cameras
from aobake import stats
from aobake.constants import AXES
from aobake.errors import InputError, UsageError
from aobake.hits import on_triangle, shading_normals
from aobake.quantities import FIELDS, QUANTITIES
from aobake.records import Finished, SamplePoints, ViewResult
from aobake.settings import DEFAULTS

#: the G-buffer channels, in the EXR's order (the method's fields follow)
GBUFFER = ("coverage", "depth", "distance", "hwdepth_gl", "hwdepth_d3d", "hwdepth_reversed",
           "P.X", "P.Y", "P.Z", "Ng.X", "Ng.Y", "Ng.Z", "N.X", "N.Y", "N.Z",
           "object_id", "primitive_id")
#: object ids: what a pixel sees
OBJECTS = {"none": -1, "mesh": 0, "ground_plane": 1}
#: ids are stored as float32: exact up to this many triangles
EXACT_IDS = 1 << 24
#: a view in which more of the covered pixels see back faces than this is taken for a
#: camera inside a closed mesh (a warning: an open or one-sided model can be seen so too)
INSIDE_FRACTION = 0.5


class ViewTarget:
    """The pixels of one camera.

    camera : ``aobake.camera.Camera`` | None (None: ``default_camera`` framing the scene),
    look : dict(look_from, look_at, up, fov) for a look-at camera (near/far fitted to the
    scene), gltf : (path, name | None) for a glTF camera node, size : (W, H) pixels.
    Give at most one of camera, look and gltf.
    """

    name = "view"

    def __init__(self, camera=None, *, look: dict | None = None, gltf=None,
                 size=cameras.DEFAULT_SIZE, fov: float = 40.0):
        given = [x is not None for x in (camera, look, gltf)]
        if sum(given) > 1:
            raise InputError("view: give one camera (a Camera, --look-from/--look-at, or "
                             "--camera), not several")
        if camera is not None and not isinstance(camera, cameras.Camera):
            raise InputError(f"view: camera must be an aobake.camera.Camera (made by "
                             f"aobake.camera.look_at), got {_shown(camera)}")
        self.camera, self.look, self.gltf = camera, _look(look), _gltf(gltf)
        self.size, self.fov = cameras.check_size(size), fov

    #: the method that will estimate this view's values (``uses_method``), or None when
    #: not told: a box filter then samples as ``--box-sampling`` says
    method = None

    def uses_method(self, method: str) -> None:
        """Told by ``aobake.api.run`` which method estimates the values: the joint box
        estimator is the ray-traced method's (a method that casts no rays averages its
        values over positions)."""
        self.method = method

    def footprint(self, config):
        """Where this view's primary rays go: ``Footprint`` (the centre, or the positions
        of a box filter) or ``view_box.Joint`` (the joint box estimator)."""
        if config.pixel_filter != "box":
            return Footprint.centre()
        if config.box_sampling == "joint" and self.method in (None, "rays"):
            from aobake.targets.view_box import Joint

            return Joint.of(config)
        return Footprint.of(config)

    def rays_per_point(self, config) -> int:
        """Rays per pixel (joint box estimator: the pixel's AO rays, ``--rays`` as the
        sampler rounds it), or per position of a box-filtered pixel (``--rays`` split over
        its ``--pixel-samples`` positions, rounded up)."""
        footprint = self.footprint(config)
        if footprint.estimator == "joint":
            return footprint.rays
        if footprint.box:
            return -(-config.rays // footprint.positions)
        return config.rays

    def resolve(self, scene, config) -> cameras.Camera:
        """The camera of this view for ``scene``, with near/far."""
        lo, hi = scene.bounds
        if self.camera is not None:
            cam = self.camera
        elif self.look is not None:
            cam = cameras.look_at(self.look["look_from"], self.look["look_at"],
                                  self.look.get("up", _up(config)), self.look.get("fov", self.fov),
                                  size=self.size)
        elif self.gltf is not None:
            path, name = self.gltf
            cam = cameras.gltf_camera(path, name, size=self.size)
        else:
            return cameras.default_camera(lo, hi, self.size, self.fov, up_axis=config.up_axis)
        _check_reach(scene, cam)
        if cam.near is None or cam.far is None:
            cam = cameras.fit_clip(cam, lo, hi)
        return cam

    def sample(self, scene, config, occluders, threads, timings, warnings,
               phase=None) -> SamplePoints:
        clock = time.perf_counter()
        cam = self.resolve(scene, config)
        origins, directions = cam.pixel_rays()
        built = occluders()  # primary rays need the occluders: wait for their build
        t, prim, ground = built.first_hits(origins, directions)
        hit = np.isfinite(t)
        index = np.flatnonzero(hit)
        centre = _surface(scene, config, built, cam.eye, directions[index], t[index],
                          prim[index], ground[index], shading=True)
        box = config.pixel_filter == "box"
        footprint = self.footprint(config)
        if not box and config.pixel_samples != DEFAULTS["pixel_samples"]:
            warnings.append(f"--pixel-samples {config.pixel_samples} is for --pixel-filter "
                            "box: a centre-filtered view casts one primary ray per pixel")
        if footprint.estimator == "joint" \
                and config.pixel_samples != DEFAULTS["pixel_samples"]:
            warnings.append(f"--pixel-samples {config.pixel_samples} is for --box-sampling "
                            f"positions: the joint estimator casts {footprint.rays} AO rays "
                            f"per pixel from {footprint.positions} positions (--rays sets "
                            "both)")
        if not hit.any() and not box:
            raise InputError(f"{scene.source}: the view sees nothing (no pixel's ray hits the "
                             "scene): check --look-from/--look-at/--fov")
        back_seen = int(np.count_nonzero(centre["back"] & (centre["faces"] >= 0)))
        if back_seen > INSIDE_FRACTION * len(index):
            warnings.append(f"{scene.source}: {back_seen} of {len(index)} covered pixels see the "
                            "back of a face: is the camera inside a closed mesh? (their AO is "
                            "taken on the side the camera sees)")
        if len(scene.faces) > EXACT_IDS:
            warnings.append(f"{scene.source}: {len(scene.faces)} triangles: primitive_id is "
                            f"float32, exact only below {EXACT_IDS}")
        if footprint.estimator == "joint":
            timings["primary_s"] = time.perf_counter() - clock
            return _joint_plan(scene, config, built, cam, footprint, index, t[index], centre,
                               threads, timings, phase)
        if box:
            subs = _box_samples(scene, config, built, cam, footprint)
            if not len(subs["pixel"]):
                raise InputError(f"{scene.source}: the view sees nothing (none of the pixels' "
                                 f"{footprint.positions} rays hits the scene): check "
                                 "--look-from/--look-at/--fov")
            gbuffer = _box_gbuffer(scene, cam, index, t[index], centre, subs, footprint)
            state = dict(camera=cam, footprint=footprint, gbuffer=gbuffer, pixel=subs["pixel"],
                         group=subs["group"], hits=subs["hits"])
            timings["primary_s"] = time.perf_counter() - clock
            # screen-space methods read a G-buffer per *point*: these points are positions
            # inside pixels, so they get none (BoxFiltered says why)
            return SamplePoints(subs["points"], subs["ng"], subs["ids"], sizes=subs["sizes"],
                                state=state, faces=subs["faces"], bary=subs["bary"],
                                image=BoxFiltered())
        gbuffer = dict(index=index, t=t[index], prim=prim[index], ground=ground[index],
                       points=centre["points"], ng=centre["ng"], ns=centre["ns"])
        state = dict(camera=cam, footprint=Footprint.centre(), gbuffer=gbuffer)
        # The G-buffer a screen-space method reads (the channels ``finish`` writes).
        from aobake.screen.gbuffer import GBuffer

        image = GBuffer.from_hits(cam, index, centre["points"], centre["ng"], centre["ns"])
        timings["primary_s"] = time.perf_counter() - clock
        return SamplePoints(centre["points"], centre["ng"], index.astype(np.int64),
                            sizes=centre["sizes"], state=state, faces=centre["faces"],
                            bary=centre["bary"], image=image)

    def finish(self, scene, config, plan, estimates, timings, warnings) -> Finished:
        state = plan.state
        cam, footprint, gb = state["camera"], state["footprint"], state["gbuffer"]
        h, w = cam.height, cam.width
        n = h * w
        index = gb["index"]
        channels = {name: np.zeros(n, dtype=np.float32) for name in GBUFFER}
        view = cam.world_to_view()
        rotation = view[:3, :3]
        p_view = (gb["points"] - cam.eye) @ rotation.T
        depth = -p_view[:, 2]
        channels["depth"][index] = depth
        channels["distance"][index] = gb["t"]
        for convention, name in (("opengl", "hwdepth_gl"), ("d3d", "hwdepth_d3d"),
                                 ("reversed", "hwdepth_reversed")):
            full = np.full(n, np.inf)
            full[index] = depth
            channels[name][:] = cameras.hardware_depth(full, cam.near, cam.far, convention)
        for axis, letter in enumerate("XYZ"):
            channels[f"P.{letter}"][index] = p_view[:, axis]
        for key, vectors in (("Ng", gb["ng"]), ("N", gb["ns"])):
            in_view = vectors @ rotation.T
            for axis, letter in enumerate("XYZ"):
                channels[f"{key}.{letter}"][index] = in_view[:, axis]
        objects = np.full(n, OBJECTS["none"], dtype=np.float32)
        objects[index] = np.where(gb["ground"], OBJECTS["ground_plane"], OBJECTS["mesh"])
        channels["object_id"][:] = objects
        channels["primitive_id"][:] = -1.0
        channels["primitive_id"][index] = gb["prim"]
        cast = None if estimates.rays is None else estimates.rays_cast
        if footprint.estimator == "joint":
            from aobake.targets import view_box

            fields, rays = view_box.pool(config, footprint, state["sums"], index,
                                         scene.diagonal)
            channels["coverage"][:] = state["sums"]["hits"] / footprint.positions
            cast = int(rays.sum())
            dark = _dark(fields, rays, scene.source)
            if dark:
                warnings.append(dark)
        elif footprint.box:
            fields, rays = pool(config, footprint, state, estimates, n, scene.diagonal)
            hits = state["hits"]
            channels["coverage"][:] = hits / footprint.positions
        else:
            fields, rays = estimates.fields, estimates.rays
            channels["coverage"][index] = 1.0
        # the pixels with values: every pixel with a G-buffer (box: some position hit)
        covered = np.zeros(n, dtype=bool)
        covered[index] = True
        for name, array in fields.items():
            for c, channel in enumerate(FIELDS[name].exr):
                image = np.zeros(n, dtype=np.float32)
                image[index] = array if array.ndim == 1 else array[:, c]
                channels[channel] = image
        if rays is not None:
            image = np.zeros(n, dtype=np.float32)
            image[index] = rays
            channels["rays"] = image
        images = {name: a.reshape(h, w) for name, a in channels.items()}
        result = ViewResult(images, covered.reshape(h, w), {}, camera=cam)
        record = cam.record()
        record["pixel_filter"] = footprint.name
        record["pixel_footprint"] = footprint.record(self.rays_per_point(config))
        record["gbuffer"] = {"channels": list(images), "empty_pixels":
                             "0 where coverage = 0, except hwdepth_* (the cleared depth: 1, "
                             "reversed 0) and object_id / primitive_id (-1)",
                             "objects": OBJECTS, "normals": "view space, unit; Ng faces the eye",
                             "ids": f"float32, exact below {EXACT_IDS}",
                             "where": footprint.gbuffer}
        rays = rays if rays is not None else np.zeros(len(index), np.int32)
        return Finished(result, fields, rays, n, cast=cast,
                        report={"camera": record, "pixels_covered": int(len(index))},
                        rays_key="rays_per_pixel")

    def check(self, config) -> None:
        """Refuse what a box-filtered view cannot estimate, before anything is loaded."""
        if config.pixel_filter != "box":
            return
        other = [q for q in config.quantities if q not in BOX_QUANTITIES]
        if other:
            raise UsageError(f"--pixel-filter box averages {', '.join(BOX_QUANTITIES)} over "
                             f"the pixel; not -q {', '.join(other)} (use --pixel-filter center)")
        if config.tolerance is not None:
            raise UsageError("--tolerance sets each point's rays for its own interval; a "
                             "box-filtered pixel's error is the spread over its positions: "
                             "not with --pixel-filter box")


#: what a box-filtered pixel can average: the quantities whose value is a scalar in [0, 1]
#: with a stderr and an interval (a bent normal's mean is no unit vector, and thickness has
#: no interval to pool)
BOX_QUANTITIES = ("ao", "obscurance", "indirect")
#: the hash stream of a box filter's positions in its pixels (distinct from every other
#: stream: samplers.base, paths, screen)
STREAM_FOOTPRINT = 0x5EED_0025
#: pixels whose positions are traced at once (about 2^20 rays a block: the primary rays'
#: memory does not grow with the image)
BLOCK_RAYS = 1 << 20
_BELOW_ONE = float(np.nextafter(1.0, 0.0))


class BoxFiltered:
    """What a box-filtered view hands a method instead of a G-buffer: its points are
    positions inside pixels, not pixels, so a screen-space method (which reads one G-buffer
    pixel per point) cannot run on them (``aobake.screen.gbuffer.of`` names this class)."""

    def __repr__(self) -> str:
        return "BoxFiltered (--pixel-filter box: use --pixel-filter center)"


@dataclass(frozen=True)
class Footprint:
    """Where in its pixel each primary ray of a view goes.

    name : ``center`` | ``box``; groups : G independent replicates of ``per_group``
    positions each (positions = G x per_group); grid : (nx, ny) the jittered grid of one
    replicate's positions, (0, 0) for i.i.d. positions; iid : every position independent
    and uniform in the pixel (``--sampler random``).
    """

    name: str
    groups: int
    per_group: int
    grid: tuple
    iid: bool

    @classmethod
    def centre(cls) -> "Footprint":
        return cls("center", 1, 1, (1, 1), False)

    @classmethod
    def of(cls, config) -> "Footprint":
        """The box filter of ``config``: ``pixel_samples`` positions, i.i.d. with an i.i.d.
        sampler, else ``replicates`` jittered grids (rounded up to a multiple of them, as
        ``--rays`` is)."""
        if config.pixel_filter != "box":
            return cls.centre()
        from aobake.samplers import sample_set
        from aobake.samplers.stratified import grid

        wanted = config.pixel_samples
        if sample_set(config.sampler, 2, config.replicates).iid:
            return cls("box", 1, wanted, (0, 0), True)
        groups = max(1, min(config.replicates, wanted))
        per_group = -(-wanted // groups)
        return cls("box", groups, per_group, grid(per_group), False)

    @property
    def box(self) -> bool:
        return self.name == "box"

    @property
    def estimator(self) -> str | None:
        """``positions`` for a box filter (``view_box.Joint`` is the joint one), None for
        the centre."""
        return "positions" if self.box else None

    @property
    def positions(self) -> int:
        """Primary rays per pixel."""
        return self.groups * self.per_group

    @property
    def gbuffer(self) -> str:
        if not self.box:
            return "the hit of the ray through the pixel's centre"
        return ("the hit of the ray through the pixel's centre; where it sees nothing and "
                "a position does, the covered position nearest the centre; empty where no "
                "position sees the scene")

    def record(self, rays_per_position: int) -> dict:
        """The camera record's ``pixel_footprint`` (the same keys for both filters)."""
        if not self.box:
            return {"estimator": None, "positions": 1, "groups": None, "grid": None,
                    "iid": None,
                    "rays_per_position": rays_per_position,
                    "where": "the pixel's centre (c + 0.5, r + 0.5)",
                    "value": "the method's value at the surface point the centre ray hits",
                    "coverage": "1 where the centre ray hits the scene, else 0",
                    "stderr": "the method's, at that point", "gbuffer": self.gbuffer}
        where = ("i.i.d. uniform in the pixel" if self.iid else
                 f"{self.groups} independent jittered {self.grid[0]} x {self.grid[1]} grids "
                 "over the pixel")
        stderr = ("the spread of the covered positions' values (i.i.d.: n - 1 degrees of "
                  "freedom, n the covered positions)" if self.iid else
                  "the spread of the replicates' ratio sum(values) / covered positions "
                  "(linearised: sqrt(sum_g (Y_g - v C_g)^2 / (G (G - 1) Cbar^2)), G - 1 "
                  "degrees of freedom)")
        return {"estimator": "positions", "positions": self.positions,
                "groups": self.groups, "grid": None if self.iid else list(self.grid),
                "iid": self.iid,
                "rays_per_position": rays_per_position, "where": where,
                "value": "the mean over the covered positions of the method's value at each "
                         "one's hit: the mean of the AO over the part of the pixel that sees "
                         "the scene (a renderer's AO with alpha, unpremultiplied: times "
                         "coverage is the premultiplied value)",
                "coverage": "the fraction of the positions whose rays hit the scene",
                "stderr": stderr, "gbuffer": self.gbuffer}

    def offsets(self, seed: int, pixels: np.ndarray) -> np.ndarray:
        """(k, positions, 2) float64 in [0, 1)^2: where in pixels ``pixels`` (k,) int64 (r W +
        c) each primary ray goes, (x right, y down) from the pixel's top-left corner.

        A pure function of (seed, pixel, replicate, position), through the one hash
        (``aobake.rng``) on a stream of its own: replicate g's position j is cell j of its
        grid (x = j mod nx, y = j div nx) jittered by a uniform in the cell; i.i.d.
        positions are the uniforms themselves.  Position index = g x per_group + j.
        """
        from aobake.rng import hash_key
        from aobake.samplers.base import replicate_keys, sample_hashes, uniforms

        keys = replicate_keys(hash_key(seed, STREAM_FOOTPRINT), pixels, self.groups)
        u = uniforms(sample_hashes(keys, 0, self.per_group))  # (k, G, m, 2)
        if not self.iid:
            nx, ny = self.grid
            j = np.arange(self.per_group)
            u[..., 0] = (j % nx + u[..., 0]) / nx
            u[..., 1] = (j // nx + u[..., 1]) / ny
            np.minimum(u, _BELOW_ONE, out=u)  # (cell + jitter) / n may round up to 1
        return u.reshape(len(pixels), self.positions, 2)


def _surface(scene, config, built, eye, directions, t, prim, ground, shading: bool) -> dict:
    """The surface points where rays from ``eye`` (3,) hit: ``directions`` (k, 3) float64 unit,
    ``t`` (k,) their hit distances, ``prim`` (k,) the triangle (-1 on the ground plane),
    ``ground`` (k,) bool.  Returns points (k, 3) float64 on the surface, ng (k, 3) the
    geometric normal facing the eye, ns (k, 3) the shading normal (with ``shading``, else
    None), back (k,) bool the eye sees a face's back, faces (k,) int64 (-1: the plane),
    bary (k, 3) float64 (0 on the plane), sizes (k,) float64 (the ray offset's scale)."""
    k = len(t)
    mesh = prim >= 0
    # The hit as Embree reports it is eye + t d with t in float32: up to a few float32
    # ulps of the *eye's* distance off the surface (measured: 1e-6 below a sphere seen
    # from 4.8 units, more than the ray offset there, so its rays started inside).  The
    # point is put back on the surface in float64, like a vertex or a texel sample: the
    # barycentric coordinates of the hit on its triangle (the plane: its exact height).
    points = eye[None, :] + t[:, None] * directions
    bary = np.zeros((k, 3))
    if mesh.any():
        points[mesh], bary[mesh] = on_triangle(scene, prim[mesh], points[mesh])
    if (~mesh).any():
        points[~mesh, AXES.index(config.up_axis)] = built.ground["height"]
    # Geometric normal: the hit triangle's (the ground plane's up axis), turned to the eye.
    ng = np.zeros((k, 3))
    ng[mesh] = scene.face_normals[prim[mesh]]
    if (~mesh).any():
        ng[~mesh, AXES.index(config.up_axis)] = 1.0
    back = np.einsum("ij,ij->i", ng, directions) > 0
    ng[back] = -ng[back]
    ns = None
    if shading:  # the vertex normals interpolated at the hit, on the side the eye sees
        ns = ng.copy()
        if mesh.any():
            ns[mesh] = shading_normals(scene, prim[mesh], bary[mesh], ng[mesh])
    # The ray offset follows the hit triangle's size (the ground plane: the scene's
    # median triangle size, as for query points).
    areas = scene.areas()
    sizes = np.full(k, math.sqrt(2.0 * float(np.median(areas))))
    sizes[mesh] = np.sqrt(2.0 * areas[prim[mesh]])
    return dict(points=points, ng=ng, ns=ns, back=back, faces=prim.astype(np.int64),
                bary=bary, sizes=sizes)


def _box_samples(scene, config, built, cam, footprint: Footprint) -> dict:
    """The primary rays of a box-filtered view, ``footprint.positions`` per pixel, and their
    hits: for each position that sees the scene (h of them, in pixel order) pixel (h,)
    int64, position (h,) int32, ids (h,) int64 = pixel x positions + position (the sample
    stream of its rays: no two positions share one), group (h,) its replicate, offset (h, 2)
    where in the pixel, t, prim, ground its ray's hit, and ``_surface``'s points, ng, faces,
    bary, sizes; hits (H W,) int64 the positions of each pixel that see the scene."""
    n, per = cam.height * cam.width, footprint.positions
    block = max(1, BLOCK_RAYS // per)
    parts = []
    for start in range(0, n, block):
        pixels = np.arange(start, min(n, start + block), dtype=np.int64)
        offsets = footprint.offsets(config.seed, pixels).reshape(-1, 2)
        row, column = np.divmod(np.repeat(pixels, per), cam.width)
        xy = np.stack([column + offsets[:, 0], row + offsets[:, 1]], axis=1)
        directions = cam.directions_through(xy)
        t, prim, ground = built.first_hits(np.broadcast_to(cam.eye, directions.shape),
                                           directions)
        seen = np.flatnonzero(np.isfinite(t))
        surface = _surface(scene, config, built, cam.eye, directions[seen], t[seen],
                           prim[seen], ground[seen], shading=False)
        position = (seen % per).astype(np.int32)
        pixel = pixels[seen // per]
        parts.append(dict(surface, pixel=pixel, position=position, offset=offsets[seen],
                          t=t[seen], prim=prim[seen], ground=ground[seen],
                          directions=directions[seen]))
    subs = {key: np.concatenate([part[key] for part in parts]) for key in parts[0]
            if parts[0][key] is not None}
    subs["ids"] = subs["pixel"] * per + subs["position"]
    subs["group"] = subs["position"] // footprint.per_group
    subs["hits"] = np.bincount(subs["pixel"], minlength=n)
    return subs


def _joint_plan(scene, config, built, cam, joint, index, t, centre, threads, timings,
                phase) -> SamplePoints:
    """The plan of a view with the joint box estimator: every pixel's rays traced here, in
    bulk (``aobake.targets.view_box``), so the method is handed no points; ``finish``
    pools the sums.  ``index``, ``t``, ``centre``: the centre rays' hit pixels, distances
    and ``_surface``."""
    from aobake.targets import view_box

    clock = time.perf_counter()
    if phase is not None:
        phase("tracing")
    n = cam.height * cam.width
    centre_hit = np.zeros(n, dtype=bool)
    centre_hit[index] = True
    sums = view_box.trace(scene, config, built, cam, joint, threads, centre_hit,
                          view_box.receiving_faces(scene, config))
    covered = np.flatnonzero(sums["hits"] > 0)
    if not len(covered):
        raise InputError(f"{scene.source}: the view sees nothing (none of the pixels' "
                         f"{joint.positions} positions hits the scene): check "
                         "--look-from/--look-at/--fov")
    # the G-buffer: the centre's hit, else the covered position nearest the centre
    out = {"index": covered}
    k = len(covered)
    row = np.full(n, -1, dtype=np.int64)
    row[index] = np.arange(len(index))
    at = row[covered]
    at_centre = at >= 0
    for key, source in (("t", t), ("prim", centre["faces"]), ("points", centre["points"]),
                        ("ng", centre["ng"]), ("ns", centre["ns"])):
        out[key] = np.zeros((k,) + source.shape[1:], dtype=source.dtype)
        out[key][at_centre] = source[at[at_centre]]
    out["ground"] = np.zeros(k, dtype=bool)
    out["ground"][at_centre] = centre["faces"][at[at_centre]] < 0
    missing = np.flatnonzero(~at_centre)
    if len(missing):
        pixels, directions, tn, prim, ground = view_box.nearest_hits(sums["context"],
                                                                     sums["near"])
        assert np.array_equal(pixels, covered[missing])  # one chosen position each
        near = _surface(scene, config, built, cam.eye, directions, tn, prim, ground,
                        shading=True)
        out["t"][missing] = tn
        out["prim"][missing] = near["faces"]
        out["ground"][missing] = ground
        for key in ("points", "ng", "ns"):
            out[key][missing] = near[key]
    # what ran (the report's parameters.kernels): the rays' generator, and no escape
    # counts (the pixels' sums are taken here)
    kernels = {"ray_generation": sums.pop("context").compiled,
               "escape_counts": None}
    timings["pixels_s"] = time.perf_counter() - clock
    state = dict(camera=cam, footprint=joint, gbuffer=out, sums=sums)
    empty = np.zeros((0, 3))
    # the method gets no points: the rays are traced (a method that would trace points of
    # its own gets a view with --box-sampling positions: ViewTarget.footprint)
    return SamplePoints(empty, empty, np.zeros(0, dtype=np.int64), sizes=np.zeros(0),
                        kernels=kernels, state=state, faces=np.zeros(0, dtype=np.int64),
                        bary=empty, image=BoxFiltered())


def _dark(fields: dict, rays: np.ndarray, source) -> str | None:
    """``groups.dark_warning`` of a view's pixels (the method estimated no points)."""
    from aobake.groups import dark_warning
    from aobake.records import Estimates

    return dark_warning(Estimates(fields, rays), source)


def _box_gbuffer(scene, cam, index, t, centre, subs, footprint) -> dict:
    """The G-buffer hits of a box-filtered view, per pixel some position sees the scene
    (index (k,) int64 ascending): the centre ray's hit where it sees the scene, else the
    position's hit nearest the pixel's centre (ties: the lower position); ``index``,
    ``t``: the centre rays' hit pixels and distances, ``centre``: their ``_surface``."""
    n = cam.height * cam.width
    covered = np.flatnonzero(subs["hits"] > 0)
    centre_row = np.full(n, -1, dtype=np.int64)
    centre_row[index] = np.arange(len(index))
    at_centre = centre_row[covered] >= 0
    rows = centre_row[covered[at_centre]]
    out = {"index": covered}
    k = len(covered)
    for key, source in (("t", t), ("prim", centre["faces"]), ("points", centre["points"]),
                        ("ng", centre["ng"]), ("ns", centre["ns"])):
        shape = (k,) + source.shape[1:]
        out[key] = np.zeros(shape, dtype=source.dtype)
        out[key][at_centre] = source[rows]
    out["ground"] = np.zeros(k, dtype=bool)
    out["ground"][at_centre] = centre["faces"][rows] < 0
    missing = ~at_centre
    if missing.any():
        # the covered position nearest the centre of each pixel whose centre sees nothing
        away = np.square(subs["offset"] - 0.5).sum(axis=1)
        order = np.lexsort((subs["position"], away, subs["pixel"]))
        first = np.ones(len(order), dtype=bool)
        first[1:] = subs["pixel"][order][1:] != subs["pixel"][order][:-1]
        nearest = np.full(n, -1, dtype=np.int64)
        nearest[subs["pixel"][order][first]] = order[first]
        chosen = nearest[covered[missing]]
        prim = subs["faces"][chosen]
        out["t"][missing] = subs["t"][chosen]
        out["prim"][missing] = prim
        out["ground"][missing] = prim < 0
        out["points"][missing] = subs["points"][chosen]
        ng = subs["ng"][chosen]
        out["ng"][missing] = ng
        ns = ng.copy()
        mesh = prim >= 0
        if mesh.any():
            ns[mesh] = shading_normals(scene, prim[mesh], subs["bary"][chosen][mesh], ng[mesh])
        out["ns"][missing] = ns
    return out


def pool(config, footprint: Footprint, state: dict, estimates, n: int,
         diagonal: float) -> tuple[dict, np.ndarray | None]:
    """A box-filtered view's pixels from its positions' estimates: (fields name -> (k,)
    float64 at the k pixels some position sees the scene, in pixel order; rays (k,) int64
    per pixel, or None for a method that casts none).

    value = the mean of the covered positions' values (positions that cast no rays, on
    faces that only occlude, are left out; a pixel with none gets the mean of their
    no-information values).  Its stderr is measured from the positions themselves, never
    from the positions' own stderrs: i.i.d. positions, the spread of their values over n
    covered positions (n - 1 degrees of freedom); replicates, the spread of the replicates'
    ratios Y_g / C_g (Y_g the sum of replicate g's covered values, C_g their count) by the
    linearised ratio estimator's variance sum_g (Y_g - v C_g)^2 / (G (G - 1) Cbar^2), G - 1
    degrees of freedom, none where fewer than two replicates see the scene.  The interval
    is ``stats.error_bars``' with n the pixel's covered positions (not its rays).  The
    estimate is of the mean over the covered part of the pixel: its conditional mean given
    which positions are covered (i.i.d. positions then are i.i.d. on the covered part).
    """
    pixel, group = state["pixel"], state["group"]
    covered = np.flatnonzero(state["hits"] > 0)
    k = len(covered)
    row = np.full(n, -1, dtype=np.int64)
    row[covered] = np.arange(k)
    at = row[pixel]
    rays = estimates.rays
    traced = np.ones(len(at), dtype=bool) if rays is None else rays > 0
    counted = np.bincount(at[traced], minlength=k)
    blind = counted == 0  # covered pixels none of whose positions cast rays

    def mean_of(values, where):
        sums = np.bincount(at[where], weights=values[where], minlength=k)
        return sums / np.maximum(np.bincount(at[where], minlength=k), 1)

    fields = {}
    for name, values in estimates.fields.items():
        fields[name] = np.where(blind, mean_of(values, np.ones(len(at), dtype=bool)),
                                mean_of(values, traced))
    if rays is None:
        return fields, None
    per_pixel = np.bincount(at, weights=rays, minlength=k).astype(np.int64)
    # The interval's floor (the rule of three) counts positions, not rays: a pixel whose
    # every ray escaped may hold a sliver none of its positions landed on (P(all n
    # positions read 1) <= v^n, v the covered mean: each position's jitter is independent,
    # and a position reads 1 with probability at most the AO around it).
    units = np.maximum(counted, 1)
    exact = config.resolve_max_distance(diagonal) == 0  # every ray gives the same answer
    for quantity in config.quantities:
        q = QUANTITIES[quantity]
        names = [q.value.name, q.error.name] + [f.name for f in (q.interval or ())]
        if not all(name in fields for name in names) or len(names) != 4:
            continue
        values, mean = estimates.fields[q.value.name], fields[q.value.name]
        v, a = values[traced], at[traced]
        if footprint.iid:
            m2 = np.bincount(a, weights=np.square(v - mean[a]), minlength=k)
            dof = counted - 1
            se = np.sqrt(m2 / np.maximum(dof, 1) / np.maximum(counted, 1))
        else:
            groups = footprint.groups
            key = a * groups + group[traced]
            y = np.bincount(key, weights=v, minlength=k * groups).reshape(k, groups)
            c = np.bincount(key, minlength=k * groups).reshape(k, groups)
            se, dof = stats.ratio_spread(y, c, mean)
        error = stats.pooled_error_bars(mean, se, dof, units, per_pixel, exact,
                                        config.confidence)
        for name, array in zip(names[1:], error):
            fields[name] = np.where(blind, fields[name], array)
    return fields, per_pixel


def _up(config) -> tuple:
    """The up vector of ``config.up_axis``."""
    up = [0.0, 0.0, 0.0]
    up[AXES.index(config.up_axis)] = 1.0
    return tuple(up)


LOOK_KEYS = ("look_from", "look_at", "up", "fov")


def _shown(value) -> str:
    """A value as a message shows it: its type, and its repr when short."""
    text = repr(value)
    return f"{type(value).__name__} {text}" if len(text) <= 60 else type(value).__name__


def _look(look) -> dict | None:
    """``look`` checked: a dict with look_from and look_at (and optionally up, fov); the
    values themselves are checked by ``aobake.camera.look_at``."""
    if look is None:
        return None
    if not isinstance(look, dict):
        raise InputError(f"view: look must be a dict with keys {', '.join(LOOK_KEYS)} "
                         f"(look_from and look_at required), got {_shown(look)}")
    unknown = sorted(map(str, set(look) - set(LOOK_KEYS)))
    if unknown:
        raise InputError(f"view: look has unknown key(s) {', '.join(unknown)}; its keys are "
                         f"{', '.join(LOOK_KEYS)}")
    missing = [key for key in ("look_from", "look_at") if look.get(key) is None]
    if missing:
        raise InputError(f"view: look needs {' and '.join(missing)} (a point: 3 numbers)")
    return dict(look)


def _gltf(gltf) -> tuple | None:
    """``gltf`` checked: a (path, camera name or None) pair."""
    if gltf is None:
        return None
    import os

    if not isinstance(gltf, (tuple, list)) or len(gltf) != 2:
        raise InputError(f"view: gltf must be a pair (path of a .gltf/.glb file, camera name "
                         f"or None), got {_shown(gltf)}")
    path, name = gltf
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"view: gltf's path must be a file path, got {_shown(path)}")
    if name is not None and not isinstance(name, str):
        raise InputError(f"view: gltf's camera name must be text or None, got {_shown(name)}")
    return path, name


#: how many scene sizes from the scene an eye may be: the backend casts a ray's origin to
#: float32 in a frame where the scene spans about [-1, 1], so the eye's coordinate there must
#: stay far below float32's largest (2^128); and from 2^24 sizes away the whole scene is
#: within one float32 step of the eye's coordinate, smaller than a pixel of any view
MAX_EYE_SIZES = 2.0 ** 64


def _check_reach(scene, cam) -> None:
    """InputError where ``cam``'s eye is more than ``MAX_EYE_SIZES`` scene sizes from the
    scene's box centre (a float32 ray from there overflows or cannot resolve the scene)."""
    lo, hi = scene.bounds
    centre = (np.asarray(lo, dtype=np.float64) + np.asarray(hi, dtype=np.float64)) / 2
    size = max(float(np.max(np.asarray(hi) - np.asarray(lo))), np.finfo(np.float64).tiny)
    with np.errstate(over="ignore"):
        offset = cam.eye - centre
    distance = math.hypot(*offset)  # inf only where the offset itself overflowed
    if not distance <= MAX_EYE_SIZES * size:
        raise InputError(f"{scene.source}: the camera's eye {cam.eye.tolist()} is "
                         f"{distance:.3g} from the scene (size {size:.3g}): more than 2^64 "
                         "times its size, beyond what float32 rays resolve; move it closer")
