"""Which UVs a lightmap is baked into: the mesh's own when they can be, else a new xatlas atlas.

The atlas is the mesh the map belongs to, split so each vertex has one atlas UV.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

import numpy as np

from aobake.errors import InputError
from aobake.targets.texels.packing import MAX_RESOLUTION
from aobake.targets.texels.raster import rasterize
from aobake.targets.texels.unwrap import discard_prestarted
from aobake.targets.texels.unwrap import unwrap as xatlas_unwrap
from aobake.targets.texels.seams import degenerate_faces
from aobake.targets.texels.uvcheck import bake_collapsed, check_uvs, find_overlap, wrap_uvs

#: rough bytes held per texel sample (sample record, point, normal, estimates): for the memory check
_BYTES_PER_SAMPLE = 320


@dataclass
class Atlas:
    """The mesh a lightmap belongs to, split so each vertex has one atlas UV.

    positions : (m, 3) float64, normals : (m, 3) float64, faces : (f, 3) int64,
    uv : (m, 2) float64 atlas UVs (OBJ convention), base_uv : (m, 2) float64 |
    None the mesh's own UVs when a new atlas was made for a mesh that had them,
    source_vertex : (m,) int64 index of each vertex in the input scene,
    new : bool True when the atlas was made by xatlas (the mesh must be written out),
    materials : list | None the input's materials (see Scene.materials), kept in GLBs,
    face_material : (f,) int64 | None each face's material,
    charts : int | None number of charts of a new atlas,
    wrap : str "clamp" | "repeat": how the map is sampled; "repeat" when own UVs
    outside [0, 1] were baked wrapped (``uvcheck.wrap_uvs``; ``uv`` keeps the mesh's
    values, the texels hold them modulo 1),
    size : (width, height) of the image the map is baked into,
    packing_compiled : bool | None whether a new atlas's charts were packed by the compiled
    kernels (False: the numpy reference; None: no new atlas),
    charting : str | None which xatlas charted a new atlas ("aobake._xatlas", built from
    third_party/xatlas, or "xatlas", the package: the same charts; None: no new atlas),
    uv_set : int the input's UV set the map belongs to (``--uv-set``): a GLB writes ``uv``
    as TEXCOORD_<uv_set>,
    other_uv : {k: (m, 2) float64} | None with uv_set > 0, the input's other UV sets at the
    atlas vertices (OBJ convention), written unchanged beside it,
    instances : ``aobake.targets.texels.instanced.SetLayout`` | None a lightmap of a set of
    instances (one region per baked instance; the fields above are the flattened scene's).
    """

    positions: np.ndarray
    normals: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    base_uv: np.ndarray | None
    source_vertex: np.ndarray
    new: bool
    materials: list | None = None
    face_material: np.ndarray | None = None
    charts: int | None = None
    wrap: str = "clamp"
    size: tuple | None = None
    packing_compiled: bool | None = None
    charting: str | None = None
    uv_set: int = 0
    other_uv: dict | None = None
    instances: object = None


def check_texture_budget(width: int, height: int, texel_samples: int) -> int:
    """Refuse absurd sizes with the memory they would need; returns the estimate in bytes."""
    need = width * height * (texel_samples * _BYTES_PER_SAMPLE + 64)
    if max(width, height) > MAX_RESOLUTION:
        raise InputError(f"resolution {width}x{height} is larger than {MAX_RESOLUTION} per side "
                         f"(it would need about {need / 2**30:.1f} GiB)")
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        total = None
    if total and need > total // 2:
        raise InputError(f"resolution {width}x{height} with {texel_samples} samples per texel needs "
                         f"about {need / 2**30:.1f} GiB, more than half of this machine's "
                         f"{total / 2**30:.1f} GiB")
    return need


def split_corners(*corner_indices):
    """Unique combinations of per-corner indices.

    corner_indices : k arrays (f, 3) int64, each >= 0.  Returns (keys (m, k) int64 in
    lexicographic order, faces (f, 3) int64 into them): ``np.unique(axis=0)``'s result.
    The combinations are packed into one int64 (first index most significant) when they
    fit, so one 1-D sort does it: ``np.unique`` along an axis sorts the rows as a
    structured type, 0.32 s for the bunny's new atlas against 0.02 s.
    """
    columns = [np.asarray(c, dtype=np.int64).reshape(-1) for c in corner_indices]
    spans = [int(c.max()) + 1 if len(c) else 1 for c in columns]
    if all(c.min(initial=0) >= 0 for c in columns) and math.prod(spans) < 2 ** 62:
        packed = np.zeros(len(columns[0]), dtype=np.int64)
        for c, span in zip(columns, spans):
            packed = packed * span + c
        unique, inverse = np.unique(packed, return_inverse=True)
        keys = np.empty((len(unique), len(columns)), dtype=np.int64)
        for i in range(len(columns) - 1, -1, -1):
            unique, keys[:, i] = np.divmod(unique, spans[i])
        return keys, inverse.reshape(-1, 3)
    stacked = np.stack(columns, axis=1)
    keys, inverse = np.unique(stacked, axis=0, return_inverse=True)
    return keys, inverse.reshape(-1, 3)


def own_uv_side(scene, texel_density: float) -> int:
    """The smallest square image side at which the mesh's own UVs reach ``texel_density``
    texels per scene unit on average: ceil(D sqrt(surface area / UV area)), UV area in
    units of the [0, 1]^2 square (at side N a UV area a holds a N^2 texels)."""
    t = scene.uv[scene.faces_uv]
    uv_area = 0.5 * float(np.abs((t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1])
                                 - (t[:, 1, 1] - t[:, 0, 1]) * (t[:, 2, 0] - t[:, 0, 0])).sum())
    area = float(scene.areas().sum())
    if not (uv_area > 0 and area > 0):
        raise InputError(f"{scene.source}: the mesh's UVs cover no area: a texel density "
                         "cannot choose their resolution")
    return max(1, math.ceil(texel_density * math.sqrt(area / uv_area)))


def check_density_budget(scene, texel_density: float, texel_samples: int) -> None:
    """Refuse a texel density whose image cannot be made before charting: the surface alone
    at that density needs a side of at least D sqrt(surface area) texels."""
    side = max(1, math.ceil(texel_density * math.sqrt(float(scene.areas().sum()))))
    try:
        check_texture_budget(side, side, texel_samples)
    except InputError as exc:
        raise InputError(f"texel density {texel_density:g} needs an image of at least "
                         f"{side}x{side}: {exc}") from None


#: face pairs an overlap refusal names (the mask shows them all)
_PAIRS_SHOWN = 5


def _refusal(scene, layout, width, height, check, mask_path) -> InputError:
    """The error of ``--uv-overlap refuse``: counts, the first overlapping face pairs (0-based
    face indices of the input), and the mask written to ``mask_path`` if given."""
    overlap = find_overlap(scene.uv, scene.faces_uv, width, height, layout)
    pairs = ", ".join(f"{a}&{b}" for a, b in overlap.pairs[:_PAIRS_SHOWN])
    more = len(overlap.pairs) - _PAIRS_SHOWN
    where = ""
    if mask_path is not None:
        from aobake.outputs import image

        shared = overlap.shared
        rgb = np.zeros(shared.shape + (3,))
        rgb[shared == 1] = 0.5
        rgb[shared >= 2] = (1.0, 0.0, 0.0)
        image.write_rgb(mask_path, rgb, metadata={"overlap_texels": overlap.texels,
                                                  "convention": "red: texel centre covered "
                                                  "by 2+ faces; grey: by one"})
        where = f"; the overlap is drawn in {mask_path} (red)"
    return InputError(
        f"{scene.source}: the own UVs overlap (--uv-overlap refuse): {overlap.texels} of "
        f"{width}x{height} texels are covered by more than one face, {len(overlap.faces)} "
        f"faces overlap ({overlap.mirrored} of them mirrored in UV; {check.mirrored_faces} "
        f"mirrored faces in all); face pairs sharing texels (0-based): {pairs}"
        f"{f' and {more} more' if more > 0 else ''}{where}. Bake a new atlas (--uv-overlap "
        "atlas) or the mean of the shared surfaces (--uv-overlap average)")


def _other_sets(scene, source_vertex) -> dict:
    """Atlas fields for the input's other UV sets (``Atlas.uv_set``, ``Atlas.other_uv``)."""
    if not scene.uv_set:
        return {}
    return {"uv_set": scene.uv_set,
            "other_uv": {k: uv[source_vertex] for k, uv in scene.uv_sets.items()
                         if k != scene.uv_set}}


def make_atlas(scene, unwrap: str, width: int, height: int, padding: int, texel_samples: int,
               seed: int, threads: int, warnings: list, timings: dict, compiled: bool | None,
               phase=lambda name: None, texel_density: float | None = None,
               uv_overlap: str = "atlas", overlap_mask: str | None = None):
    """Choose the UVs to bake into (the mesh's own when valid, wrapped into [0, 1] where
    they stray out of it, else a fresh xatlas atlas) and rasterise them.

    Returns (atlas, bake_uv (t, 2), bake_faces_uv (f, 3), uv_check or None, samples);
    ``samples.face`` indexes ``scene.faces`` (with wrapped own UVs, a face may have
    samples at two tile positions; ``bake_uv`` are the mesh's own UVs, unwrapped).
    ``atlas.size`` is the image (width, height): ``width`` x ``height``, or with a
    ``texel_density`` (texels per scene unit) the size chosen for it.  ``compiled``: the
    rasteriser and a new atlas's packer in the compiled kernels (True), in numpy (False), or
    when built (None); ``atlas.packing_compiled`` records which packed.
    Fills ``timings`` with uv_check_s, unwrap_s and raster_s.
    uv_overlap : what overlapping own UVs get (``LightmapOptions.uv_overlap``): "atlas" (a
    new atlas, unless ``unwrap`` is "never"), "refuse" (InputError naming the overlap;
    ``overlap_mask``, a .png path, gets a picture of it first) or "average" (baked as
    they are when overlap is their only fault: shared texels average their surfaces).
    """
    if texel_density is not None:
        check_density_budget(scene, texel_density, texel_samples)
        if scene.faces_uv is not None and unwrap != "always":
            width = height = own_uv_side(scene, texel_density)
            check_texture_budget(width, height, texel_samples)

    def raster(uv, faces_uv):
        phase("rasterising")
        clock = time.perf_counter()
        samples = rasterize(uv, faces_uv, width, height, texel_samples, seed, threads=threads,
                            compiled=compiled)
        timings["raster_s"] = time.perf_counter() - clock
        return samples

    check = samples = layout = None
    timings.update(uv_check_s=0.0, unwrap_s=0.0)
    if scene.faces_uv is not None:
        clock = time.perf_counter()
        layout = wrap_uvs(scene.uv, scene.faces_uv)  # the input's own when all in [0, 1]
        wrap_s = time.perf_counter() - clock
        if unwrap == "never" or (unwrap == "auto" and not layout.oversized_faces):
            # Likely baked as they are: the bake's own rasterisation gives the overlap
            # count too (texel-centre coverage), so the check costs no extra pass.  A
            # prestarted xatlas child (the CLI's) is ended: most own UVs are baked as they
            # are (if they are rejected after all, the unwrap starts its own child).
            discard_prestarted()
            laid = raster(layout.uv, layout.faces)  # the layout's triangles
            samples = layout.to_faces(laid)
            clock = time.perf_counter()
            has_area = ~degenerate_faces(scene.vertices, scene.faces)
            check = check_uvs(scene.uv, scene.faces_uv, width, height, shared=samples.shared,
                              layout=layout, has_area=has_area)
        else:  # not baked as they are: a texel-centre (K = 1) pass for the report is enough
            clock = time.perf_counter()
            has_area = ~degenerate_faces(scene.vertices, scene.faces)
            check = check_uvs(scene.uv, scene.faces_uv, width, height, layout=layout,
                              has_area=has_area)
        timings["uv_check_s"] = wrap_s + time.perf_counter() - clock
    accept = False  # own UVs baked although they overlap (--uv-overlap average)
    if check is not None and unwrap != "always" and check.overlapping_texels:
        if uv_overlap == "refuse":
            raise _refusal(scene, layout, width, height, check, overlap_mask)
        if uv_overlap == "average" and check.bakeable:
            warnings.append(f"{scene.source}: baking the overlapping own UVs as asked "
                            f"(--uv-overlap average): {check.message}; each shared texel is "
                            "the mean of the surfaces that share it")
            accept = True
    if unwrap == "never":
        if scene.faces_uv is None:
            raise InputError(f"{scene.source}: mesh has no UVs and --no-unwrap was given")
        if not check.valid:
            warnings.append(f"{scene.source}: baking into the mesh's own UVs although {check.message}")
    use_own = scene.faces_uv is not None and unwrap != "always" and (
        check.valid or unwrap == "never" or accept)
    if use_own:
        discard_prestarted()
        if check.collapsed_faces:  # faces with area whose UVs have none: baked, said so
            laid, collapsed = bake_collapsed(laid, layout.uv, layout.faces, has_area
                                             if layout.face is None else has_area[layout.face])
            samples = layout.to_faces(laid)
            warnings.append(f"{scene.source}: {collapsed.message()}")
        keys, faces = split_corners(scene.faces, scene.faces_uv)
        atlas = Atlas(scene.vertices[keys[:, 0]], scene.vertex_normals[keys[:, 0]], faces,
                      scene.uv[keys[:, 1]], None, keys[:, 0], new=False, materials=scene.materials,
                      face_material=scene.face_material,
                      wrap="repeat" if layout.wrapped else "clamp", size=(width, height),
                      **_other_sets(scene, keys[:, 0]))
        return atlas, scene.uv, scene.faces_uv, check, samples
    if scene.faces_uv is not None and unwrap == "auto":
        warnings.append(f"{scene.source}: the mesh's UVs cannot be baked ({check.message}); "
                        "made a new atlas with xatlas")
    if samples is not None:  # rasterising the rejected own UVs was part of checking them
        timings["uv_check_s"] += timings.pop("raster_s")
    if width != height and texel_density is None:
        warnings.append(f"{scene.source}: xatlas packs square layouts: the new atlas uses the "
                        f"top-left {min(width, height)}x{min(width, height)} of the "
                        f"{width}x{height} image")
    phase("unwrapping")
    clock = time.perf_counter()
    try:
        unwrapped = xatlas_unwrap(scene.vertices, scene.faces, (width, height), padding,
                                  texel_density=texel_density, compiled=compiled)
    except InputError as exc:  # name the mesh: the unwrapper knows only its triangles
        raise InputError(f"{scene.source}: {exc}") from None
    timings["unwrap_s"] = time.perf_counter() - clock
    if texel_density is not None:  # the image the charts were packed for
        width, height = unwrapped.size
        check_texture_budget(width, height, texel_samples)
    if not np.array_equal(unwrapped.vmapping[unwrapped.faces], scene.faces):
        raise RuntimeError("xatlas changed the face order")  # the texel->face mapping relies on it
    if scene.faces_uv is not None:
        keys, faces = split_corners(unwrapped.faces, scene.faces_uv)
        base_uv = scene.uv[keys[:, 1]]
    else:
        keys, faces = split_corners(unwrapped.faces)
        base_uv = None
    source = unwrapped.vmapping[keys[:, 0]]
    atlas = Atlas(scene.vertices[source], scene.vertex_normals[source], faces,
                  unwrapped.uv[keys[:, 0]], base_uv, source, new=True,
                  materials=scene.materials if base_uv is not None else None,
                  face_material=scene.face_material if base_uv is not None else None,
                  charts=unwrapped.charts, size=(width, height),
                  packing_compiled=unwrapped.packing_compiled, charting=unwrapped.charting,
                  **_other_sets(scene, source))
    if atlas.uv_set:  # the new atlas takes the chosen set's place; the input's sets stay
        atlas.base_uv = None
    return atlas, unwrapped.uv, unwrapped.faces, check, raster(unwrapped.uv, unwrapped.faces)
