"""ORM packing (``--orm``): the map engines load, R = occlusion, G = roughness, B = metalness.

glTF's ``metallicRoughnessTexture`` reads roughness from G and metalness from B, and its
``occlusionTexture`` reads R, so one RGB image serves both (the glTF spec's own example of a
packed map).  R is the baked map (AO, or obscurance without AO: the value an occlusion
texture carries).  G and B come from, in order:

1. ``orm_from``: an existing ORM or metallic-roughness texture laid out in the UVs the map
   was baked into; its G and B are copied texel for texel.  It must have the lightmap's size
   (no resampling: a resampled roughness map is a different map, so a mismatch is refused
   with the size to bake at).
2. The input's own ``metallicRoughnessTexture`` (glTF), when the map was baked into the UVs
   it is laid out in (the mesh's own set 0, not a new atlas), every material with faces uses
   the same one, and it has the lightmap's size.
3. Otherwise "empty": G = 1 (roughness 1) and B = 0 (metalness 0), the plain diffuse
   surface aobake's GLBs always had (``glb._white_pbr``).

A material's roughness and metallic *factors* multiply the G and B of its own texture
(glTF), so where G and B are that texture's (2.) the packed GLB's materials keep the
input's factors (each its own: two materials may share the texture with different ones)
and render as the input did; from ``orm_from`` (1.) or empty (3.) the factors are 1, so
the texture's G and B are the material's roughness and metalness.  (Folding a factor into
the image's values instead would need each texel's material.)
"""

from __future__ import annotations

import numpy as np

from aobake.errors import OutputError

#: G and B of an "empty" ORM map: roughness 1, metalness 0 (a plain diffuse surface)
EMPTY_ROUGHNESS = 1.0
EMPTY_METALNESS = 0.0
#: the ``source`` :func:`pack` names for G/B from the input's own texture (case 2)
OWN_TEXTURE = "the input's metallicRoughnessTexture"


def pack(result, value: np.ndarray, orm_from=None) -> tuple[np.ndarray, str]:
    """(orm (H, W, 3) float64 in [0, 1], where G/B came from) for a lightmap ``result``.

    value : (H, W) the baked map (R); orm_from : path of a texture or None (module
    docstring).  OutputError naming the texture on a size mismatch or an unreadable file.
    """
    value = np.asarray(value, dtype=np.float64)
    height, width = value.shape
    if orm_from is not None:
        gb, source = _read(orm_from, width, height), str(orm_from)
    else:
        gb, source = _own(result, width, height)
    orm = np.empty((height, width, 3))
    orm[..., 0] = value
    if gb is None:
        orm[..., 1], orm[..., 2] = EMPTY_ROUGHNESS, EMPTY_METALNESS
        source = source or (f"empty: roughness {EMPTY_ROUGHNESS:g}, metalness "
                            f"{EMPTY_METALNESS:g}")
    else:
        orm[..., 1:] = gb
    return orm, source


def check_source(path, resolution) -> None:
    """Refuse an ``orm_from`` texture whose size is not ``resolution`` (width, height) before
    a bake (the header alone is read); OutputError naming it."""
    from aobake.outputs.image import read_size
    from aobake.outputs.table import Unreadable

    try:  # the image library's own complaints (libpng's) stay off the terminal
        width, height, channels = read_size(path)
    except (Unreadable, OSError) as exc:
        raise OutputError(f"{path}: cannot read the ORM source ({exc})") from None
    size = (width, height)
    if channels < 3:
        raise OutputError(f"{path}: has {channels} channels; an ORM / metallic-roughness "
                          "texture needs G (roughness) and B (metalness)")
    if tuple(size) != tuple(resolution):
        raise OutputError(f"{path}: is {size[0]}x{size[1]}, the lightmap {resolution[0]}x"
                          f"{resolution[1]}; G and B are copied texel for texel, not "
                          f"resampled: bake with --resolution {size[0]}x{size[1]}")


def _read(path, width: int, height: int) -> np.ndarray:
    """(H, W, 2) G and B of a texture file, checked against the lightmap's size."""
    from aobake.outputs.image import read_pixels
    from aobake.outputs.table import Unreadable

    try:
        pixels, _, _ = read_pixels(path)
    except (Unreadable, OSError) as exc:
        raise OutputError(f"{path}: cannot read the ORM source ({exc})") from None
    return _channels(pixels, str(path), width, height)


def _channels(pixels: np.ndarray, what: str, width: int, height: int) -> np.ndarray:
    h, w, c = pixels.shape
    if c < 3:
        raise OutputError(f"{what}: has {c} channels; an ORM / metallic-roughness texture "
                          "needs G (roughness) and B (metalness)")
    if (w, h) != (width, height):
        raise OutputError(f"{what}: is {w}x{h}, the lightmap {width}x{height}; G and B are "
                          f"copied texel for texel, not resampled: bake with --resolution "
                          f"{w}x{h}")
    return np.clip(pixels[..., 1:3].astype(np.float64), 0.0, 1.0)


def _own(result, width: int, height: int) -> tuple[np.ndarray | None, str | None]:
    """The input's own metallicRoughnessTexture, where it lines up with the map (module
    docstring); (None, None) when the input has none."""
    atlas = result.atlas
    used = np.unique(atlas.face_material) if atlas.face_material is not None else []
    textures = {atlas.materials[i].get("metallic_roughness_png") for i in used} \
        if atlas.materials else set()
    textures.discard(None)
    if not textures:
        return None, None
    if atlas.new or atlas.uv_set:
        where = ("the map in one region per instance of the set's atlas"
                 if getattr(atlas, "instances", None) is not None else
                 "the map on a new atlas" if atlas.new else f"the map on UV set {atlas.uv_set}")
        raise OutputError("the input's metallicRoughnessTexture is laid out on its UV set 0, "
                          + where
                          + ": its G and B cannot be copied texel for texel; give --orm-from "
                            "a texture in the map's layout")
    if len(textures) > 1:
        raise OutputError(f"the input's materials have {len(textures)} different "
                          "metallicRoughnessTextures; one ORM map holds one: give --orm-from")
    import tempfile
    from pathlib import Path

    from aobake.outputs.image import read_pixels
    from aobake.outputs.table import Unreadable

    try:
        with tempfile.TemporaryDirectory(prefix="aobake-orm-") as tmp:
            path = Path(tmp, "metallic_roughness.png")
            path.write_bytes(textures.pop())
            pixels, _, _ = read_pixels(path)
    except (Unreadable, OSError) as exc:
        raise OutputError(f"the input's metallicRoughnessTexture: {exc}") from None
    return _channels(pixels, OWN_TEXTURE, width, height), OWN_TEXTURE
