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
  or repeat; clamp for an image without aobake's metadata).  One level by default (a
  lookup reads the four texels around its UV whatever the pixel's footprint; a
  box-filtered view, ``--pixel-filter box``, averages lookups over the pixel instead); with
  ``--lightmap-filter trilinear`` a centre view reads a mip chain as an engine does
  (:func:`mip_chain`, :func:`footprint_levels`, :func:`trilinear`).
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
    #: quantity -> the mip chain of its image (``mip_chain``), for trilinear lookups; None
    levels: dict | None = None

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


def mip_chain(image: np.ndarray) -> list:
    """The mip levels of ``image`` (H, W) float64: level 0 the image, each next one the
    means of 2 x 2 texels of the one before (an odd width or height first padded with its
    last column or row, so a level is ceil(half) wide), down to 1 x 1.  A level's texel (r,
    c) covers the same part of [0, 1]^2 as the 2 x 2 it averages, so texel centres stay at
    u = (c + 0.5) / W_k, v = 1 - (r + 0.5) / H_k in every level (``bilinear``'s)."""
    levels = [np.asarray(image, dtype=np.float64)]
    while levels[-1].shape != (1, 1):
        a = levels[-1]
        for axis in (0, 1):  # the means of pairs along each axis: of 2 x 2 texels
            n = a.shape[axis]
            if n == 1:
                continue
            if n % 2:  # the last row or column twice
                a = np.concatenate([a, a.take([n - 1], axis=axis)], axis=axis)
                n += 1
            a = 0.5 * (a.take(range(0, n, 2), axis=axis) + a.take(range(1, n, 2), axis=axis))
        levels.append(a)
    return levels


def footprint_levels(cam, pixels: np.ndarray, points: np.ndarray, normals: np.ndarray,
                     triangles: np.ndarray, corner_uvs: np.ndarray, size) -> np.ndarray:
    """(n,) float64 mip level lambda = log2(rho) of each pixel's lookup, OpenGL's rho: the
    longer of the pixel's two edges in texels.  The rays through the next pixel to the right
    and down meet the hit's plane (point ``points`` (n, 3), unit normal ``normals`` (n, 3));
    the offsets to those meeting points, in the hit triangle's UV map (``triangles`` (n, 3,
    3) its corners, ``corner_uvs`` (n, 3, 2) theirs), times the map's ``size`` (W, H) are
    the pixel's edges in texels (a GPU's derivatives, on the plane, not from the next
    pixel's hit).  ``pixels`` (n,) int64 r W + c.  inf where a ray grazes the plane, 0 on a
    triangle without area in UV or space (no footprint to measure: the finest level)."""
    row, column = np.divmod(np.asarray(pixels, dtype=np.int64), cam.width)
    eye = np.asarray(cam.eye, dtype=np.float64)
    e1, e2 = triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]
    g11, g12, g22 = (np.einsum("ij,ij->i", a, b) for a, b in ((e1, e1), (e1, e2), (e2, e2)))
    det = g11 * g22 - g12 * g12
    flat = ~(det > 1e-30 * np.maximum(g11 * g22, 1e-300))
    du1, du2 = corner_uvs[:, 1] - corner_uvs[:, 0], corner_uvs[:, 2] - corner_uvs[:, 0]
    scale = np.asarray(size, dtype=np.float64)
    lengths = []
    for dx, dy in ((1.0, 0.0), (0.0, 1.0)):
        d = cam.directions_through(np.stack([column + 0.5 + dx, row + 0.5 + dy], axis=1))
        along = np.einsum("ij,ij->i", normals, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.einsum("ij,ij->i", normals, points - eye) / along
        delta = eye + t[:, None] * d - points
        r1, r2 = np.einsum("ij,ij->i", delta, e1), np.einsum("ij,ij->i", delta, e2)
        with np.errstate(divide="ignore", invalid="ignore"):
            a = (g22 * r1 - g12 * r2) / det
            b = (g11 * r2 - g12 * r1) / det
        duv = (a[:, None] * du1 + b[:, None] * du2) * scale
        length = np.hypot(duv[:, 0], duv[:, 1])
        length = np.where(np.isfinite(length) & (np.abs(along) > 1e-12), length, np.inf)
        lengths.append(length)
    rho = np.maximum(lengths[0], lengths[1])
    with np.errstate(divide="ignore"):
        level = np.log2(rho)
    return np.where(flat, 0.0, np.maximum(level, 0.0))


def trilinear(levels: list, uv: np.ndarray, level: np.ndarray, wrap: str) -> np.ndarray:
    """(n,) float64: ``bilinear`` reads of the mip chain ``levels`` at ``uv`` (n, 2) in the
    two levels around each ``level`` (n,) float64 >= 0 (inf: the coarsest), blended
    linearly by its fraction (GL_LINEAR_MIPMAP_LINEAR)."""
    top = len(levels) - 1
    level = np.minimum(level, top)
    low = np.floor(level).astype(np.int64)
    frac = level - low
    out = np.zeros(len(uv))
    for k in np.unique(low):
        at = low == k
        value = bilinear(levels[k], uv[at], wrap)
        if k < top:
            value = (1.0 - frac[at]) * value + frac[at] * bilinear(levels[k + 1], uv[at], wrap)
        out[at] = value
    return out


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
                 lightmap: Lightmap | None = None, vertices: np.ndarray | None = None):
        """path : the bake file, values : quantity -> (v,) float64 per vertex ({} for a
        lightmap), faces : (f, 3) int64 the scene's triangles, lightmap : the map and the
        mesh's UVs, or None for a per-vertex bake; vertices : (v, 3) float64 the scene's,
        for a trilinear lookup's footprints (the lightmap then carries its mip chains)."""
        self.path, self.values, self._faces, self.lightmap = path, values, faces, lightmap
        self._vertices = vertices

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
        trilinear_asked = getattr(config, "lightmap_filter", "bilinear") == "trilinear"
        if first.target == "texels":
            lightmap = _lightmap(path, read_values, scene, config)
            if trilinear_asked:
                import dataclasses

                lightmap = dataclasses.replace(lightmap, levels={
                    name: mip_chain(image) for name, image in lightmap.images.items()})
            return cls(path, {}, scene.faces, lightmap,
                       np.asarray(scene.vertices, dtype=np.float64))
        if trilinear_asked:
            raise InputError(f"{path}: is a per-vertex bake: --lightmap-filter trilinear reads "
                             "a lightmap's mip levels (give a lightmap, or drop it)")
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
        level = None
        if self.lightmap is not None and self.lightmap.levels is not None:
            image = getattr(points, "image", None)
            cam = getattr(image, "camera", None)
            if cam is None:
                raise InputError(f"{self.path}: --lightmap-filter trilinear picks a mip level by "
                                 "a camera pixel's footprint: these points are no view's pixels")
            faces = np.maximum(points.faces, 0)
            level = footprint_levels(
                cam, points.ids, np.asarray(points.points, dtype=np.float64),
                np.asarray(points.normals, dtype=np.float64),
                self._vertices[self._faces[faces]], self.lightmap.corners[faces],
                self.lightmap.size)
        return self.interpolate(points.faces, points.bary, points.normals, level)

    def interpolate(self, faces: np.ndarray, bary: np.ndarray, normals: np.ndarray,
                    level: np.ndarray | None = None) -> Estimates:
        """The values at barycentric ``bary`` (n, 3) of triangles ``faces`` (n,) of the
        scene; 0 where the normal is zero (no point there) or the face is -1 (no triangle:
        the ground plane holds no file values).  A lightmap's estimates carry the extra
        ``in_charts`` (n,) bool: the texel nearest the lookup is one the map covers.
        ``level`` (n,) float64: each lookup's mip level (trilinear), or None (bilinear)."""
        fields = {}
        ok = defined(normals) & (faces >= 0)  # -1: a point on no triangle (the ground plane)
        if self.lightmap is not None:
            lightmap = self.lightmap
            uv = np.einsum("nc,ncd->nd", bary, lightmap.corners[np.maximum(faces, 0)])
            for name, image in lightmap.images.items():
                if level is None:
                    value = bilinear(image, uv, lightmap.wrap)
                else:
                    value = trilinear(lightmap.levels[name], uv, level, lightmap.wrap)
                fields[name] = np.where(ok, value, 0.0)
            read = _texels_read(lightmap.covered, uv, lightmap.wrap) & ok
            extras = {"in_charts": read, "looked_up": ok}
            if level is not None:
                extras["mip_level"] = np.where(ok, level, np.nan)
            return Estimates(fields, None, extras)
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
        levels = estimates.extras.get("mip_level")
        filtering = "one level, no mip maps (--lightmap-filter bilinear)"
        mip = None
        if levels is not None:
            seen = levels[np.isfinite(levels)]
            filtering = ("trilinear: a mip chain of 2x2 means, level log2 of the pixel's "
                         "footprint in texels (OpenGL's rho, on the hit's plane), bilinear in "
                         "the two levels around it, blended")
            mip = {"levels": len(next(iter(lightmap.levels.values()))),
                   "mean_level": float(seen.mean()) if len(seen) else None,
                   "above_level_1": float(np.mean(seen >= 1.0)) if len(seen) else None}
        return {"parameters": {
            "method": self.name, "ao_from": str(self.path),
            "quantities": sorted(lightmap.images),
            "interpolation": "the lightmap looked up at each point's UV (its triangle's UVs "
                             "interpolated barycentrically): bilinear, texel (r, c) centred "
                             f"at u = (c + 0.5) / W, v = 1 - (r + 0.5) / H; {filtering}",
            "lightmap_filter": "bilinear" if levels is None else "trilinear",
            "mip": mip,
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
