"""Values from a bake file (``--method file --ao-from ao.ply`` or ``--ao-from ao.exr``): how a
user looks at a bake, or moves a vertex bake into a lightmap.

No estimate is made.  The file is one of two kinds (``aobake.outputs.read`` tells them by
their format):

- a **per-vertex bake** (.npz, .ply, .glb): its values (every scalar ``-q`` quantity it
  holds: ``ao``, ``obscurance``) are interpolated at each sample point with the barycentric
  coordinates of the point on its triangle, which the target gives (``SamplePoints.faces``,
  ``.bary``: camera pixels and lightmap texels have them).  It must be a bake of the same
  mesh: the same vertices, in the same order (checked by count and by position);
- a **lightmap** (.exr, .png, .tif): looked up at the point's UV (UV set ``--uv-set`` of the
  mesh, interpolated with the same barycentrics) as an engine samples a texture: bilinear,
  texel (r, c) centred at u = (c + 0.5) / W, v = 1 - (r + 0.5) / H (docs/conventions.md,
  "Lightmaps"), wrapping as the map's metadata says (``texture.wrap``: clamp to the edge
  or repeat; clamp for an image without aobake's metadata).  One level: no mip maps (a
  lookup reads the four texels around its UV whatever the pixel's footprint; a
  box-filtered view, ``--pixel-filter box``, averages lookups over the pixel instead).
  The mesh must be the one the map was baked on (a new atlas is written beside the map:
  ``<out>.obj``); the report's ``parameters.lookups_in_charts`` says how many lookups read
  a texel the map covers, and a warning says when few do.

Deterministic, no rays and no stderr: the file's own errors are not carried through an
interpolation (read them from the file).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aobake.errors import InputError
from aobake.settings.file import FileOptions  # noqa: F401  (the method's settings)
from aobake.records import Estimates
from aobake.vectors import defined

log = logging.getLogger(__name__)

#: the wrap modes of a lightmap lookup (an aobake map's ``texture.wrap``)
WRAPS = ("clamp", "repeat")
#: below this fraction of lookups on texels the map covers, a warning: the UVs are likely
#: not the map's (another mesh, another UV set); gutters and bilinear reads at chart edges
#: keep a right mesh's fraction near 1
IN_CHARTS_WARNING = 0.9


@dataclass(frozen=True)
class Lightmap:
    """A lightmap and the UVs it is looked up at.

    images : quantity -> (H, W) float64, row 0 the top of the image (v = 1); covered : (H,
    W) bool the texels the map covers (its coverage; all True without one); wrap : 'clamp'
    | 'repeat'; corners : (f, 3, 2) float64 the UV (OBJ convention, v up) of each corner of
    each face of the mesh; uv_set : which of the mesh's UV sets they are.
    """

    images: dict
    covered: np.ndarray
    wrap: str
    corners: np.ndarray
    uv_set: int

    @property
    def size(self) -> tuple[int, int]:
        """(W, H) texels."""
        height, width = self.covered.shape
        return width, height


def bilinear(image: np.ndarray, uv: np.ndarray, wrap: str = "clamp") -> np.ndarray:
    """(n,) float64: ``image`` (H, W) float read at ``uv`` (n, 2) float64 as a GPU's bilinear
    filter reads a texture.

    Texel (r, c) holds the value at its centre, u = (c + 0.5) / W, v = 1 - (r + 0.5) / H
    (row 0 at the top, v = 0 at the bottom: OBJ's and aobake's convention), so the lookup is
    at continuous texel coordinates x = u W - 0.5, y = (1 - v) H - 0.5 and weights the four
    texels around (x, y) by (1 - fx)(1 - fy), fx (1 - fy), (1 - fx) fy, fx fy.  wrap
    'clamp' (CLAMP_TO_EDGE: indices clamped into the image) or 'repeat' (taken modulo the
    size).  A lookup at a texel centre returns that texel exactly.
    """
    if wrap not in WRAPS:
        raise InputError(f"lightmap wrap must be one of {WRAPS}, got {wrap!r}")
    image = np.asarray(image, dtype=np.float64)
    height, width = image.shape
    uv = np.asarray(uv, dtype=np.float64)
    x = uv[:, 0] * width - 0.5
    y = (1.0 - uv[:, 1]) * height - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)

    def index(i, n):
        return np.mod(i, n) if wrap == "repeat" else np.clip(i, 0, n - 1)

    c0, c1 = index(x0, width), index(x0 + 1, width)
    r0, r1 = index(y0, height), index(y0 + 1, height)
    return ((1.0 - fy) * ((1.0 - fx) * image[r0, c0] + fx * image[r0, c1])
            + fy * ((1.0 - fx) * image[r1, c0] + fx * image[r1, c1]))


def _texels_read(covered: np.ndarray, uv: np.ndarray, wrap: str) -> np.ndarray:
    """(n,) bool: the texel nearest each lookup ``uv`` (n, 2) is one the map covers."""
    height, width = covered.shape
    c = np.floor(uv[:, 0] * width).astype(np.int64)
    r = np.floor((1.0 - uv[:, 1]) * height).astype(np.int64)
    if wrap == "repeat":
        c, r = np.mod(c, width), np.mod(r, height)
    else:
        c, r = np.clip(c, 0, width - 1), np.clip(r, 0, height - 1)
    return covered[r, c]


class FileMethod:
    """A bake file's values at the points: a per-vertex bake interpolated on the surface, or
    a lightmap looked up at the surface's UVs."""

    name = "file"
    casts_rays = False

    def __init__(self, path: Path, values: dict, faces: np.ndarray,
                 lightmap: Lightmap | None = None):
        """path : the bake file, values : quantity -> (v,) float64 per vertex ({} for a
        lightmap), faces : (f, 3) int64 the scene's triangles, lightmap : the map and the
        mesh's UVs, or None for a per-vertex bake."""
        self.path, self.values, self._faces, self.lightmap = path, values, faces, lightmap

    @classmethod
    def prepare(cls, scene, config, occluders, rays_per_point: int,
                compiled: bool | None = None) -> "FileMethod":
        from aobake.outputs import read

        if config.ao_from is None:
            raise InputError("--method file needs --ao-from FILE (a per-vertex bake of the "
                             "mesh, or a lightmap of it)")
        path = Path(config.ao_from)
        wanted = [q for q in config.quantities if q in ("ao", "obscurance")]
        if not wanted:
            raise InputError(f"{path}: --method file reads ao or obscurance; got -q "
                             f"{', '.join(config.quantities)}")
        read_values = {quantity: read(path, quantity, role="reference") for quantity in wanted}
        first = read_values[wanted[0]]
        if first.target == "texels":
            return cls(path, {}, scene.faces, _lightmap(path, read_values, scene, config))
        values = {}
        for quantity, read_value in read_values.items():
            value = np.asarray(read_value.value, dtype=np.float64)
            if value.shape != (len(scene.vertices),):
                raise InputError(f"{path}: {value.shape[0]} vertices, the mesh "
                                 f"{scene.source} has {len(scene.vertices)}: not a bake of "
                                 "this mesh")
            positions = read_value.positions
            if positions is not None:
                # float32 files (GLB) hold positions to float32's precision
                tol = 4 * np.finfo(np.float32).eps * max(scene.diagonal, 1e-300) + \
                    4 * np.finfo(np.float32).eps * float(np.abs(scene.vertices).max())
                far = float(np.abs(positions - scene.vertices).max())
                if not far <= tol:
                    raise InputError(f"{path}: its vertices are not the mesh's (they differ by "
                                     f"up to {far:.3g}): not a bake of {scene.source}")
            if not np.isfinite(value).all():
                raise InputError(f"{path}: {quantity} holds non-finite values")
            values[quantity] = value
        return cls(path, values, scene.faces)

    def estimate(self, points, threads: int, chunk_rays: int, progress=None) -> Estimates:
        """points : SamplePoints with ``faces`` (n,) int64 and ``bary`` (n, 3) float64."""
        if points.faces is None or points.bary is None:
            raise InputError(f"{self.path}: --method file interpolates on triangles; this "
                             "target gives no triangle per point (use a view or a lightmap)")
        return self.interpolate(points.faces, points.bary, points.normals)

    def interpolate(self, faces: np.ndarray, bary: np.ndarray, normals: np.ndarray) -> Estimates:
        """The values at barycentric ``bary`` (n, 3) of triangles ``faces`` (n,) of the
        scene; 0 where the normal is zero (no point there) or the face is -1 (no triangle:
        the ground plane holds no file values).  A lightmap's estimates carry the extra
        ``in_charts`` (n,) bool: the texel nearest the lookup is one the map covers."""
        fields = {}
        ok = defined(normals) & (faces >= 0)  # -1: a point on no triangle (the ground plane)
        if self.lightmap is not None:
            lightmap = self.lightmap
            uv = np.einsum("nc,ncd->nd", bary, lightmap.corners[np.maximum(faces, 0)])
            for name, image in lightmap.images.items():
                fields[name] = np.where(ok, bilinear(image, uv, lightmap.wrap), 0.0)
            read = _texels_read(lightmap.covered, uv, lightmap.wrap) & ok
            return Estimates(fields, None, {"in_charts": read, "looked_up": ok})
        corners = self._faces[np.maximum(faces, 0)]
        for name, value in self.values.items():
            out = np.einsum("nc,nc->n", bary, value[corners])
            fields[name] = np.where(ok, out, 0.0)
        return Estimates(fields, None, {})

    def record(self, estimates: Estimates) -> dict:
        if self.lightmap is None:
            return {"parameters": {"method": self.name, "ao_from": str(self.path),
                                   "quantities": sorted(self.values),
                                   "interpolation": "barycentric, of the file's per-vertex "
                                                    "values"}}
        lightmap = self.lightmap
        looked = int(np.count_nonzero(estimates.extras["looked_up"]))
        inside = int(np.count_nonzero(estimates.extras["in_charts"]))
        fraction = inside / looked if looked else None
        if fraction is not None and fraction < IN_CHARTS_WARNING:
            log.warning("%s: %d of %d lookups (%.0f%%) read texels the lightmap does not "
                        "cover: is the mesh the one it was baked on (a new atlas is written "
                        "beside the map: <out>.obj), with --uv-set %d?", self.path,
                        looked - inside, looked, 100 * (1 - fraction), lightmap.uv_set)
        width, height = lightmap.size
        return {"parameters": {
            "method": self.name, "ao_from": str(self.path),
            "quantities": sorted(lightmap.images),
            "interpolation": "the lightmap looked up at each point's UV (its triangle's UVs "
                             "interpolated barycentrically): bilinear, texel (r, c) centred "
                             "at u = (c + 0.5) / W, v = 1 - (r + 0.5) / H; one level, no mip "
                             "maps",
            "lightmap": {"width": width, "height": height, "wrap": lightmap.wrap,
                         "uv_set": lightmap.uv_set},
            "lookups_in_charts": fraction}}

    def error_quantities(self) -> list:
        return []

    def kernel_stages(self) -> dict:
        return {}


def _lightmap(path: Path, read_values: dict, scene, config) -> Lightmap:
    """The lightmap of ``read_values`` (quantity -> Values of an image) and the mesh's UVs
    in set ``config.uv_set``; InputError naming the file for a view, non-finite values, a
    map of another UV set, or a mesh without those UVs."""
    first = next(iter(read_values.values()))
    metadata = first.metadata or {}
    if isinstance(metadata.get("camera"), dict):
        raise InputError(f"{path}: is a camera view (aobake view), not a lightmap: --ao-from "
                         "reads a per-vertex bake or a lightmap")
    images = {}
    for quantity, values in read_values.items():
        image = np.asarray(values.value, dtype=np.float64)
        if image.ndim != 2 or not image.size:
            raise InputError(f"{path}: {quantity} is not an image ({image.shape})")
        if not np.isfinite(image).all():
            raise InputError(f"{path}: {quantity} holds non-finite values")
        images[quantity] = image
    texture = metadata.get("texture") if isinstance(metadata.get("texture"), dict) else {}
    wrap = texture.get("wrap", "clamp")
    if wrap not in WRAPS:
        raise InputError(f"{path}: its metadata's texture.wrap is {wrap!r}, not one of {WRAPS}")
    baked_set = texture.get("uv_set")
    if isinstance(baked_set, int) and baked_set != config.uv_set:
        raise InputError(f"{path}: was baked into UV set {baked_set} (its metadata); look it "
                         f"up there: --uv-set {baked_set}")
    covered = first.mask if first.mask is not None else np.ones(first.value.shape, dtype=bool)
    return Lightmap(images, np.asarray(covered, dtype=bool), wrap,
                    _corner_uvs(scene, config, path), config.uv_set)


def _corner_uvs(scene, config, path: Path) -> np.ndarray:
    """(f, 3, 2) float64 the UVs of set ``config.uv_set`` at each face's corners."""
    uv_set = config.uv_set
    uv, faces_uv = scene.uv, scene.faces_uv
    if scene.uv_set != uv_set:
        sets = scene.uv_sets or {}
        if uv_set in sets:
            uv, faces_uv = sets[uv_set], None
        else:  # the scene was loaded with another set (a view reads set 0): read this one
            from aobake.scene import load_scene

            if not Path(str(scene.source)).is_file():
                raise InputError(f"{path}: --uv-set {uv_set}: {scene.source} is no file to "
                                 "read that UV set from")
            other = load_scene(scene.source, config.normals, config.fix_normals, uv_set)
            if other.vertices.shape != scene.vertices.shape or \
                    not np.array_equal(other.faces, scene.faces):
                raise InputError(f"{scene.source}: its UV set {uv_set} comes with other "
                                 "vertices or faces than the scene baked")
            uv, faces_uv = other.uv, other.faces_uv
    if uv is None:
        raise InputError(f"{scene.source}: has no UVs (set {uv_set}): a lightmap ({path}) is "
                         "looked up at the mesh's UVs; give the mesh it was baked on (a new "
                         "atlas is written beside the map: <out>.obj)")
    uv = np.asarray(uv, dtype=np.float64)
    index = scene.faces if faces_uv is None else np.asarray(faces_uv)
    return uv[index]
