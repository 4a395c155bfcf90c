"""Camera target (``aobake view``): one primary ray per pixel centre, a G-buffer, and the
method's values at each first hit.

Primary rays go through the scene's occluders (Embree), one per pixel centre, no jitter
(``aobake.camera``).  At each first hit the method estimates about the *geometric*
normal turned to face the eye (a two-sided surface seen from either side has AO on the
side the camera sees).  The sample-stream id of a pixel is its index r * W + c, so a
pixel's value equals ``bake_points`` at its hit point with that id and the same seed.

Every channel is float32 (H, W), row 0 = top.  Where ``coverage`` is 0 (the pixel sees
nothing) every channel is 0, except the hardware depths (the cleared depth buffer's
value: 1 for OpenGL and Direct3D, 0 for reversed-Z) and the ids (-1): no inf or NaN in
any output.  Conventions: docs/conventions.md ("Camera views").
"""

from __future__ import annotations

import math
import time

import numpy as np

from aobake import camera as cameras
from aobake.constants import AXES
from aobake.errors import InputError
from aobake.quantities import FIELDS
from aobake.hits import on_triangle, shading_normals
from aobake.records import Finished, SamplePoints, ViewResult

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

    def rays_per_point(self, config) -> int:
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
        if not hit.any():
            raise InputError(f"{scene.source}: the view sees nothing (no pixel's ray hits the "
                             "scene): check --look-from/--look-at/--fov")
        index = np.flatnonzero(hit)
        dirs = directions[index]
        mesh = prim[index] >= 0
        # The hit as Embree reports it is eye + t d with t in float32: up to a few float32
        # ulps of the *eye's* distance off the surface (measured: 1e-6 below a sphere seen
        # from 4.8 units, more than the ray offset there, so its rays started inside).  The
        # point is put back on the surface in float64, like a vertex or a texel sample: the
        # barycentric coordinates of the hit on its triangle (the plane: its exact height).
        points = origins[index] + t[index, None] * directions[index]
        bary = None
        if mesh.any():
            points[mesh], bary = on_triangle(scene, prim[index][mesh], points[mesh])
        if (~mesh).any():
            points[~mesh, AXES.index(config.up_axis)] = built.ground["height"]
        # Geometric normal: the hit triangle's (the ground plane's up axis), turned to the eye.
        ng = np.zeros((len(index), 3))
        ng[mesh] = scene.face_normals[prim[index][mesh]]
        if (~mesh).any():
            ng[~mesh, AXES.index(config.up_axis)] = 1.0
        facing = np.einsum("ij,ij->i", ng, dirs)
        back = facing > 0
        ng[back] = -ng[back]
        # Shading normal: the vertex normals interpolated at the hit, on the side the eye sees.
        ns = ng.copy()
        if mesh.any():
            ns[mesh] = shading_normals(scene, prim[index][mesh], bary, ng[mesh])
        back_seen = int(np.count_nonzero(back & mesh))
        if back_seen > INSIDE_FRACTION * len(index):
            warnings.append(f"{scene.source}: {back_seen} of {len(index)} covered pixels see the "
                            "back of a face: is the camera inside a closed mesh? (their AO is "
                            "taken on the side the camera sees)")
        if len(scene.faces) > EXACT_IDS:
            warnings.append(f"{scene.source}: {len(scene.faces)} triangles: primitive_id is "
                            f"float32, exact only below {EXACT_IDS}")
        # The ray offset follows the hit triangle's size (the ground plane: the scene's
        # median triangle size, as for query points).
        areas = scene.areas()
        sizes = np.full(len(index), math.sqrt(2.0 * float(np.median(areas))))
        sizes[mesh] = np.sqrt(2.0 * areas[prim[index][mesh]])
        state = dict(camera=cam, index=index, t=t, prim=prim, ground=ground, ng=ng, ns=ns,
                     points=points)
        faces = prim[index].copy()  # -1 on the ground plane
        barycentric = np.zeros((len(index), 3))
        if bary is not None:
            barycentric[mesh] = bary
        # The G-buffer a screen-space method reads (the channels ``finish`` writes).
        from aobake.screen.gbuffer import GBuffer

        image = GBuffer.from_hits(cam, index, points, ng, ns)
        timings["primary_s"] = time.perf_counter() - clock
        return SamplePoints(points, ng, index.astype(np.int64), sizes=sizes, state=state,
                            faces=faces, bary=barycentric, image=image)

    def finish(self, scene, config, plan, estimates, timings, warnings) -> Finished:
        state = plan.state
        cam = state["camera"]
        h, w = cam.height, cam.width
        index = state["index"]
        n = h * w
        channels = {name: np.zeros(n, dtype=np.float32) for name in GBUFFER}
        covered = np.zeros(n, dtype=bool)
        covered[index] = True
        channels["coverage"][index] = 1.0
        view = cam.world_to_view()
        rotation = view[:3, :3]
        p_view = (state["points"] - cam.eye) @ rotation.T
        depth = -p_view[:, 2]
        channels["depth"][index] = depth
        channels["distance"][index] = state["t"][index]
        for convention, name in (("opengl", "hwdepth_gl"), ("d3d", "hwdepth_d3d"),
                                 ("reversed", "hwdepth_reversed")):
            full = np.full(n, np.inf)
            full[index] = depth
            channels[name][:] = cameras.hardware_depth(full, cam.near, cam.far, convention)
        for axis, letter in enumerate("XYZ"):
            channels[f"P.{letter}"][index] = p_view[:, axis]
        for key, vectors in (("Ng", state["ng"]), ("N", state["ns"])):
            in_view = vectors @ rotation.T
            for axis, letter in enumerate("XYZ"):
                channels[f"{key}.{letter}"][index] = in_view[:, axis]
        objects = np.full(n, OBJECTS["none"], dtype=np.float32)
        objects[index] = np.where(state["ground"][index], OBJECTS["ground_plane"],
                                  OBJECTS["mesh"])
        channels["object_id"][:] = objects
        channels["primitive_id"][:] = -1.0
        channels["primitive_id"][index] = state["prim"][index]
        for name, array in estimates.fields.items():
            for c, channel in enumerate(FIELDS[name].exr):
                image = np.zeros(n, dtype=np.float32)
                image[index] = array if array.ndim == 1 else array[:, c]
                channels[channel] = image
        if estimates.rays is not None:
            rays = np.zeros(n, dtype=np.float32)
            rays[index] = estimates.rays
            channels["rays"] = rays
        images = {name: a.reshape(h, w) for name, a in channels.items()}
        result = ViewResult(images, covered.reshape(h, w), {}, camera=cam)
        record = cam.record()
        record["gbuffer"] = {"channels": list(images), "empty_pixels":
                             "0 where coverage = 0, except hwdepth_* (the cleared depth: 1, "
                             "reversed 0) and object_id / primitive_id (-1)",
                             "objects": OBJECTS, "normals": "view space, unit; Ng faces the eye",
                             "ids": f"float32, exact below {EXACT_IDS}"}
        values = estimates.fields
        rays = estimates.rays if estimates.rays is not None else np.zeros(len(index), np.int32)
        return Finished(result, values, rays, n, report={"camera": record,
                                                         "pixels_covered": int(len(index))},
                        rays_key="rays_per_pixel")


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
