"""Alpha-cutout occluders (``--alpha-cutout``): a ray passes through cut-out texels.

A face whose glTF material has ``alphaMode`` MASK occludes only where its alpha is at least
the material's ``alphaCutoff`` (glTF's default 0.5); elsewhere a ray goes on.  The alpha at a
hit is the base-colour texture's alpha at the hit's UV times the base-colour factor's alpha
(glTF's definition; COLOR_0's alpha is not read), the texture sampled **bilinearly** on its
full-resolution level with **repeat** wrapping (glTF's default sampler; a
sampler's NEAREST or clamp modes are not read), texel centres at (i + 0.5) / W.

Embree (through embreex) has no filter callbacks, so the cutout faces get their own scene:
each query casts closest-hit rays at them, looks the alpha up at each hit (barycentrics of the
hit point recomputed in float64 from the triangle, so any backend serves), and recasts only the
rays that hit a cut-out texel, from just past the hit (``step``, the back-face step), up to
:data:`MAX_LAYERS` times (a ray still crossing cut-out texels then counts as blocked there, as
``--backfaces ignore`` does).  Every other face stays in the main backend at full speed; the
union (``aobake.backends.union``) asks this member only about rays the others left open.
"""

from __future__ import annotations

import io

import numpy as np

from aobake.errors import InputError
from aobake.vectors import distinct

#: cut-out layers a ray crosses before it counts as blocked where it is
MAX_LAYERS = 64


def decode_alpha(png: bytes | None, name: str = "base colour") -> np.ndarray | None:
    """(H, W) float32 alpha in [0, 1] of PNG/JPEG bytes (row 0 = the image's top), or None.
    InputError naming ``name`` (the material) where the bytes are no image."""
    if png is None:
        return None
    from PIL import Image

    try:
        with Image.open(io.BytesIO(png)) as image:
            rgba = np.asarray(image.convert("RGBA"))
    except (OSError, ValueError, Image.DecompressionBombError) as exc:
        raise InputError(f"--alpha-cutout: the base-colour texture of material {name!r} "
                         f"cannot be decoded ({type(exc).__name__}: {exc})") from None
    return (rgba[..., 3].astype(np.float32) / np.float32(255.0))


def bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(n,) float64 bilinear lookups of ``image`` (H, W) at ``uv`` (n, 2) float64 (OBJ
    convention: v = 0 at the image's bottom), repeat wrapping, texel centres at
    ((i + 0.5) / W, 1 - (j + 0.5) / H)."""
    height, width = image.shape
    x = uv[:, 0] * width - 0.5
    y = (1.0 - uv[:, 1]) * height - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    x0 = np.mod(x0.astype(np.int64), width)
    y0 = np.mod(y0.astype(np.int64), height)
    x1, y1 = (x0 + 1) % width, (y0 + 1) % height
    a = image.astype(np.float64)
    return ((1 - fx) * (1 - fy) * a[y0, x0] + fx * (1 - fy) * a[y0, x1]
            + (1 - fx) * fy * a[y1, x0] + fx * fy * a[y1, x1])


def cutout_faces(scene) -> np.ndarray | None:
    """(f,) bool the faces of ``scene`` whose material is alpha-tested (MASK), or None when
    none is (or the scene has no materials: they need UVs).

    InputError (naming the file, the material and its texture) where a MASK material some
    face uses declares a base-colour texture that could not be read (``Scene.materials``'
    "base_color_error"): without its alpha the material would occlude everywhere, a wrong
    bake that looks like a right one."""
    if scene.materials is None or scene.face_material is None:
        return None
    masked = np.array([m.get("alpha_mode") == "MASK" for m in scene.materials], dtype=bool)
    cut = masked[scene.face_material]
    if not cut.any():
        return None
    for index in distinct(scene.face_material[cut], len(scene.materials)):
        material = scene.materials[int(index)]
        if material.get("base_color_error"):
            raise InputError(f"{scene.source}: --alpha-cutout: material "
                             f"{material.get('name')!r} (alphaMode MASK): "
                             f"{material['base_color_error']}")
    return cut


class CutoutOccluder:
    """The alpha-tested faces of a scene in their own backend.

    backend : a ``TriangleBackend`` of those faces (local frame), vertices : (v, 3) float64
    local, faces : (k, 3) int64, face_normals : (k, 3) float64, uv : (k, 3, 2) float64 each
    corner's UV, material : (k,) int64 index into ``materials`` (the scene's dicts), step :
    float local units stepped past a cut-out hit, scene_faces : (k,) int64 each face's
    index in the scene.  Queries as ``aobake.backends.base`` (front ones: a back-facing hit
    passes too); ``intersect`` -> (t, prim) of the first opaque hit, prim in 0..k-1.
    """

    name = "alpha_cutout"
    #: the union may hand it only the rays the members before it left open (boolean queries)
    selective = True

    def __init__(self, backend, vertices, faces, face_normals, uv, material, materials,
                 step, scene_faces):
        self.backend = backend
        self.corners = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]  # (k, 3, 3)
        self.normals = np.asarray(face_normals, dtype=np.float64)
        self.uv = np.asarray(uv, dtype=np.float64)
        self.material = np.asarray(material, dtype=np.int64)
        self.step = np.float32(step)
        self.scene_faces = np.asarray(scene_faces, dtype=np.int64)
        used = distinct(self.material, len(materials))
        self.alpha = {int(i): decode_alpha(materials[i].get("base_color_png"),
                                           materials[i].get("name", str(i))) for i in used}
        self.factor = np.ones(len(materials))
        self.cutoff = np.full(len(materials), 0.5)
        for i, m in enumerate(materials):
            factor = m.get("base_color_factor")
            if factor is not None:
                self.factor[i] = float(factor[3])
            self.cutoff[i] = float(m.get("alpha_cutoff", 0.5))
        # The compiled march's view of the same data (aobake/_embree.c: march): the images
        # one after another in one float32 array, each material's offset (-1: none) and size.
        self._offset = np.full(len(materials), -1, dtype=np.int64)
        self._width = np.zeros(len(materials), dtype=np.int64)
        self._height = np.zeros(len(materials), dtype=np.int64)
        images, start = [], 0
        for index, image in self.alpha.items():
            if image is not None:
                self._offset[index], start = start, start + image.size
                self._height[index], self._width[index] = image.shape
                images.append(image.reshape(-1))
        self._pixels = np.concatenate(images).astype(np.float32) if images \
            else np.zeros(0, dtype=np.float32)

    def alpha_at(self, prim: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(n,) float64 the alpha at ``points`` (n, 3) float64 local on faces ``prim`` (n,).
        Sums are written out left to right (np.einsum's order depends on the CPU), as the
        compiled march adds them."""
        c = self.corners[prim]
        e1, e2, q = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0], points - c[:, 0]

        def dot(a, b):
            return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]

        d11, d12, d22 = dot(e1, e1), dot(e1, e2), dot(e2, e2)
        q1, q2 = dot(q, e1), dot(q, e2)
        det = d11 * d22 - d12 * d12
        safe = np.where(det > 0, det, 1.0)
        b1 = (d22 * q1 - d12 * q2) / safe
        b2 = (d11 * q2 - d12 * q1) / safe
        b0 = 1.0 - b1 - b2
        corner_uv = self.uv[prim]
        uv = (b0[:, None] * corner_uv[:, 0] + b1[:, None] * corner_uv[:, 1]
              + b2[:, None] * corner_uv[:, 2])
        material = self.material[prim]
        alpha = self.factor[material].copy()
        for index, image in self.alpha.items():
            if image is None:
                continue
            rows = material == index
            if rows.any():
                alpha[rows] *= bilinear(image, uv[rows])
        return alpha

    def march(self, origins, directions, tmax, front: bool = False, compiled: bool = True):
        """(t (n,) float32 the first opaque hit's distance, inf on a miss; prim (n,) int64
        its face, -1 on a miss) of local float32 rays, passing cut-out texels (and, with
        ``front``, back-facing hits).  Compiled (``aobake._embree``'s march: each ray's layers
        in one C loop, the same operations in the same order) where the backend is the
        compiled Embree binding, else (or ``compiled`` False) in numpy, layer by layer."""
        native = getattr(self.backend, "native_scene", lambda: None)() if compiled else None
        if native is not None:
            module, handle = native
            n = len(origins)
            t = np.empty(n, dtype=np.float32)
            prim = np.empty(n, dtype=np.int64)
            limit = np.ascontiguousarray(np.broadcast_to(np.asarray(tmax, dtype=np.float32),
                                                         (n,)))
            module.march(handle, _f32(origins), _f32(directions), limit,
                         np.ascontiguousarray(self.corners), np.ascontiguousarray(self.uv),
                         np.ascontiguousarray(self.material), np.ascontiguousarray(self.normals),
                         self.factor, self.cutoff, self._offset, self._width, self._height,
                         self._pixels, float(self.step), MAX_LAYERS, bool(front), t, prim)
            return t, prim
        n = len(origins)
        result = np.full(n, np.inf, dtype=np.float32)
        prim_out = np.full(n, -1, dtype=np.int64)
        travelled = np.zeros(n, dtype=np.float32)
        limit = np.broadcast_to(np.asarray(tmax, dtype=np.float32), (n,))
        org = np.array(origins, dtype=np.float32)
        directions = np.asarray(directions, dtype=np.float32)
        active = np.arange(n)
        for _ in range(MAX_LAYERS):
            if not len(active):
                break
            # a zero (not negative) limit once a ray has stepped to its end: a miss
            remaining = np.maximum(limit[active] - travelled[active], np.float32(0))
            t, prim = self.backend.intersect(org[active], directions[active], remaining)
            hit = prim >= 0
            idx, t, prim = active[hit], t[hit], prim[hit].astype(np.int64)
            d = directions[idx].astype(np.float64)
            points = org[idx].astype(np.float64) + t.astype(np.float64)[:, None] * d
            solid = self.alpha_at(prim, points) >= self.cutoff[self.material[prim]]
            if front:
                n_hit = self.normals[prim]
                solid &= (n_hit[:, 0] * d[:, 0] + n_hit[:, 1] * d[:, 1]
                          + n_hit[:, 2] * d[:, 2]) <= 0
            result[idx[solid]] = travelled[idx[solid]] + t[solid]
            prim_out[idx[solid]] = prim[solid]
            through = ~solid
            advance = t[through] + self.step
            ahead = idx[through]
            travelled[ahead] += advance
            org[ahead] += advance[:, None] * directions[ahead]
            active = ahead
        result[active] = travelled[active]  # still crossing cut-out texels: blocked there
        return result, prim_out

    def distance(self, origins, directions, tmax) -> np.ndarray:
        return self.march(origins, directions, tmax)[0]

    def occluded(self, origins, directions, tmax) -> np.ndarray:
        return np.isfinite(self.distance(origins, directions, tmax))

    def front_distance(self, origins, directions, tmax) -> np.ndarray:
        return self.march(origins, directions, tmax, front=True)[0]

    def front_occluded(self, origins, directions, tmax) -> np.ndarray:
        return np.isfinite(self.front_distance(origins, directions, tmax))

    def intersect(self, origins, directions, tmax):
        """(t (n,) float32, prim (n,) int64 -1 on a miss) of the first opaque hit."""
        return self.march(origins, directions, tmax)


def _f32(rows) -> np.ndarray:
    return np.ascontiguousarray(rows, dtype=np.float32)
