"""The scene's occluders, built once per bake before any target samples.

scene -> :class:`Occluders`: the local frame every backend works in (rebased on the
per-axis median of the used vertices, scaled by a power of two so the scene spans
[-1, 1]), the triangle backend, the optional ground plane and their union.  A target
may cast primary rays through it (the camera target finds each pixel's first hit); a
method traces its secondary rays through it.  Built from (scene, config) alone, so a
worker process rebuilds exactly the same occluders from the same inputs.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from aobake.backends import BACKENDS
from aobake.backends.cutout import MAX_LAYERS, CutoutOccluder, cutout_faces
from aobake.backends.extra import FrontBeyond
from aobake.backends.plane import PlaneOccluder
from aobake.backends.union import Union
from aobake.constants import AXES, OFFSET_ULPS
from aobake.errors import InputError
from aobake.scene import release_freed_memory
from aobake.vectors import distinct

log = logging.getLogger(__name__)

#: Embree's largest finite ray length (float32), in local units
_FAR = np.float32(3.0e38)


@dataclass
class Occluders:
    """What blocks rays, in the backend's local frame.

    center : (3,) float64 the rebase point (scene units), scale : float a power of two
    (local = (world - center) * scale), step : float local units a ray steps past a back
    face (``--backfaces ignore``), diagonal : float the scene's bounding-box diagonal,
    backend : the triangle backend (``BACKENDS[config.backend]``), union : backend plus
    ground plane (``Union``), backend_name : str, ground : {"axis", "height"} | None,
    faces : (k,) int64 the scene face of each of the backend's triangles when only some
    faces occlude (``Scene.occluding``), or None: the backend holds every face, in order;
    extras : the report's record of ``Scene.extra_occluders`` (members of ``union`` only:
    primary and cage rays never see them); cutout : the ``CutoutOccluder`` of the
    alpha-tested faces (``--alpha-cutout``: then not in ``backend``), or None;
    traversal : ``embree_mode`` (robust | fast) of an Embree backend, None for the others;
    instanced : the report's record of ``Scene.instances`` (how they were traced, the baked
    instances' layout), or None for a scene loaded flat.  With instances traced as such
    (``backends.instanced``) or flattened for tracing, ``backend`` holds every instance and
    its ``prim`` numbers their faces in instance order (the scene's own faces when every
    instance is baked).
    """

    center: np.ndarray
    scale: float
    step: float
    diagonal: float
    backend: object
    union: Union
    backend_name: str
    ground: dict | None
    faces: np.ndarray | None = None
    extras: tuple = ()
    cutout: object = None
    traversal: str | None = None
    instanced: dict | None = None

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) float64 scene units -> (n, 3) float64 local units."""
        return (np.asarray(points, dtype=np.float64) - self.center) * self.scale

    def trace(self, query: str, origins, directions, tmax):
        """``Union.trace`` on local float32 rays: (occluded (n,) bool, distance | None)."""
        return self.union.trace(query, origins, directions, tmax)

    def nearest(self, origins: np.ndarray, directions: np.ndarray, tmax):
        """Nearest hit of local float32 rays: origins (n, 3), directions (n, 3) unit, tmax
        (scalar or (n,) float32 local units).  Returns (t (n,) float32 local, inf on a miss;
        prim (n,) int64 the triangle hit, -1 on a miss or on the ground plane; ground (n,)
        bool the ground plane is the nearest hit)."""
        limit = np.minimum(np.asarray(tmax, dtype=np.float32), _FAR)
        t, prim = self.backend.intersect(origins, directions, limit)
        t = np.where(prim >= 0, t, np.float32(np.inf)).astype(np.float32)
        prim = prim.astype(np.int64)
        if self.faces is not None:  # the backend's triangles are a subset: scene indices
            prim = np.where(prim >= 0, self.faces[np.maximum(prim, 0)], -1)
        if self.cutout is not None:  # the first opaque texel of the alpha-tested faces
            tc, pc = self.cutout.intersect(origins, directions, limit)
            nearer = (pc >= 0) & (tc < t)
            t = np.where(nearer, tc, t).astype(np.float32)
            prim = np.where(nearer, self.cutout.scene_faces[np.maximum(pc, 0)], prim)
        ground = np.zeros(len(t), dtype=bool)
        if self.ground is not None:
            plane = self.union.occluders[-1]
            tp = plane.distance(origins, directions, limit)
            ground = tp < t
            t = np.where(ground, tp, t)
            prim = np.where(ground, -1, prim)
        return t, prim, ground

    def first_hits(self, origins: np.ndarray, directions: np.ndarray):
        """Nearest hit of rays given in scene units.

        origins (n, 3) float64, directions (n, 3) float64 unit.  Returns (t (n,) float64
        scene units, inf on a miss; prim (n,) int64 the triangle hit, -1 on a miss or where
        the ground plane is nearer; ground (n,) bool the ground plane is the nearest hit).
        The distance is Embree's float32 ``tfar`` converted exactly to scene units.
        """
        local = self.to_local(origins).astype(np.float32)
        t, prim, ground = self.nearest(local, np.asarray(directions, dtype=np.float32), _FAR)
        return t.astype(np.float64) / self.scale, prim, ground

    def record(self) -> dict:
        """The report's parameters of the frame and occluders."""
        params = {"backend": self.backend_name, "rebase_center": self.center.tolist(),
                  "trace_scale": self.scale, "diagonal": self.diagonal}
        if self.traversal is not None:  # which Embree traversal ran (docs/performance.md)
            params["embree_mode"] = self.traversal
            # which binding traced (aobake.backends.native): the same answers, not the same speed
            params["embree_binding"] = getattr(self.backend, "binding", "embreex")
        described = getattr(self.backend, "described", None)
        if described is not None:  # what the backend says ran (warp: its device and version)
            params.update(described())
        if self.ground is not None:
            params["ground_plane"] = dict(self.ground)
        if self.faces is not None:
            params["occluding_faces"] = int(len(self.faces))
        if self.extras:
            params["extra_occluders"] = [dict(extra) for extra in self.extras]
        if self.cutout is not None:
            params["alpha_cutout"] = {
                "faces": int(len(self.cutout.scene_faces)),
                "rule": "glTF alphaMode MASK: a hit passes where alpha < alphaCutoff; alpha = "
                        "baseColorTexture alpha (bilinear, repeat) x baseColorFactor alpha",
                "max_layers": MAX_LAYERS}
        if self.instanced is not None:
            params["instances"] = self.instanced
        return params


def check(scene) -> None:
    """InputError for a scene nothing can be traced in (checked before any work)."""
    if not math.isfinite(scene.diagonal) or scene.diagonal <= 0:
        raise InputError(f"{scene.source}: scene has zero extent")


def _triangles(config, vertices, faces, face_normals, step):
    """A triangle backend (``BACKENDS[config.backend]``) of the given local-frame triangles,
    in the config's ``embree_mode`` (robust or fast traversal; the reference backend is
    exact in float64 either way)."""
    return BACKENDS[config.backend](vertices, faces, face_normals, step,
                                    robust=getattr(config, "embree_mode", "robust") == "robust")


def build(scene, config) -> Occluders:
    """The occluders of ``scene`` under ``config`` (backend, ground_plane, up_axis).

    With ``scene.occluding`` (``aobake.groups``: some faces are baked but cast nothing) the
    backend holds the occluding faces alone, and the frame is theirs (rebased on their
    vertices, scaled to their extent): the same occluders, bit for bit, as a scene of those
    faces alone.  The ground plane stays under the whole scene.
    """
    check(scene)
    how = _instancing(scene, config)
    if how is not None and how != "scene":
        return _build_instanced(scene, config, how)
    lo, hi = scene.bounds
    faces, subset = scene.faces, None
    if scene.occluding is not None and not np.all(scene.occluding):
        subset = np.flatnonzero(scene.occluding)
        if not len(subset):
            raise InputError(f"{scene.source}: no face occludes (every face is receive-only)")
        faces = scene.faces[subset]
    # The backend's frame: rebased on the per-axis median of the vertices (far-from-origin
    # scenes; the median, not the bbox centre, so a stray far-away triangle does not move
    # the bulk of the scene to large float32 coordinates, where its rays would need larger
    # offsets) and scaled by a power of two so the scene spans [-1, 1] (tiny and huge
    # scenes).  A power of two scales float32 values and spacings exactly, so this changes
    # no bit at ordinary scales, and Embree's float32 arithmetic never under- or overflows.
    # (a mask, not np.unique: numpy 2's hashing unique took 44 ms on the ogre's faces)
    if subset is None:  # np.median(vertices[used], axis=0), without its copies of the rows
        center = scene.used_median()
    else:
        used = distinct(faces, len(scene.vertices))
        center = np.median(scene.vertices[used], axis=0)
    if subset is None:
        reach = float(np.maximum(np.abs(hi - center), np.abs(lo - center)).max())
    else:  # the occluders' own extent
        span = scene.vertices[used]
        reach = float(np.maximum(np.abs(span.max(axis=0) - center),
                                 np.abs(span.min(axis=0) - center)).max())
    scale = 2.0 ** -math.frexp(reach)[1]
    # Stepping past a back face (--backfaces ignore): OFFSET_ULPS ulps of the scene's
    # largest local coordinate, a length any point of the scene can resolve.
    step = OFFSET_ULPS * float(np.spacing(np.float32(reach * scale)))
    # Vertices no face uses never reach a ray; zero them so a far-off one cannot overflow
    # the backend's float32 cast.
    unused = np.ones(len(scene.vertices), dtype=bool)
    unused[faces.ravel()] = False
    cut = cutout_faces(scene) if getattr(config, "alpha_cutout", False) else None
    local = _local(scene.vertices, center, scale, unused,
                   float32=config.backend == "embree" and cut is None)
    del unused
    # (the scene's own rows, read per hit, and only where a front-face query asks for them:
    # a lean scene (Scene.lean) remakes them then; a subset's as float32: the bits the
    # backend reads)
    normals = (lambda: scene.face_normals) if subset is None else \
        scene.face_normals[subset].astype(np.float32)
    cutout = None
    if cut is not None:  # the alpha-tested faces in a member of their own
        index = np.arange(len(scene.faces)) if subset is None else subset
        keep, cut_here = index[~cut[index]], index[cut[index]]
        if len(cut_here):
            uv = scene.uv[scene.faces_uv[cut_here]]
            cutout = CutoutOccluder(
                _triangles(config, local, scene.faces[cut_here],
                           scene.face_normals[cut_here], step),
                local, scene.faces[cut_here], scene.face_normals[cut_here], uv,
                scene.face_material[cut_here], scene.materials, step, cut_here)
            subset = keep
            if len(keep):
                faces, normals = scene.faces[keep], scene.face_normals[keep]
            else:  # every face is cut out: the main backend holds one degenerate triangle
                faces, normals = np.zeros((1, 3), dtype=np.int64), np.zeros((1, 3))
                subset = np.full(1, -1, dtype=np.int64)
    backend = _triangles(config, local, faces, normals, step)
    del local, normals
    release_freed_memory()  # the frame's and the BVH build's temporaries
    members = [backend]
    if cutout is not None:
        members.append(cutout)
    extras, ground = _others(scene, config, center, scale, step, members)
    traversal = getattr(config, "embree_mode", "robust") if config.backend == "embree" else None
    return Occluders(center, scale, step, scene.diagonal, backend, Union(members),
                     config.backend, ground, subset, tuple(extras), cutout, traversal,
                     None if how is None else _instanced_record(
                         scene, "flattened: the scene's own faces are every instance's ("
                         + _why_flat(scene, config) + ")"
                         if getattr(scene.instances, "instanced", True) else
                         "the file's faces: every one is baked"))


#: vertices put in the local frame at a time (bounds the float64 temporary)
LOCAL_BLOCK = 1 << 16


def _local(vertices, center, scale, unused, float32: bool) -> np.ndarray:
    """(v, 3) ``(vertices - center) * scale``, rows ``unused`` zero: float64, or with
    ``float32`` the float32 rows Embree reads in place (``backends.embree.padded_rows``; the
    bits of the float64 rows cast), made a block at a time so that no float64 copy of the
    whole mesh exists."""
    if not float32:
        local = (vertices - center) * scale
        local[unused] = 0.0
        return local
    from aobake.backends.embree import padded_rows

    local = padded_rows(len(vertices))
    for start in range(0, len(vertices), LOCAL_BLOCK):
        block = slice(start, start + LOCAL_BLOCK)
        local[block] = (vertices[block] - center) * scale
    local[unused] = 0.0
    return local


def _others(scene, config, center, scale, step, members) -> tuple[list, dict | None]:
    """Append the scene's extra occluders and the ground plane to ``members`` (in that
    order: ``nearest`` takes the plane last); (their report records, the ground record)."""
    lo = scene.bounds[0]
    ground, extras = None, []
    for extra in scene.extra_occluders:  # before the ground plane: ``nearest`` takes it last
        faces_extra = np.asarray(extra.faces, dtype=np.int64)
        vertices_extra = np.asarray(extra.vertices, dtype=np.float64)
        corners = vertices_extra[faces_extra]
        cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        length = np.linalg.norm(cross, axis=1)
        extra_normals = np.divide(cross, length[:, None], out=np.zeros_like(cross),
                                  where=length[:, None] > 0)
        member = _triangles(config, (vertices_extra - center) * scale, faces_extra,
                            extra_normals, step)
        members.append(FrontBeyond(member, extra.skip * scale))
        extras.append({"name": extra.name, "faces": int(len(faces_extra)),
                       "skip": float(extra.skip),
                       "rule": "front faces only, beyond skip from the ray's origin"})
    if config.ground_plane:
        axis = AXES.index(config.up_axis)
        ground = {"axis": config.up_axis, "height": float(lo[axis])}
        members.append(PlaneOccluder(axis, (ground["height"] - center[axis]) * scale))
    return extras, ground


def _why_flat(scene, config) -> str:
    """Why instances are traced flattened rather than as Embree instances (a phrase)."""
    from aobake.backends.instanced import available

    if getattr(config, "instances", "trace") == "flatten":
        return "--instances flatten"
    if config.backend != "embree":
        return f"--backend {config.backend} has no instances"
    if getattr(config, "alpha_cutout", False):
        return "--alpha-cutout tests the faces' own materials"
    if scene.occluding is not None:
        return "--receive-only leaves some faces out of the occluders"
    if not available():
        return "embreex traces (aobake._embree not built or not opened): it has no instances"
    return "as asked"


def _instancing(scene, config) -> str | None:
    """How a scene's instances are traced: None (a scene loaded flat), "embree" (Embree
    instances: ``backends.instanced``), "scene" (the scene's own faces, which are every
    instance's: nothing baked is left out), "flatten" (every instance's triangles copied
    into one triangle backend: a backend without instances, with some instances not baked)
    or "file" (some faces of a flat file baked, ``instances.Subset``: the file's faces).
    InputError where a ``--bake`` selection cannot be honoured."""
    from aobake.backends.instanced import available

    instances = scene.instances
    patterns = tuple(getattr(config, "bake", ()) or ())
    if patterns and (instances is None or tuple(instances.patterns) != patterns):
        raise InputError(f"{scene.source}: --bake {' '.join(patterns)}: the scene was loaded "
                         "without it (aobake.scene.load_scene(path, bake=...) chooses the "
                         "baked instances; this caller did not pass the setting on)")
    if instances is None:
        return None
    if not getattr(instances, "instanced", True):  # an OBJ's objects: the file's faces
        return "scene" if instances.everything else "file"
    embree = (config.backend == "embree" and getattr(config, "instances", "trace") == "trace"
              and not getattr(config, "alpha_cutout", False) and scene.occluding is None)
    if embree and available():
        return "embree"
    if instances.everything:
        return "scene"
    if getattr(config, "alpha_cutout", False) or scene.occluding is not None:
        raise InputError(f"{scene.source}: --alpha-cutout and --receive-only act on the baked "
                         "instances' faces only: not with --bake")
    return "flatten"


def _instanced_record(scene, traced_as: str) -> dict:
    """The report's ``parameters.instances``: how they were traced, the counts, and the
    baked instances' layout (each one's vertex and face ranges in the outputs)."""
    instances = scene.instances
    return {"traced_as": traced_as, **instances.record(), "layout": instances.layout(),
            "source": instances.source()}


def _build_instanced(scene, config, how: str) -> Occluders:
    """The occluders of a scene whose every instance occludes while only the baked ones
    are its faces (``how`` "embree" or "flatten", see :func:`_instancing`; "file": an OBJ's
    faces chosen by name, every face of the file occluding).

    The frame is rebased on the baked instances' vertices (their median: where the rays
    start) and scaled by a power of two to span every instance (``Scene.bounds`` is the
    whole scene's): with every instance baked, the flattened scene's frame exactly."""
    instances = scene.instances
    lo, hi = scene.bounds
    center = scene.used_median()  # np.median(vertices[used], axis=0), without its copies
    reach = float(np.maximum(np.abs(hi - center), np.abs(lo - center)).max())
    scale = 2.0 ** -math.frexp(reach)[1]
    step = OFFSET_ULPS * float(np.spacing(np.float32(reach * scale)))
    robust = getattr(config, "embree_mode", "robust") == "robust"
    if how == "file":  # some faces of a flat file baked: every face of it occludes
        from aobake.scene import face_normals

        vertices, faces = instances.vertices, instances.faces
        backend = _triangles(config, (vertices - center) * scale, faces,
                             face_normals(vertices, faces), step)
        traced_as = "the file's faces: the baked ones and every other"
    elif how == "embree":
        from aobake.backends.instanced import InstancedEmbree

        backend = InstancedEmbree(instances, center, scale, step, robust=robust)
        traced_as = ("embree instances: one child scene per unique mesh, one instance "
                     "geometry per placement")
    else:
        from aobake.instances import flattened
        from aobake.scene import face_normals

        vertices, faces = flattened(instances)
        why = _why_flat(scene, config)
        log.warning("%s: %d instances traced flattened (%s): %d triangles in memory where "
                    "Embree instances would hold %d", scene.source, len(instances), why,
                    len(faces), sum(len(f) for _, f in instances.meshes))
        backend = _triangles(config, (vertices - center) * scale, faces,
                             face_normals(vertices, faces), step)
        traced_as = f"flattened for tracing ({why}): every instance's triangles copied"
        del vertices
    members = [backend]
    extras, ground = _others(scene, config, center, scale, step, members)
    traversal = getattr(config, "embree_mode", "robust") if config.backend == "embree" else None
    return Occluders(center, scale, step, scene.diagonal, backend, Union(members),
                     config.backend, ground, None, tuple(extras), None, traversal,
                     _instanced_record(scene, traced_as))
