"""Write a baked lightmap: EXR (all channels), PNG/TIFF (one map), or GLB (mesh + occlusion texture),
plus the unwrapped mesh when the atlas is new.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from aobake.errors import OutputError
from aobake.outputs.atomic import atomic_path
from aobake.outputs.orm import OWN_TEXTURE

log = logging.getLogger(__name__)

def _map(result):
    """(value, name): the map an 8/16-bit image or a glTF occlusion texture carries."""
    for name in ("ao", "obscurance"):
        if name in result.channels:
            return result.channels[name], name
    raise OutputError("an image output needs ao or obscurance; add -q ao")


def write_obj(path, positions, faces, uv, normals=None, header: str = "") -> None:
    """Write an OBJ with one ``vt`` per vertex (positions (m, 3), faces (f, 3), uv (m, 2)), atomically.

    Numbers as ``%.9g`` (positions, UVs: float32-exact) and ``%.7g`` (normals).
    """
    _write_lines(path, obj_lines(positions, faces, uv, normals, header))


def _write_lines(path, parts: list[str]) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="\n") as f:
            f.writelines(parts or ["\n"])


def obj_lines(positions, faces, uv, normals=None, header: str = "") -> list[str]:
    """``write_obj``'s text, as a list of strings (no file touched)."""
    parts = [f"# {line}\n" for line in header.splitlines()]
    parts += _lines("v %.9g %.9g %.9g\n", np.asarray(positions, dtype=np.float64))
    parts += _lines("vt %.9g %.9g\n", np.asarray(uv, dtype=np.float64))
    corners = np.asarray(faces, dtype=np.int64) + 1
    if normals is not None:
        parts += _lines("vn %.7g %.7g %.7g\n", np.asarray(normals, dtype=np.float64))
        parts += _lines("f %d/%d/%d %d/%d/%d %d/%d/%d\n", np.repeat(corners, 3, axis=1))
    else:
        parts += _lines("f %d/%d %d/%d %d/%d\n", np.repeat(corners, 2, axis=1))
    return parts


#: OBJ lines formatted by one %-operation at a time (a line at a time costs 4x more)
_OBJ_BLOCK = 1 << 14


def _lines(line: str, rows: np.ndarray) -> list[str]:
    """``line`` (one row's format, ending in a newline) applied to each row of ``rows``
    (n, k), in blocks of ``_OBJ_BLOCK`` rows: a list of strings."""
    if not len(rows):
        return []
    rows = rows.reshape(len(rows), -1)
    return [(line * len(block)) % tuple(block.reshape(-1).tolist())
            for block in (rows[i:i + _OBJ_BLOCK] for i in range(0, len(rows), _OBJ_BLOCK))]


#: the EXR channels of an ORM-packed lightmap (``--orm``), beside the bake's own
ORM_CHANNELS = ("orm.R", "orm.G", "orm.B")


def orm_map(result, orm_from=None) -> tuple[np.ndarray, dict]:
    """(orm (H, W, 3) float64, its metadata entry) of a lightmap (``aobake.outputs.orm``)."""
    from aobake.outputs import orm

    value, name = _map(result)
    packed, source = orm.pack(result, value, orm_from)
    return packed, {"R": name, "G": "roughness", "B": "metalness", "G_B_from": source}


def write_texture(path, result, metadata: dict, *, half=False, bit_depth=8, r_only=False,
                  orm=False, orm_from=None) -> None:
    """Write ``result`` (a TexelResult) to ``path`` chosen by extension; ``orm``: packed as
    R occlusion, G roughness, B metalness (G/B from ``orm_from``, see ``outputs.orm``)."""
    from aobake.outputs import image

    suffix = Path(path).suffix.lower()
    packed = None
    if orm or orm_from is not None:
        packed, entry = orm_map(result, orm_from)
        metadata = dict(metadata, orm=entry)
    if suffix == ".exr":
        channels = result.channels
        if packed is not None:
            channels = dict(channels, **{c: packed[..., i] for i, c in enumerate(ORM_CHANNELS)})
        image.write_exr(path, channels, metadata, half=half)
    elif suffix in image.LDR_SUFFIXES and packed is not None:
        image.write_rgb(path, packed, bit_depth=bit_depth, metadata=dict(metadata, map="orm"))
    elif suffix in image.LDR_SUFFIXES:
        value, name = _map(result)
        image.write_ldr(path, value, result.channels["coverage"], bit_depth=bit_depth,
                        r_only=r_only, metadata=dict(metadata, map=name))
    elif suffix == ".glb":
        _write_glb(path, result, _map(result)[0], metadata, packed,
                   own_factors=packed is not None and metadata["orm"]["G_B_from"] == OWN_TEXTURE)
    else:
        raise OutputError(f"{path}: unsupported lightmap format {suffix!r}; "
                          f"use one of {', '.join(('.exr', *image.LDR_SUFFIXES, '.glb'))}")


def write_atlas_mesh(path, result, metadata: dict, orm=False, orm_from=None) -> None:
    """Write the atlas mesh (OBJ with the atlas UVs, or GLB with the occlusion texture)."""
    prepare_atlas_mesh(path, result, metadata, orm, orm_from)()


def prepare_atlas_mesh(path, result, metadata: dict, orm=False, orm_from=None):
    """``write_atlas_mesh`` in two steps: returns the function that writes the file.

    An OBJ's text is formatted on a thread from now on, so it overlaps whatever is written
    first (the EXR's compression releases the GIL: the bunny's 1024^2 map and 7.6 MB atlas
    0.41-0.46 s one after the other, 0.36-0.38 s so); the file itself is written by the
    returned function, on the caller's thread and in its output transaction.
    """
    atlas = result.atlas
    suffix = Path(path).suffix.lower()
    if suffix == ".obj":
        from concurrent.futures import ThreadPoolExecutor

        pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="aobake-obj")
        text = pool.submit(obj_lines, atlas.positions, atlas.faces, atlas.uv, atlas.normals,
                           "aobake lightmap atlas: vt are the lightmap UVs (OBJ convention)")
        pool.shutdown(wait=False)  # its one thread ends with the task
        return lambda: _write_lines(path, text.result())
    if suffix == ".glb":
        if orm or orm_from is not None:  # the same packed map as --out's
            packed, entry = orm_map(result, orm_from)
            own = entry["G_B_from"] == OWN_TEXTURE
            return lambda: _write_glb(path, result, _map(result)[0], dict(metadata, orm=entry),
                                      packed, own_factors=own)
        return lambda: _write_glb(path, result, _map(result)[0], metadata)
    raise OutputError(f"{path}: unsupported mesh format for --mesh-out; use .obj or .glb")


def _write_glb(path, result, value, metadata: dict, orm=None, own_factors=False) -> None:
    """The atlas mesh with the AO map as occlusionTexture, keeping the input's materials
    (one primitive per material, each with its base colour and the shared AO texture).
    own_factors : an ORM map whose G and B are the input's own texture's: the materials
    keep the input's roughness and metallic factors (``aobake.outputs.orm``), else 1.

    With the mesh's own UVs the base colour and the AO share them (TEXCOORD_0 and an
    identical TEXCOORD_1); with a new atlas the input UVs stay in TEXCOORD_0 and the
    atlas goes to TEXCOORD_1.
    """
    from aobake.outputs import glb, image

    atlas = result.atlas
    if atlas.instances is not None:  # a set: every mesh once, each instance its region
        return _write_set_glb(path, result, value, metadata, orm)
    base_uv = atlas.base_uv
    textured = any(m["base_color_png"] is not None for m in atlas.materials or [])
    if base_uv is None and textured and not atlas.uv_set:
        base_uv = atlas.uv  # own UVs: the base colour textures use the same coordinates
    uv_sets = None
    if atlas.uv_set:  # --uv-set N: the map on TEXCOORD_N, the input's other sets kept
        uv_sets = dict(atlas.other_uv)
        uv_sets[atlas.uv_set] = atlas.uv
        if sorted(uv_sets) != list(range(len(uv_sets))):
            raise OutputError(f"{path}: UV sets {sorted(uv_sets)} are not TEXCOORD_0.."
                              f"{len(uv_sets) - 1} (glTF numbers them without gaps)")
        uv_sets = [uv_sets[k] for k in range(len(uv_sets))]
        base_uv = None
    # glTF reads occlusion from R; the gutters are already dilated, so alpha
    # (coverage) is not needed by viewers and is left opaque.
    if orm is None:
        png = image.png_bytes(value, np.ones_like(value), bit_depth=8, r_only=True)
    else:  # the packed map: R occlusion, G roughness, B metalness
        png = image.rgb_png_bytes(orm, bit_depth=8)
    materials = atlas.materials
    if materials and not own_factors:  # the texture's values are the material's
        materials = [dict(m, roughness_factor=None, metallic_factor=None) for m in materials]
    glb.write_textured(path, atlas.positions, atlas.faces, atlas.normals, atlas.uv, png,
                       metadata, base_uv=base_uv, materials=materials,
                       face_material=atlas.face_material,
                       occlusion_wrap=atlas.wrap, uv_sets=uv_sets, occlusion_set=atlas.uv_set,
                       packed_orm=orm is not None)


def _write_set_glb(path, result, value, metadata: dict, orm=None) -> None:
    """A lightmap of a set of instances as a GLB whose instances share their geometry, each
    reading its region of the one atlas through ``KHR_texture_transform``
    (``glb.write_textured_instances``; ``aobake.targets.texels.instanced``)."""
    from aobake.outputs import glb, image

    if orm is None:
        png = image.png_bytes(value, np.ones_like(value), bit_depth=8, r_only=True)
    else:
        png = image.rgb_png_bytes(orm, bit_depth=8)
    meshes, instances = result.atlas.instances.gltf()
    glb.write_textured_instances(path, meshes, instances, png, metadata,
                                 materials=result.atlas.materials, packed_orm=orm is not None)
