"""Cameras other tools load: a view's camera and mesh as a glTF with a camera node, and as a
Mitsuba 3 scene (``aobake view --export-camera`` / ``--export-mitsuba``; docs/renderers.md).

Both hold the scene as the view baked it (the input mesh as loaded, its ``--exclude``\\ d
faces left out, and ``--ground-plane`` as a large quad), in aobake's world coordinates,
unchanged: no axis conversion, so ``aobake view EXPORT.glb --camera first`` reads back the
same camera record, and a tool that converts axes on import (Blender's glTF importer turns
glTF's +Y up into its +Z up) turns the camera with the mesh, so the view is the same.

**glTF** (2.0, ``.glb`` or ``.gltf`` with its buffer in a ``data:`` URI: one file either way):

- one camera node, ``perspective`` with ``yfov`` = the vertical fov (radians, between the
  image's top and bottom edges, as aobake's), ``aspectRatio`` = width / height, ``znear`` /
  ``zfar`` = the record's near / far.  Its ``matrix`` is the camera-to-world transform,
  inverse(``world_to_view``): columns right, up, -forward and the eye; glTF's camera looks
  down its node's -Z with +Y up, which is aobake's view space, so no flip is needed.  The
  camera's ``extras`` hold ``width`` and ``height`` (glTF has no image size; Blender's
  importer keeps extras as custom properties) and ``pixel_filter``.
- the mesh: POSITION (float32) and indices, **no NORMAL**: glTF's rule for a mesh without
  normals is flat shading, whose normal is the geometric normal aobake's view uses (a
  renderer's AO pass uses the shading normal); a white, rough, double-sided material
  (aobake's view sees both sides of a face).
- ``asset.extras``: the view's camera record and conventions (as ``<out>.camera.json``).

**Mitsuba 3** (``.xml``, the mesh beside it as ``<stem>.ply``, binary, float64 positions):

- ``perspective`` sensor: ``fov_axis`` 'y' and ``fov`` = the vertical fov (Mitsuba's default
  axis is 'x'), ``to_world`` from ``lookat`` (eye, a point on the view axis, the record's up:
  Mitsuba's camera looks down its +Z with +X to the *left*, which ``lookat`` builds),
  ``near_clip`` = near and ``far_clip`` beyond everything written (the ground quad too).
- ``hdrfilm`` of the view's width x height, ``rgba`` (alpha = the fraction of the pixel's
  samples that hit: the coverage), with a **box** filter: a box of radius 0.5 averages
  uniform positions over the pixel's area and gives each sample to its own pixel alone,
  which is ``--pixel-filter box``'s definition of a pixel's AO.  Mitsuba's default, a
  Gaussian (stddev 0.5, radius 2 px), would blend neighbouring pixels' AO and match neither
  of aobake's filters; centre sampling would need a filter much narrower than a pixel,
  which in Mitsuba throws most samples away.  The colour is premultiplied: AO = RGB / A.
- the AO "integrator": Mitsuba 3 has no AO plugin, so ``direct`` with one BSDF sample and
  no emitter samples, a ``twosided`` white ``diffuse`` BSDF (reflectance 1) and a
  ``constant`` emitter of radiance 1: each sample is one cosine-distributed ray that
  scores 1 if it escapes, which is aobake's (cosine-weighted, unbounded) AO.
  ``hide_emitters``: pixels that see nothing are 0 with alpha 0, as aobake's.
- ``face_normals`` true: Mitsuba otherwise computes smooth vertex normals, and its BSDF
  samples about the shading normal.
- ``<default name="spp">`` = the view's rays per pixel (override: ``mi.load_file(path,
  spp=1024)`` or ``mitsuba -Dspp=1024``).

What Mitsuba does differently, left as it is (docs/renderers.md measures it): its ray
offset is about 1e-4 x (1 + max |p|) of the hit point p, not the triangle's size, so a
small mesh far from the origin, or a thin gap, reads lighter; it traces float32 positions as
given, where aobake rebases them first.  A view with a finite ``--max-distance``, the
uniform weighting, ``--backfaces ignore`` or another method has no Mitsuba equivalent in
this scene: the export is written with a warning saying so.
"""

from __future__ import annotations

import base64
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from aobake.errors import InputError, OutputError, UsageError

log = logging.getLogger(__name__)

#: the suffixes each export writes (chosen by its flag, checked by the suffix)
SUFFIXES = {"gltf": (".gltf", ".glb"), "mitsuba": (".xml",)}
#: the ground plane's quad: half its side, in bounding-box diagonals of the scene.  A point
#: at height h <= one diagonal over it misses at most the cosine-weighted part of the plane
#: beyond the quad, h^2 / (h^2 + L^2) <= 1e-6 of its AO.
GROUND_HALF_SIZE = 1000.0
#: the glTF camera's and node's name
CAMERA_NAME = "aobake_view"
#: Mitsuba's scene format version written
MITSUBA_FORMAT = "3.0.0"
#: settings a scene of one mesh cannot carry: refused before any work (the exported scene
#: would not be the one baked)
NOT_EXPORTABLE = {
    "receive_only": "--receive-only faces are baked but cast nothing",
    "occluder_only": "--occluder-only faces cast but are not baked",
    "alpha_cutout": "--alpha-cutout cuts faces by their texture's alpha",
}

_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_FLOAT, _UNSIGNED_INT = 5126, 5125
_AXES = "xyz"


@dataclass(frozen=True)
class Exports:
    """The files one view's exports will write, checked before the bake (:func:`plan`).

    gltf : .gltf/.glb path or None; mitsuba : .xml path or None; mitsuba_mesh : the PLY
    beside it (``<stem>.ply``) or None.
    """

    gltf: Path | None = None
    mitsuba: Path | None = None
    mitsuba_mesh: Path | None = None

    def paths(self) -> list[Path]:
        """Every file written, in the order :func:`write_view` returns them."""
        return [p for p in (self.gltf, self.mitsuba, self.mitsuba_mesh) if p is not None]

    def __bool__(self) -> bool:
        return bool(self.paths())


def _setting(config, name, default=None):
    if config is None:
        return default
    if isinstance(config, dict):
        return config.get(name, default)
    return getattr(config, name, default)


def plan(gltf=None, mitsuba=None, *, config=None, taken=()) -> Exports:
    """Check the export paths before any work: suffixes, directories, and no file written
    twice or over an input.

    gltf : a .gltf or .glb path (or None); mitsuba : an .xml path (or None), its mesh goes
    beside it as ``<stem>.ply``; config : the view's BakeConfig (or its dict), whose
    ``receive_only`` / ``occluder_only`` / ``alpha_cutout`` a one-mesh scene cannot carry
    (UsageError); taken : {role: path} (or paths) of the view's other outputs and inputs,
    none of which an export may overwrite.  OutputError naming the path otherwise.
    """
    for name, why in NOT_EXPORTABLE.items():
        # only an export asked for is refused: a view with groups and no export is a view
        if (gltf is not None or mitsuba is not None) and _setting(config, name):
            raise UsageError(f"the exported scene holds one mesh every renderer sees and "
                             f"occludes with; {why}: no export of such a view")
    paths = {}
    for kind, flag, path in (("gltf", "--export-camera", gltf),
                             ("mitsuba", "--export-mitsuba", mitsuba)):
        if path is None:
            continue
        if not isinstance(path, (str, os.PathLike)):
            raise InputError(f"{flag}: a file path, got {path!r}")
        path = Path(path)
        if path.suffix.lower() not in SUFFIXES[kind]:
            raise OutputError(f"{path}: {flag} writes {' or '.join(SUFFIXES[kind])}, not "
                              f"{path.suffix or 'a file without a suffix'}")
        paths[kind] = path
    mesh = None
    if "mitsuba" in paths:
        mesh = paths["mitsuba"].with_suffix(".ply")
    exports = Exports(paths.get("gltf"), paths.get("mitsuba"), mesh)
    roles = {"--export-camera": exports.gltf, "--export-mitsuba": exports.mitsuba,
             "the Mitsuba scene's mesh (<stem>.ply)": exports.mitsuba_mesh}
    seen = {}
    named = taken.items() if isinstance(taken, dict) else (("another file", p) for p in taken)
    for role, other in named:
        if isinstance(other, (str, os.PathLike)):
            seen.setdefault(Path(other).resolve(), role)
    for role, path in roles.items():
        if path is None:
            continue
        if not path.parent.resolve().is_dir():
            raise OutputError(f"{path}: directory {path.parent} does not exist")
        if path.is_dir():
            raise OutputError(f"{path}: is a directory; {role} needs a file name")
        where = path.resolve()
        if where in seen:
            raise OutputError(f"{path}: refusing to write {role} over {seen[where]}: every "
                              "output needs its own file")
        seen[where] = role
    return exports


# ---- geometry --------------------------------------------------------------------------------

def camera_to_world(camera) -> np.ndarray:
    """(4, 4) float64 camera -> world transform of ``camera`` (``aobake.camera.Camera``),
    column vectors: inverse(``world_to_view``), columns right, up, -forward (view +X, +Y,
    +Z in world space) and the eye.  The node matrix of a glTF camera (-Z forward, +Y up)."""
    matrix = np.eye(4)
    matrix[:3, 0] = camera.right
    matrix[:3, 1] = camera.up
    matrix[:3, 2] = -camera.forward
    matrix[:3, 3] = camera.eye
    return matrix


def ground_quad(bounds, axis: str, height: float) -> tuple[np.ndarray, np.ndarray]:
    """The ground plane as a square: vertices (4, 3) float64, faces (2, 3) int64, facing
    +``axis`` (counter-clockwise seen from above), at ``height`` along ``axis``, centred under
    the box ``bounds`` (2, 3), half its side GROUND_HALF_SIZE diagonals of the box (1 for a
    point box)."""
    if axis not in _AXES:
        raise InputError(f"ground plane axis must be one of x, y, z, got {axis!r}")
    lo, hi = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    k = _AXES.index(axis)
    half = GROUND_HALF_SIZE * (float(np.linalg.norm(hi - lo)) or 1.0)
    centre = 0.5 * (lo + hi)
    centre[k] = height
    u, v = np.zeros(3), np.zeros(3)
    u[(k + 1) % 3], v[(k + 2) % 3] = half, half  # (u, v, axis) right-handed: u x v = +axis
    vertices = np.stack([centre - u - v, centre + u - v, centre + u + v, centre - u + v])
    return vertices, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)


def _check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise InputError(f"export: vertices must be (n, 3) floats, n >= 1, got "
                         f"{vertices.shape}")
    if not np.isfinite(vertices).all():
        raise InputError("export: vertices must be finite")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0 or faces.dtype.kind not in "iu":
        raise InputError(f"export: faces must be (f, 3) integers, f >= 1, got {faces.shape} "
                         f"{faces.dtype}")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError(f"export: face index out of range (have {len(vertices)} vertices)")
    if faces.max() > np.iinfo(np.int32).max:
        raise InputError("export: more vertices than 32-bit indices hold")
    return vertices, faces.astype(np.int64)


def _check_camera(camera):
    from aobake.camera import Camera

    if not isinstance(camera, Camera):
        raise InputError(f"export: camera must be an aobake.camera.Camera, got "
                         f"{type(camera).__name__}")
    if camera.near is None or camera.far is None:
        raise InputError("export: the camera's near/far clip planes are not set "
                         "(aobake.camera.fit_clip sets them; a view's camera has them)")


# ---- glTF ------------------------------------------------------------------------------------

def gltf_document(vertices, faces, camera, *, ground=None, metadata=None
                  ) -> tuple[dict, bytes]:
    """The glTF JSON object and its buffer's bytes for a mesh and a camera (module docstring).

    vertices : (n, 3) float world positions (stored float32), faces : (f, 3) int;
    camera : ``aobake.camera.Camera`` with near/far; ground : (vertices (4, 3), faces (2, 3))
    or None, a second mesh node ``ground_plane``; metadata : JSON-able dict for
    ``asset.extras`` or None.  The buffer has no ``uri``: the caller embeds or points to it.
    """
    from aobake.outputs.strictjson import check_metadata, to_jsonable

    vertices, faces = _check_mesh(vertices, faces)
    _check_camera(camera)
    blob = bytearray()
    gltf: dict = {"asset": {"version": "2.0", "generator": "aobake"}}
    extras = to_jsonable(check_metadata(metadata))
    if extras:
        gltf["asset"]["extras"] = extras
    material = {"name": "aobake_white", "doubleSided": True,
                "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0],
                                         "metallicFactor": 0.0, "roughnessFactor": 1.0}}
    gltf["materials"] = [material]
    parts = [("aobake_mesh", vertices, faces)]
    if ground is not None:
        parts.append(("ground_plane",) + _check_mesh(*ground))
    meshes, nodes = [], []
    for name, positions, triangles in parts:
        position = _accessor(gltf, blob, positions.astype(np.float32), _ARRAY_BUFFER, "VEC3",
                             bounds=True)
        indices = _accessor(gltf, blob, triangles.reshape(-1).astype(np.uint32),
                            _ELEMENT_ARRAY_BUFFER, "SCALAR")
        meshes.append({"name": name, "primitives": [
            {"attributes": {"POSITION": position}, "indices": indices, "material": 0,
             "mode": 4}]})
        nodes.append({"name": name, "mesh": len(meshes) - 1})
    gltf["meshes"] = meshes
    gltf["cameras"] = [{
        "name": CAMERA_NAME, "type": "perspective",
        "perspective": {"yfov": math.radians(camera.fov_y), "aspectRatio": camera.aspect,
                        "znear": camera.near, "zfar": camera.far},
        # glTF has no image size; Blender's importer keeps extras as custom properties
        "extras": {"width": camera.width, "height": camera.height}}]
    matrix = camera_to_world(camera)
    matrix[3] = (0.0, 0.0, 0.0, 1.0)  # exactly affine, as glTF requires
    nodes.insert(0, {"name": CAMERA_NAME, "camera": 0,
                     # glTF stores matrices column-major
                     "matrix": [float(x) for x in matrix.T.reshape(-1)]})
    gltf["nodes"] = nodes
    gltf["scenes"] = [{"nodes": list(range(len(nodes)))}]
    gltf["scene"] = 0
    blob.extend(b"\0" * (-len(blob) % 4))
    gltf["buffers"] = [{"byteLength": len(blob)}]
    return gltf, bytes(blob)


def _accessor(gltf, blob, values, target, kind, bounds=False) -> int:
    blob.extend(b"\0" * (-len(blob) % 4))  # 4-byte aligned components
    views = gltf.setdefault("bufferViews", [])
    views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": values.nbytes,
                  "target": target})
    blob.extend(np.ascontiguousarray(values, dtype=values.dtype.newbyteorder("<")).tobytes())
    accessor = {"bufferView": len(views) - 1,
                "componentType": _FLOAT if values.dtype == np.float32 else _UNSIGNED_INT,
                "count": len(values), "type": kind}
    if bounds:  # min/max of the stored float32 values, as a validator reads them back
        accessor["min"] = [float(v) for v in values.min(axis=0)]
        accessor["max"] = [float(v) for v in values.max(axis=0)]
    accessors = gltf.setdefault("accessors", [])
    accessors.append(accessor)
    return len(accessors) - 1


def write_gltf(path, vertices, faces, camera, *, ground=None, metadata=None) -> Path:
    """Write the mesh and ``camera`` as a glTF (``.glb``: a GLB container; ``.gltf``: JSON
    with the buffer in a ``data:`` URI), atomically (inside an enclosing
    ``aobake.outputs.atomic.transaction``, with its other files).  Arguments as
    :func:`gltf_document`; returns ``path``."""
    import json

    from aobake.outputs.atomic import atomic_path
    from aobake.outputs.gltf import write_glb

    path = Path(path)
    if path.suffix.lower() not in SUFFIXES["gltf"]:
        raise OutputError(f"{path}: a glTF export is .gltf or .glb, not "
                          f"{path.suffix or 'a file without a suffix'}")
    gltf, blob = gltf_document(vertices, faces, camera, ground=ground, metadata=metadata)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:
            if path.suffix.lower() == ".glb":
                write_glb(handle, gltf, blob)
            else:
                gltf["buffers"][0]["uri"] = ("data:application/octet-stream;base64,"
                                             + base64.b64encode(blob).decode("ascii"))
                handle.write(json.dumps(gltf, indent=1, allow_nan=False).encode("utf-8"))
    log.debug("wrote %s: %d vertices, %d faces and camera %s", path, len(vertices),
              len(faces), CAMERA_NAME)
    return path


# ---- Mitsuba 3 -------------------------------------------------------------------------------

def _numbers(values) -> str:
    return ", ".join(repr(float(v)) for v in values)


def mitsuba_scene(camera, mesh_file: str, *, ground=None, spp: int = 64,
                  far_clip: float | None = None, notes=()) -> str:
    """The Mitsuba 3 scene XML (module docstring) for ``camera`` (``aobake.camera.Camera``
    with near/far) and the mesh file ``mesh_file`` (a name relative to the XML, .ply/.obj);
    ground : (vertices (4, 3), faces (2, 3)) or None, written as a ``rectangle``; spp : the
    default samples per pixel; far_clip : None = the camera's far; notes : lines for the
    comment at the top."""
    _check_camera(camera)
    if isinstance(spp, bool) or not isinstance(spp, (int, np.integer)) or spp < 1:
        raise InputError(f"export: spp must be a positive integer, got {spp!r}")
    far = camera.far if far_clip is None else max(float(far_clip), camera.far)
    forward = camera.forward
    lines = [
        '<?xml version="1.0" encoding="utf-8"?>',
        "<!-- aobake view's camera and scene for Mitsuba 3 (docs/renderers.md).",
        "     AO per pixel = R / A (the film is premultiplied: A is the fraction of the",
        "     pixel's samples that hit, aobake's coverage); the box filter is aobake's",
        "     pixel filter 'box'."
        # an XML comment may not hold two hyphens in a row
        + "".join(f"\n     Not as the view: {note.replace('--', '-')}." for note in notes)
        + " -->",
        f'<scene version="{MITSUBA_FORMAT}">',
        f'    <default name="spp" value="{int(spp)}"/>',
        "    <!-- Mitsuba 3 has no AO plugin: direct lighting of a white diffuse surface",
        "         under a white sky, one cosine-distributed BSDF ray per sample, is AO -->",
        '    <integrator type="direct">',
        '        <integer name="emitter_samples" value="0"/>',
        '        <integer name="bsdf_samples" value="1"/>',
        '        <boolean name="hide_emitters" value="true"/>',
        "    </integrator>",
        '    <sensor type="perspective" id="aobake_view">',
        '        <string name="fov_axis" value="y"/>',
        f'        <float name="fov" value="{camera.fov_y!r}"/>',
        f'        <float name="near_clip" value="{camera.near!r}"/>',
        f'        <float name="far_clip" value="{far!r}"/>',
        '        <transform name="to_world">',
        f'            <lookat origin="{_numbers(camera.eye)}" '
        f'target="{_numbers(camera.eye + forward)}" up="{_numbers(camera.up)}"/>',
        "        </transform>",
        '        <sampler type="independent">',
        '            <integer name="sample_count" value="$spp"/>',
        "        </sampler>",
        '        <film type="hdrfilm">',
        f'            <integer name="width" value="{camera.width}"/>',
        f'            <integer name="height" value="{camera.height}"/>',
        '            <string name="pixel_format" value="rgba"/>',
        '            <rfilter type="box"/>',
        "        </film>",
        "    </sensor>",
        '    <bsdf type="twosided" id="white">',
        '        <bsdf type="diffuse">',
        '            <rgb name="reflectance" value="1.0"/>',
        "        </bsdf>",
        "    </bsdf>",
        '    <emitter type="constant">',
        '        <rgb name="radiance" value="1.0"/>',
        "    </emitter>",
        f'    <shape type="{Path(mesh_file).suffix.lower()[1:] or "ply"}" id="aobake_mesh">',
        f'        <string name="filename" value={quoteattr(str(mesh_file))}/>',
        '        <boolean name="face_normals" value="true"/>',
        '        <ref id="white"/>',
        "    </shape>",
    ]
    if ground is not None:
        corners, _ = ground
        corners = np.asarray(corners, dtype=np.float64)
        centre = corners.mean(axis=0)
        # rectangle: [-1, 1]^2 in z = 0 facing +z; columns: half sides u, v and their normal
        u, v = 0.5 * (corners[1] - corners[0]), 0.5 * (corners[3] - corners[0])
        n = np.cross(u, v)
        n /= np.linalg.norm(n)
        matrix = np.eye(4)
        matrix[:3, 0], matrix[:3, 1], matrix[:3, 2], matrix[:3, 3] = u, v, n, centre
        lines += [
            '    <shape type="rectangle" id="ground_plane">',
            '        <transform name="to_world">',
            f'            <matrix value="{" ".join(repr(float(x)) for x in matrix.reshape(-1))}"/>',
            "        </transform>",
            '        <ref id="white"/>',
            "    </shape>",
        ]
    lines.append("</scene>")
    return "\n".join(lines) + "\n"


def _write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """A binary little-endian PLY of float64 x y z and int32 triangles, nothing else."""
    vertex = np.ascontiguousarray(vertices, dtype="<f8")
    face = np.empty(len(faces), dtype=[("count", "|u1"), ("vertex_indices", "<i4", (3,))])
    face["count"] = 3
    face["vertex_indices"] = faces
    header = ("ply\nformat binary_little_endian 1.0\ncomment aobake view export\n"
              f"element vertex {len(vertex)}\nproperty double x\nproperty double y\n"
              f"property double z\nelement face {len(faces)}\n"
              "property list uchar int vertex_indices\nend_header\n")
    with open(path, "wb") as handle:
        handle.write(header.encode("ascii"))
        handle.write(vertex.tobytes())
        handle.write(face.tobytes())


def write_mitsuba(path, vertices, faces, camera, *, ground=None, spp: int = 64,
                  notes=()) -> list[Path]:
    """Write the Mitsuba 3 scene ``path`` (.xml) and its mesh beside it (``<stem>.ply``),
    atomically (inside an enclosing transaction, with its other files).  vertices (n, 3)
    float, faces (f, 3) int, camera, ground, spp, notes: :func:`mitsuba_scene`'s.  Returns
    [the XML, the PLY]."""
    from aobake.outputs.atomic import atomic_path, transaction

    path = Path(path)
    if path.suffix.lower() not in SUFFIXES["mitsuba"]:
        raise OutputError(f"{path}: a Mitsuba scene is .xml, not "
                          f"{path.suffix or 'a file without a suffix'}")
    vertices, faces = _check_mesh(vertices, faces)
    mesh = path.with_suffix(".ply")
    every = vertices if ground is None else np.vstack([vertices, ground[0]])
    # far_clip past every vertex written, so the ground quad is not cut at the view's far
    far = float(np.max((every - camera.eye) @ camera.forward)) * 1.01
    text = mitsuba_scene(camera, mesh.name, ground=ground, spp=spp, far_clip=far, notes=notes)
    with transaction():
        with atomic_path(mesh) as tmp:
            _write_ply(tmp, vertices, faces)
        with atomic_path(path) as tmp:
            tmp.write_text(text, encoding="utf-8")
    log.debug("wrote %s and %s: %d vertices, %d faces", path, mesh, len(vertices), len(faces))
    return [path, mesh]


def mitsuba_differences(config, method: str = "rays") -> list[str]:
    """What in a view's settings (a BakeConfig or the report's ``config`` dict) and method
    the Mitsuba scene does not reproduce: one sentence each, [] when it renders the same
    AO."""
    notes = []
    if method != "rays":
        notes.append(f"method {method}: the scene renders the ray-traced AO, not this "
                     "method's estimate")
    distance = _setting(config, "max_distance", math.inf)
    try:
        finite = math.isfinite(float(distance))
    except (TypeError, ValueError):  # a 'P%' text: finite
        finite = True
    if finite:
        notes.append(f"max_distance {distance}: Mitsuba's direct integrator has no ray "
                     "length; it renders the unbounded AO")
    if _setting(config, "weighting", "cosine") != "cosine":
        notes.append("weighting uniform: the scene renders cosine-weighted AO")
    if _setting(config, "backfaces", "occlude") != "occlude":
        notes.append("backfaces ignore: in Mitsuba every face occludes")
    quantities = tuple(_setting(config, "quantities", ("ao",)) or ("ao",))
    if "ao" not in quantities:
        notes.append(f"quantities {', '.join(quantities)}: the scene renders ao")
    return notes


def _default(name: str):
    from aobake.settings import BakeConfig

    return BakeConfig.__dataclass_fields__[name].default


# ---- a view's exports ------------------------------------------------------------------------

def view_geometry(result, mesh) -> tuple[np.ndarray, np.ndarray, tuple | None]:
    """The scene ``result`` (a ViewResult) was baked on: (vertices (n, 3) float64, faces
    (f, 3) int64, ground quad or None), from ``mesh`` (the path or mesh the view was given)
    loaded as its report's config says (normals and repair, ``--exclude``) and its
    ground plane's axis and height."""
    from aobake import groups
    from aobake.scene import load_scene

    report = result.report if isinstance(getattr(result, "report", None), dict) else {}
    config = report.get("config", {})
    scene = load_scene(mesh, config.get("normals", "file"), config.get("fix_normals", "warn"))
    selection = groups.Selection(tuple(config.get("exclude") or ()),
                                 tuple(config.get("receive_only") or ()),
                                 tuple(config.get("occluder_only") or ()))
    if selection:
        scene = groups.apply(scene, selection).scene
    plane = report.get("parameters", {}).get("ground_plane")
    ground = None
    if plane:
        ground = ground_quad(scene.bounds, plane["axis"], float(plane["height"]))
    return scene.vertices, scene.faces, ground


def write_view(result, mesh, exports: Exports) -> list[Path]:
    """Write ``exports`` (:func:`plan`) of the view ``result`` (``aobake.bake_view``'s) of
    ``mesh``, in one transaction (the enclosing one, if any: ``aobake view`` writes them in
    the transaction of its image, camera file and report).  Returns the paths written."""
    from aobake.outputs.atomic import transaction
    from aobake.records import ViewResult

    if not isinstance(result, ViewResult):
        raise InputError(f"export: result must be a view's (ViewResult), got "
                         f"{type(result).__name__}")
    if not exports:
        return []
    for name, why in NOT_EXPORTABLE.items():
        if result.report.get("config", {}).get(name):
            raise UsageError(f"the exported scene holds one mesh; {why}: no export of such "
                             "a view")
    vertices, faces, ground = view_geometry(result, mesh)
    camera = result.camera
    record = result.report.get("camera")
    written = []
    with transaction():
        if exports.gltf is not None:
            meta = {"camera": record, "conventions": result.report.get("conventions")}
            written.append(write_gltf(exports.gltf, vertices, faces, camera, ground=ground,
                                      metadata=meta))
        if exports.mitsuba is not None:
            config = result.report.get("config", {})
            differences = mitsuba_differences(
                config, result.report.get("parameters", {}).get("method", "rays"))
            for note in differences:
                log.warning("%s: %s", exports.mitsuba, note)
            if record and record.get("pixel_filter", "center") != "box":
                log.info("%s: the view's pixels are centre samples; Mitsuba's box filter "
                         "averages over the pixel (compare with --pixel-filter box)",
                         exports.mitsuba)
            written += write_mitsuba(exports.mitsuba, vertices, faces, camera, ground=ground,
                                     spp=int(config.get("rays", _default("rays"))),
                                     notes=differences)
    return written


def export_view(result, mesh, *, gltf=None, mitsuba=None) -> list[Path]:
    """The library's ``--export-camera`` / ``--export-mitsuba``: :func:`plan` then
    :func:`write_view` for a view ``result`` of ``mesh``.  gltf : .gltf/.glb path or None;
    mitsuba : .xml path or None.  Returns the paths written."""
    exports = plan(gltf, mitsuba, config=getattr(result, "report", {}).get("config"),
                   taken={"the input mesh": mesh} if isinstance(mesh, (str, os.PathLike))
                   else ())
    return write_view(result, mesh, exports)
