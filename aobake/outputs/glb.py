"""Bake results as binary glTF 2.0 (``.glb``), written by hand, and their reader.

Two writers, and ``read`` (any GLB's triangle meshes as a ``Table``, what
``aobake.outputs.read`` picks a quantity from); the container itself is
``aobake.outputs.gltf``'s, for the writers and the reader alike:

- ``write``: a vertex bake.  One mesh, one triangle primitive with
  ``POSITION`` (float32, with the min/max the spec requires), ``NORMAL`` (unit
  float32) if normals were given, ``COLOR_0`` = (ao, ao, ao, 1) as linear
  float32 (obscurance when AO is absent, clipped to [0, 1], NaN -> 0), and the
  application-specific attributes ``_AO``, ``_AO_STDERR``, ``_OBSCURANCE``,
  ``_OBSCURANCE_STDERR`` (SCALAR), ``_BENT_NORMAL`` (VEC3), ``_BENT_NORMAL_STDERR``
  (SCALAR, radians) and ``_RAYS`` (SCALAR)
  for the fields present.  All are float32: glTF attributes must be float or
  normalised integers, so ``_RAYS`` is a float32 count (exact below 2**24).
  The material is white (``baseColorFactor`` 1, metallic 0, roughness 1) so
  the vertex colours show as they are.
  A bake of instances (``aobake.instances``: its metadata's
  ``parameters.instances.layout``) is written as instances instead: one POSITION,
  NORMAL and index accessor per unique mesh (in the mesh's own units), and per baked
  instance a node (its ``matrix``; ``extras.aobake_instance`` its place in the bake) with a
  mesh whose primitive shares those accessors and has its own ``COLOR_0`` and custom
  attributes.  ``read`` places them back (node matrix x stored positions) in the bake's
  order, so the file reads as the flattened bake does.
- ``write_textured``: a lightmap bake.  The AO atlas is an embedded PNG used as
  the material's ``occlusionTexture`` (glTF reads occlusion from the R channel,
  1 = unoccluded).
- ``write_textured_instances``: a lightmap of a set of instances (one region per
  instance): each mesh's geometry once, per instance a node and materials whose
  occlusionTexture reads its region through ``KHR_texture_transform`` (offset, scale).

Conventions:

- UVs are taken in the OBJ convention (v = 0 at the *bottom* of the image) and
  written as (u, 1 - v), since glTF's UV origin is the top-left corner.
- Bake metadata goes in ``asset.extras``; ``asset.generator`` is "aobake".
  (trimesh does not load ``asset.extras``; ``read`` returns it as the metadata.)
- Indices are uint32 (componentType 5125); every bufferView starts on a 4-byte
  boundary and both chunks are padded to 4 bytes, as the GLB container requires.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from aobake.outputs.atomic import atomic_path
from aobake.outputs.gltf import COMPONENT_DTYPES, accessor_array, parse_glb, write_glb
from aobake.outputs.npz import check_vertex_data
from aobake.outputs.strictjson import check_metadata, to_jsonable
from aobake.outputs.table import Table, Unreadable, float64
from aobake.quantities import FIELDS

log = logging.getLogger(__name__)

GENERATOR = "aobake"

#: bake field -> glTF application-specific vertex attribute (names must start with "_"),
#: from the registry (normals go to the standard NORMAL attribute)
CUSTOM_ATTRIBUTES = {f.name: f.gltf for f in FIELDS.values() if f.gltf}

# glTF enums
_MODE_TRIANGLES = 4
_FLOAT = 5126
_UNSIGNED_INT = 5125
_ARRAY_BUFFER = 34962
_ELEMENT_ARRAY_BUFFER = 34963
_LINEAR = 9729
_CLAMP_TO_EDGE = 33071
_REPEAT = 10497
#: Atlas.wrap -> glTF sampler wrapS / wrapT
_WRAPS = {"clamp": _CLAMP_TO_EDGE, "repeat": _REPEAT}

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def write(
    path: str | os.PathLike,
    positions: np.ndarray,
    faces: np.ndarray,
    fields: Mapping[str, np.ndarray],
    metadata: Mapping | None,
) -> None:
    """Write a vertex bake to ``path`` as a GLB file, atomically.

    Parameters
    ----------
    path : output file
    positions : (n, 3) float, stored as float32, n >= 1
    faces : (f, 3) int, stored as uint32, f >= 1
    fields : dict of per-vertex arrays (``aobake.outputs.npz.VERTEX_FIELDS``);
      see the module docstring for the attributes they become
    metadata : JSON-serialisable dict, stored in ``asset.extras``
    """
    positions, faces, fields = check_vertex_data(positions, faces, fields)
    _check_not_empty(positions, faces)
    gltf = _new_gltf(metadata)
    blob = bytearray()
    shared = _shared_meshes(positions, faces, fields, metadata)
    if shared is not None:
        _write_instances(path, gltf, blob, fields, shared)
        return

    attributes = _add_geometry(gltf, blob, positions, fields.get("normals"))
    attributes.update(_value_attributes(gltf, blob, fields, slice(None)))

    material = {"name": GENERATOR, "pbrMetallicRoughness": _white_pbr()}
    _add_mesh(gltf, blob, attributes, [(faces, material)])
    _write_glb(path, gltf, blob)
    log.debug("wrote %s: %d vertices, %d faces, %s", path, len(positions), len(faces), list(fields))


def _value_attributes(gltf: dict, blob: bytearray, fields: Mapping, rows) -> dict:
    """COLOR_0 (linear grey of ao, else obscurance) and the custom attributes of
    ``fields``' ``rows``: attribute name -> accessor."""
    attributes = {}
    shade = fields.get("ao", fields.get("obscurance"))
    if shade is not None:
        # linear grey; clipped because COLOR_0 is a [0, 1] multiplier
        grey = np.nan_to_num(np.clip(shade[rows].astype(np.float64), 0.0, 1.0), nan=0.0)
        rgba = np.column_stack([grey, grey, grey, np.ones_like(grey)])
        attributes["COLOR_0"] = _add_accessor(gltf, blob, rgba, _ARRAY_BUFFER)
    for name, attribute in CUSTOM_ATTRIBUTES.items():
        if name in fields:
            attributes[attribute] = _add_accessor(gltf, blob, fields[name][rows],
                                                  _ARRAY_BUFFER)
    return attributes


def _shared_meshes(positions, faces, fields, metadata):
    """A bake of instances as the shared geometry the instanced GLB stores: (layout
    entries, {mesh name: (mesh-unit positions (v, 3), faces (f, 3), normals (v, 3) | None)}),
    or None to write the arrays flat (not a bake of instances, or one whose instances of a
    mesh do not all have its faces: ``--fix-normals fix`` may have flipped some).

    A mesh's geometry is its first baked instance's, mapped back by the inverse of its
    transform (float64; stored as float32 like any position), its faces in the mesh's own
    winding (a mirroring transform's placed faces are reversed: ``Scene.dump``), its
    normals by the transform's transpose (normals map by the inverse transpose)."""
    from aobake.outputs.npz import instance_arrays

    arrays = instance_arrays(metadata, len(positions), len(faces))
    if not arrays:
        return None
    normals = fields.get("normals")
    meshes, entries = {}, []
    for k, name in enumerate(arrays["instance_meshes"]):
        (v0, v1), (f0, f1) = arrays["instance_vertices"][k], arrays["instance_faces"][k]
        transform = arrays["instance_transforms"][k]
        linear = transform[:3, :3]
        own = faces[f0:f1] - v0
        if np.linalg.det(linear) < 0:
            own = own[:, ::-1]
        name = str(name)
        if name not in meshes:
            try:
                inverse = np.linalg.inv(transform)
            except np.linalg.LinAlgError:
                return None
            local = (positions[v0:v1] - transform[:3, 3]) @ inverse[:3, :3].T
            mesh_normals = None if normals is None else normals[v0:v1] @ linear
            meshes[name] = (local, np.ascontiguousarray(own), mesh_normals)
        elif meshes[name][0].shape != (v1 - v0, 3) or not np.array_equal(meshes[name][1], own):
            log.warning("instance %s of mesh %s does not have the mesh's faces: the .glb "
                        "holds the bake flattened", arrays["instance_names"][k], name)
            return None
        entries.append({"name": str(arrays["instance_names"][k]), "mesh": name,
                        "rows": slice(int(v0), int(v1)), "transform": transform})
    return entries, meshes


def _write_instances(path, gltf: dict, blob: bytearray, fields: Mapping, shared) -> None:
    """The instanced GLB (see the module docstring): shared geometry per mesh, one node and
    mesh per baked instance with its own value accessors."""
    entries, meshes = shared
    geometry = {}
    for name, (local, own, normals) in meshes.items():
        attributes = _add_geometry(gltf, blob, local, normals)
        indices = _add_accessor(gltf, blob, own.reshape(-1), _ELEMENT_ARRAY_BUFFER,
                                _UNSIGNED_INT)
        geometry[name] = (attributes, indices)
    gltf["materials"] = [{"name": GENERATOR, "pbrMetallicRoughness": _white_pbr()}]
    gltf["meshes"], gltf["nodes"] = [], []
    for k, entry in enumerate(entries):
        attributes, indices = geometry[entry["mesh"]]
        own = dict(attributes)
        own.update(_value_attributes(gltf, blob, fields, entry["rows"]))
        gltf["meshes"].append({"name": entry["mesh"], "primitives": [
            {"attributes": own, "indices": indices, "material": 0, "mode": _MODE_TRIANGLES}]})
        gltf["nodes"].append({"name": entry["name"], "mesh": len(gltf["meshes"]) - 1,
                              # glTF matrices are column-major
                              "matrix": [float(x) for x in entry["transform"].T.reshape(-1)],
                              "extras": {"aobake_instance": k}})
    gltf["scenes"] = [{"nodes": list(range(len(entries)))}]
    gltf["scene"] = 0
    _write_glb(path, gltf, blob)
    log.debug("wrote %s: %d instances of %d meshes, %s", path, len(entries), len(meshes),
              list(fields))


def write_textured(
    path: str | os.PathLike,
    positions: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray | None,
    atlas_uv: np.ndarray,
    occlusion_png: bytes,
    metadata: Mapping | None,
    base_uv: np.ndarray | None = None,
    base_color_png: bytes | None = None,
    base_color_factor: Sequence[float] | None = None,
    materials: Sequence[Mapping] | None = None,
    face_material: np.ndarray | None = None,
    occlusion_wrap: str = "clamp",
    uv_sets: Sequence[np.ndarray] | None = None,
    occlusion_set: int = 0,
    packed_orm: bool = False,
) -> None:
    """Write a mesh whose materials carry the baked AO atlas as their occlusion texture.

    Parameters
    ----------
    path : output file
    positions : (n, 3) float, stored as float32
    faces : (f, 3) int, stored as uint32
    normals : (n, 3) float or None; stored normalised
    atlas_uv : (n, 2) float, AO atlas coordinates, OBJ convention (v = 0 at the
      bottom); written as (u, 1 - v)
    occlusion_png : bytes of a PNG whose R channel is AO (linear, 1 = unoccluded)
    metadata : JSON-serialisable dict, stored in ``asset.extras``
    base_uv : (n, 2) float or None, the mesh's own UVs (OBJ convention).  When
      given it is TEXCOORD_0 and the atlas is TEXCOORD_1 (occlusionTexture.texCoord
      = 1); otherwise the atlas is TEXCOORD_0 (texCoord = 0).
    base_color_png : bytes of a PNG or None; the baseColorTexture, on TEXCOORD_0,
      so it needs ``base_uv``
    base_color_factor : 4 floats in [0, 1] or None (white)
    materials : several materials instead of ``base_color_png``/``base_color_factor``:
      a list of {"name", "base_color_png", "base_color_factor"} (the latter two as above),
      optionally with "roughness_factor" and "metallic_factor" (floats in [0, 1] or None:
      1), written with ``packed_orm``
    face_material : (f,) int index into ``materials`` of each face; the mesh gets
      one primitive per material that has faces (the vertex attributes are shared)
    occlusion_wrap : "clamp" (CLAMP_TO_EDGE) or "repeat" (REPEAT: the mesh's own UVs
      reach outside [0, 1] and the map was baked wrapped)
    uv_sets : instead of ``atlas_uv`` / ``base_uv``: every UV set, (n, 2) float each (OBJ
      convention), written as TEXCOORD_0.. in order; the occlusion texture reads set
      ``occlusion_set`` (``atlas_uv`` must equal it), a base colour texture set 0
    packed_orm : the occlusion PNG is an ORM map (R occlusion, G roughness, B metalness):
      it is also the ``metallicRoughnessTexture``, as glTF intends for packed maps, with
      each material's roughness and metallic factors (the input's: they multiply G and B
      as they multiplied the input's own texture; 1 where it had none)

    The occlusion texture samples with linear filtering and no mipmaps (mips
    would average texels of unrelated charts) and clamps to the edge unless
    ``occlusion_wrap`` says repeat; the base colour texture repeats, as the mesh's
    own UVs may tile.
    """
    if occlusion_wrap not in _WRAPS:
        raise ValueError(f"occlusion_wrap must be one of {sorted(_WRAPS)}, got {occlusion_wrap!r}")
    fields = {} if normals is None else {"normals": normals}
    positions, faces, fields = check_vertex_data(positions, faces, fields)
    _check_not_empty(positions, faces)
    n = len(positions)
    atlas_uv = _check_uv("atlas_uv", atlas_uv, n)
    occlusion_png = _check_png("occlusion_png", occlusion_png)
    if base_uv is not None:
        base_uv = _check_uv("base_uv", base_uv, n)
    if uv_sets is not None:
        if base_uv is not None:
            raise ValueError("give uv_sets or base_uv, not both")
        uv_sets = [_check_uv(f"uv_sets[{i}]", uv, n) for i, uv in enumerate(uv_sets)]
        if not 0 <= occlusion_set < len(uv_sets) or \
                not np.array_equal(uv_sets[occlusion_set], atlas_uv):
            raise ValueError(f"occlusion_set {occlusion_set} must index the set equal to "
                             "atlas_uv")
    elif occlusion_set:
        raise ValueError("occlusion_set needs uv_sets")
    if materials is None:
        if face_material is not None:
            raise ValueError("face_material needs materials")
        materials = [{"name": GENERATOR, "base_color_png": base_color_png,
                      "base_color_factor": base_color_factor}]
        face_material = np.zeros(len(faces), dtype=np.int64)
    else:
        if base_color_png is not None or base_color_factor is not None:
            raise ValueError("give either materials or base_color_png/base_color_factor")
        if not len(materials):
            raise ValueError("materials must not be empty")
        face_material = np.asarray(face_material if face_material is not None
                                   else np.zeros(len(faces)), dtype=np.int64)
        if face_material.shape != (len(faces),) or (len(materials) and (
                face_material.min() < 0 or face_material.max() >= len(materials))):
            raise ValueError(f"face_material must be ({len(faces)},) indices into {len(materials)} materials")
    checked = []
    for material in materials:
        png, factor = material.get("base_color_png"), material.get("base_color_factor")
        if png is not None:
            if base_uv is None and uv_sets is None:
                raise ValueError("base_color_png needs base_uv (the UVs it is mapped with)")
            png = _check_png("base_color_png", png)
        rgba = [1.0, 1.0, 1.0, 1.0]
        if factor is not None:
            rgba = [float(c) for c in np.asarray(factor, dtype=np.float64).reshape(-1)]
            if len(rgba) != 4 or not all(0.0 <= c <= 1.0 for c in rgba):
                raise ValueError(f"base_color_factor must be 4 floats in [0, 1], got {factor}")
        pbr_factors = {}
        for key, field in (("roughness_factor", "roughnessFactor"),
                           ("metallic_factor", "metallicFactor")):
            value = material.get(key)
            try:
                value = 1.0 if value is None else float(value)
            except (TypeError, ValueError):
                value = math.nan
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{key} must be a float in [0, 1], got {material.get(key)!r}")
            pbr_factors[field] = value
        checked.append((str(material.get("name") or GENERATOR), png, rgba, pbr_factors))

    gltf = _new_gltf(metadata)
    blob = bytearray()
    attributes = _add_geometry(gltf, blob, positions, fields.get("normals"))
    if uv_sets is None:
        uv_sets = [atlas_uv] if base_uv is None else [base_uv, atlas_uv]
        occlusion_set = len(uv_sets) - 1
    for i, uv in enumerate(uv_sets):
        attributes[f"TEXCOORD_{i}"] = _add_accessor(gltf, blob, _flip_v(uv), _ARRAY_BUFFER)
    occlusion = _add_texture(gltf, blob, occlusion_png, _WRAPS[occlusion_wrap],
                             "orm" if packed_orm else "occlusion")
    parts = []
    for index in np.unique(face_material):  # materials without faces are not written
        name, png, rgba, pbr_factors = checked[index]
        pbr = _white_pbr()
        pbr["baseColorFactor"] = rgba
        if packed_orm:  # one image, as glTF packs it: G roughness, B metalness
            pbr.update(**pbr_factors,
                       metallicRoughnessTexture={"index": occlusion,
                                                 "texCoord": occlusion_set})
        material = {
            "name": name,
            "occlusionTexture": {"index": occlusion, "texCoord": occlusion_set},
            "pbrMetallicRoughness": pbr,
        }
        if png is not None:
            pbr["baseColorTexture"] = {"index": _add_texture(gltf, blob, png, _REPEAT, "base_color"),
                                       "texCoord": 0}
        parts.append((faces[face_material == index], material))
    _add_mesh(gltf, blob, attributes, parts)
    _write_glb(path, gltf, blob)
    log.debug("wrote %s: %d vertices, %d faces, textured", path, n, len(faces))


#: the extension a lightmap of a set of instances reads its regions through
TEXTURE_TRANSFORM = "KHR_texture_transform"


def write_textured_instances(
    path: str | os.PathLike,
    meshes: Sequence[Mapping],
    instances: Sequence[Mapping],
    occlusion_png: bytes,
    metadata: Mapping | None,
    materials: Sequence[Mapping] | None = None,
    packed_orm: bool = False,
) -> None:
    """Write a set of instances lit by one atlas: every mesh's geometry once, every instance
    a node whose materials read its region of the atlas through ``KHR_texture_transform``.

    meshes : per unique mesh {"name", "positions" (v, 3) mesh units, "normals" (v, 3) | None,
      "uv" (L, 2) its lightmap layout (OBJ convention), "faces" (f, 3) into it, "vertex" (L,)
      the mesh vertex of each layout vertex, "own_uv" (v, 2) | None its own UVs (what a base
      colour texture reads; the layout itself when it is them), "face_material" (f,) |
      None};
    instances : per instance {"name", "mesh" (index into ``meshes``), "matrix" (4, 4) mesh ->
      scene units, "transform" {"offset", "scale"} (glTF UVs) into the atlas, "extras"};
    occlusion_png : the atlas (R = AO; with ``packed_orm`` an ORM map, also the
      metallicRoughnessTexture, as ``write_textured``'s); materials : the input's (as
      ``write_textured``'s), or None: one white material.

    One POSITION, NORMAL, TEXCOORD and index accessor per mesh (per material) is shared by
    all its instances; each instance has its own glTF mesh (the same accessors) and its own
    materials, whose occlusionTexture (and packed metallicRoughnessTexture) carry the
    instance's offset and scale.  The layout is TEXCOORD_0, or TEXCOORD_1 beside the mesh's
    own UVs (TEXCOORD_0, for base colours) when it is a new atlas.
    """
    occlusion_png = _check_png("occlusion_png", occlusion_png)
    if not meshes or not instances:
        raise ValueError("a set needs at least one mesh and one instance")
    gltf = _new_gltf(metadata)
    gltf["extensionsUsed"] = [TEXTURE_TRANSFORM]
    blob = bytearray()
    occlusion = _add_texture(gltf, blob, occlusion_png, _CLAMP_TO_EDGE,
                             "orm" if packed_orm else "occlusion")
    if materials is None:
        materials = [{"name": GENERATOR}]
    base_textures = {}  # input material -> its base colour texture, embedded once
    shared = []
    for mesh in meshes:
        vertex = np.asarray(mesh["vertex"], dtype=np.int64)
        positions, faces, fields = check_vertex_data(
            np.asarray(mesh["positions"])[vertex], mesh["faces"],
            {} if mesh.get("normals") is None else
            {"normals": np.asarray(mesh["normals"])[vertex]})
        _check_not_empty(positions, faces)
        layout = _check_uv("uv", mesh["uv"], len(positions))
        attributes = _add_geometry(gltf, blob, positions, fields.get("normals"))
        own = mesh.get("own_uv")
        if own is not None:
            own = np.asarray(own, np.float64)[vertex]
        # the mesh's own UVs as its layout: one set serves the base colour and the atlas
        sets = [layout] if own is None or np.array_equal(own, layout) else [own, layout]
        for i, uv in enumerate(sets):
            attributes[f"TEXCOORD_{i}"] = _add_accessor(gltf, blob, _flip_v(uv), _ARRAY_BUFFER)
        by_material = np.zeros(len(faces), np.int64) if mesh.get("face_material") is None \
            else np.asarray(mesh["face_material"], dtype=np.int64)
        if by_material.shape != (len(faces),) or by_material.min() < 0 \
                or by_material.max() >= len(materials):
            raise ValueError(f"mesh {mesh['name']!r}: face_material must be ({len(faces)},) "
                             f"indices into {len(materials)} materials")
        parts = [(int(j), _add_accessor(gltf, blob, faces[by_material == j].reshape(-1),
                                        _ELEMENT_ARRAY_BUFFER, _UNSIGNED_INT))
                 for j in np.unique(by_material)]
        shared.append((attributes, parts, len(sets) - 1, own is not None))
    gltf["materials"], gltf["meshes"], gltf["nodes"] = [], [], []
    for k, instance in enumerate(instances):
        attributes, parts, tex_coord, has_own = shared[instance["mesh"]]
        transform = {"offset": [float(v) for v in instance["transform"]["offset"]],
                     "scale": [float(v) for v in instance["transform"]["scale"]]}
        primitives = []
        for j, indices in parts:
            given = materials[j]
            reads = {"index": occlusion, "texCoord": tex_coord,
                     "extensions": {TEXTURE_TRANSFORM: dict(transform)}}
            pbr = _white_pbr()
            factor = given.get("base_color_factor")
            if factor is not None:
                pbr["baseColorFactor"] = [float(c) for c in factor]
            png = given.get("base_color_png")
            if png is not None and has_own:
                if j not in base_textures:
                    base_textures[j] = _add_texture(gltf, blob, _check_png("base_color_png",
                                                                           png),
                                                    _REPEAT, "base_color")
                pbr["baseColorTexture"] = {"index": base_textures[j], "texCoord": 0}
            if packed_orm:
                pbr["metallicFactor"] = pbr["roughnessFactor"] = 1.0
                pbr["metallicRoughnessTexture"] = {
                    "index": occlusion, "texCoord": tex_coord,
                    "extensions": {TEXTURE_TRANSFORM: dict(transform)}}
            gltf["materials"].append({"name": f"{given.get('name') or GENERATOR}"
                                              f"@{instance['name']}",
                                      "occlusionTexture": reads, "pbrMetallicRoughness": pbr})
            primitives.append({"attributes": attributes, "indices": indices,
                               "material": len(gltf["materials"]) - 1,
                               "mode": _MODE_TRIANGLES})
        gltf["meshes"].append({"name": str(meshes[instance["mesh"]]["name"]),
                               "primitives": primitives})
        matrix = np.asarray(instance["matrix"], dtype=np.float64).reshape(4, 4)
        node = {"name": str(instance["name"]), "mesh": len(gltf["meshes"]) - 1,
                "extras": dict(instance.get("extras") or {}, aobake_instance=k)}
        if not np.array_equal(matrix, np.eye(4)):  # glTF matrices are column-major
            node["matrix"] = [float(x) for x in matrix.T.reshape(-1)]
        gltf["nodes"].append(node)
    gltf["scenes"] = [{"nodes": list(range(len(instances)))}]
    gltf["scene"] = 0
    _write_glb(path, gltf, blob)
    log.debug("wrote %s: %d instances of %d meshes lit by one atlas", path, len(instances),
              len(meshes))


def _new_gltf(metadata: Mapping | None) -> dict:
    asset = {"version": "2.0", "generator": GENERATOR}
    extras = to_jsonable(check_metadata(metadata))
    if extras:
        asset["extras"] = extras
    return {"asset": asset}


def _white_pbr() -> dict:
    # metallic 0 / roughness 1: a plain diffuse surface, so the stored colours
    # show as they are rather than as a black mirror (metallicFactor defaults to 1)
    return {
        "baseColorFactor": [1.0, 1.0, 1.0, 1.0],
        "metallicFactor": 0.0,
        "roughnessFactor": 1.0,
    }


def _check_not_empty(positions: np.ndarray, faces: np.ndarray) -> None:
    # glTF accessors must have count >= 1
    if len(positions) == 0 or len(faces) == 0:
        raise ValueError(
            "a GLB mesh needs at least one vertex and one face, "
            f"got {len(positions)} and {len(faces)}"
        )


def _check_uv(name: str, uv, n: int) -> np.ndarray:
    uv = np.asarray(uv)
    if uv.shape != (n, 2):
        raise ValueError(f"{name} must be (n, 2) = {(n, 2)}, got {uv.shape}")
    if uv.dtype.kind not in "iuf" or not np.isfinite(uv).all():
        raise ValueError(f"{name} must be finite floats")
    return uv.astype(np.float64, copy=False)


def _check_png(name: str, data) -> bytes:
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ValueError(f"{name} must be PNG file bytes, got {type(data).__name__}")
    data = bytes(data)
    if not data.startswith(_PNG_SIGNATURE):
        raise ValueError(f"{name} is not a PNG file (wrong signature)")
    return data


def _flip_v(uv: np.ndarray) -> np.ndarray:
    # OBJ (v = 0 at the bottom) -> glTF (v = 0 at the top)
    return np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])


def _unit(normals: np.ndarray) -> np.ndarray:
    """(n, 3) float -> (n, 3) float64 unit vectors; zero vectors become +Z (logged)."""
    normals = normals.astype(np.float64)
    length = np.linalg.norm(normals, axis=1)
    # glTF requires unit NORMALs; a zero normal (e.g. an unreferenced vertex)
    # has no direction to keep, so give it one rather than fail at the end of a bake
    zero = ~(length > 1e-30)
    if zero.any():
        log.warning("%d zero-length normals written as +Z", int(zero.sum()))
        normals[zero] = (0.0, 0.0, 1.0)
        length[zero] = 1.0
    return normals / length[:, None]


def _add_geometry(
    gltf: dict, blob: bytearray, positions: np.ndarray, normals: np.ndarray | None
) -> dict[str, int]:
    """POSITION (with the min/max the spec requires) and, if given, unit NORMAL accessors."""
    attributes = {"POSITION": _add_accessor(gltf, blob, positions, _ARRAY_BUFFER, bounds=True)}
    if normals is not None:
        attributes["NORMAL"] = _add_accessor(gltf, blob, _unit(normals), _ARRAY_BUFFER)
    return attributes


def _add_view(gltf: dict, blob: bytearray, data: bytes, target: int | None) -> int:
    """Append ``data`` to the buffer on a 4-byte boundary; return the bufferView index."""
    # float32/uint32 components must be aligned to their size; 4 covers all used here
    blob.extend(b"\0" * (-len(blob) % 4))
    view = {"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)}
    if target is not None:
        view["target"] = target
    blob.extend(data)
    views = gltf.setdefault("bufferViews", [])
    views.append(view)
    return len(views) - 1


def _add_accessor(
    gltf: dict,
    blob: bytearray,
    values: np.ndarray,
    target: int,
    component: int = _FLOAT,
    bounds: bool = False,
) -> int:
    """Append (count,) or (count, k) values as a tightly packed accessor; return its index.

    ``component`` is _FLOAT (values cast to float32) or _UNSIGNED_INT (uint32).
    ``bounds`` adds min/max, computed on the stored values so they match
    exactly what a validator reads back.
    """
    stored = np.ascontiguousarray(values, dtype=COMPONENT_DTYPES[component])
    width = 1 if stored.ndim == 1 else stored.shape[1]
    accessor = {
        "bufferView": _add_view(gltf, blob, stored.tobytes(), target),
        "componentType": component,
        "count": len(stored),
        "type": "SCALAR" if width == 1 else f"VEC{width}",
    }
    if bounds:
        table = stored.reshape(len(stored), width)
        accessor["min"] = [float(v) for v in table.min(axis=0)]
        accessor["max"] = [float(v) for v in table.max(axis=0)]
    accessors = gltf.setdefault("accessors", [])
    accessors.append(accessor)
    return len(accessors) - 1


def _add_texture(gltf: dict, blob: bytearray, png: bytes, wrap: int, name: str) -> int:
    """Embed a PNG with its own sampler; return the texture index."""
    images = gltf.setdefault("images", [])
    view = _add_view(gltf, blob, png, None)
    images.append({"name": name, "bufferView": view, "mimeType": "image/png"})
    samplers = gltf.setdefault("samplers", [])
    samplers.append({"magFilter": _LINEAR, "minFilter": _LINEAR, "wrapS": wrap, "wrapT": wrap})
    textures = gltf.setdefault("textures", [])
    textures.append({"name": name, "sampler": len(samplers) - 1, "source": len(images) - 1})
    return len(textures) - 1


def _add_mesh(gltf: dict, blob: bytearray, attributes: dict, parts) -> None:
    """Add one mesh with a primitive per (faces (k, 3), material) part, sharing
    ``attributes``; its materials, node and scene."""
    gltf["materials"], primitives = [], []
    for faces, material in parts:
        indices = _add_accessor(gltf, blob, faces.reshape(-1), _ELEMENT_ARRAY_BUFFER, _UNSIGNED_INT)
        gltf["materials"].append(material)
        primitives.append({
            "attributes": attributes,
            "indices": indices,
            "material": len(gltf["materials"]) - 1,
            "mode": _MODE_TRIANGLES,
        })
    gltf["meshes"] = [{"name": GENERATOR, "primitives": primitives}]
    gltf["nodes"] = [{"name": GENERATOR, "mesh": 0}]
    gltf["scenes"] = [{"nodes": [0]}]
    gltf["scene"] = 0


def _write_glb(path: str | os.PathLike, gltf: dict, blob: bytearray) -> None:
    """Pack the JSON and BIN chunks into a GLB container and write it atomically."""
    blob.extend(b"\0" * (-len(blob) % 4))  # BIN chunk padding is zeros
    gltf["buffers"] = [{"byteLength": len(blob)}]
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:
            write_glb(handle, gltf, blob)


# ---------------------------------------------------------------------------------------------
# reading


def read(path) -> Table:
    """Every vertex attribute of a GLB's triangle primitives as a ``Table`` (columns by
    attribute name, ``naming`` 'gltf'), aobake's or another tool's.

    Primitives sharing a POSITION accessor share their vertices, as in aobake's files;
    positions are as stored (node transforms are not applied: a warning says so), NORMAL
    the normals, ``asset.extras`` the metadata when aobake wrote the file.  Normalised
    integer attributes are scaled to [0, 1] ([-1, 1] signed).  Raises ``Unreadable``.
    """
    data = Path(path).read_bytes()
    gltf, binary = parse_glb(data)
    # Every accessor read takes from one budget, a few times the file's size: accessors
    # sharing bytes (or all zeros, without a bufferView) cannot multiply what is allocated.
    budget = [4 * len(data) + (1 << 20)]

    def accessor(index):
        values = _scaled(gltf, binary, index, budget[0])
        budget[0] -= values.nbytes
        return values

    placed = _read_instances(gltf, accessor)
    if placed is not None:  # aobake's bake of instances: placed back, in the bake's order
        return placed

    groups: dict = {}  # POSITION accessor -> (attributes, [index arrays])
    for mesh in _list(gltf.get("meshes", [])):
        for prim in _list(mesh.get("primitives", []) if isinstance(mesh, dict) else None):
            attributes = prim.get("attributes", {}) if isinstance(prim, dict) else None
            if not isinstance(attributes, dict):
                raise Unreadable("a primitive without an attributes object")
            if prim.get("mode", 4) != 4 or "POSITION" not in attributes:
                continue
            if not all(isinstance(a, int) for a in attributes.values()):
                raise Unreadable("a primitive's attributes are not accessor numbers")
            group = groups.setdefault(attributes["POSITION"], (attributes, []))
            if "indices" in prim:
                indices = accessor(prim["indices"])
                if indices.dtype.kind != "u":
                    raise Unreadable(f"indices of {indices.dtype} (glTF indices are unsigned "
                                     "integers)")
                group[1].append(indices.astype(np.int64))
    if not groups:
        raise Unreadable("no triangle mesh with POSITION")
    names = set.intersection(*(set(a) for a, _ in groups.values()))
    parts: dict = {name: [] for name in names}
    faces, base = [], 0
    for attributes, indices in groups.values():
        for name in names:
            parts[name].append(accessor(attributes[name]))
        count = len(parts["POSITION"][-1])
        flat = np.concatenate(indices) if indices else np.arange(count)
        faces.append(flat.reshape(-1, 3) + base)
        base += count
    columns = {name: np.concatenate(arrays) for name, arrays in parts.items()}
    asset = gltf.get("asset", {})
    asset = asset if isinstance(asset, dict) else {}
    metadata = asset.get("extras", {}) if asset.get("generator") == GENERATOR else {}
    warnings = []
    if any(isinstance(node, dict) and k in node for node in _list(gltf.get("nodes", []))
           for k in ("matrix", "translation", "rotation", "scale")):
        warnings.append("node transforms are not applied: positions are matched as stored")
    positions = columns.pop("POSITION").astype(np.float64)
    normals = columns.get("NORMAL")
    return Table(columns, "gltf", positions, float64(normals), np.concatenate(faces),
                 metadata if isinstance(metadata, dict) else {}, warnings)


def node_matrix(node: dict) -> np.ndarray:
    """(4, 4) float64 local transform of a glTF node: its ``matrix`` (column-major), else
    translation x rotation (a unit quaternion x, y, z, w) x scale, each absent part the
    identity (glTF 2.0's node transform: a node placed where its parent is has none).
    Unreadable for a malformed one."""
    matrix = node.get("matrix")
    if matrix is not None:
        if not isinstance(matrix, list) or len(matrix) != 16:
            raise Unreadable(f"node {node.get('name')!r}: its matrix is not 16 numbers")
        return np.asarray(matrix, dtype=np.float64).reshape(4, 4).T
    parts = {}
    for key, size, default in (("translation", 3, [0.0, 0.0, 0.0]),
                               ("rotation", 4, [0.0, 0.0, 0.0, 1.0]),
                               ("scale", 3, [1.0, 1.0, 1.0])):
        value = node.get(key, default)
        if not isinstance(value, list) or len(value) != size:
            raise Unreadable(f"node {node.get('name')!r}: its {key} is not {size} numbers")
        parts[key] = np.asarray(value, dtype=np.float64)
    x, y, z, w = parts["rotation"]
    rotation = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                         [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                         [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    out = np.eye(4)
    out[:3, :3] = rotation * parts["scale"][None, :]
    out[:3, 3] = parts["translation"]
    return out


def _read_instances(gltf: dict, accessor) -> Table | None:
    """An instanced GLB of aobake's (nodes with ``extras.aobake_instance``) as the flattened
    bake's table: each instance's stored positions placed by its node's matrix (float64),
    its normals by the matrix's inverse transpose, its attributes, faces reversed where the
    matrix mirrors (as the bake's), instances in ``aobake_instance`` order; None for any
    other GLB."""
    nodes = _list(gltf.get("nodes", []))
    placed = [node for node in nodes if isinstance(node, dict)
              and isinstance(node.get("extras"), dict) and "aobake_instance" in node["extras"]]
    asset = gltf.get("asset", {}) if isinstance(gltf.get("asset"), dict) else {}
    if not placed or asset.get("generator") != GENERATOR:
        return None
    placed.sort(key=lambda node: node["extras"]["aobake_instance"])
    meshes = _list(gltf.get("meshes", []))
    parts: dict = {}
    positions, normals, faces, base = [], [], [], 0
    for node in placed:
        if not isinstance(node.get("mesh"), int) or not 0 <= node["mesh"] < len(meshes):
            raise Unreadable(f"instance node {node.get('name')!r} without a mesh")
        transform = node_matrix(node)
        primitive = _list(meshes[node["mesh"]].get("primitives", []))[0]
        attributes = primitive["attributes"]
        stored = accessor(attributes["POSITION"]).astype(np.float64)
        positions.append(stored @ transform[:3, :3].T + transform[:3, 3])
        if "NORMAL" in attributes:
            normal = accessor(attributes["NORMAL"]).astype(np.float64) @ np.linalg.inv(
                transform[:3, :3])
            normals.append(normal / np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None])
        own = accessor(primitive["indices"]).astype(np.int64).reshape(-1, 3)
        if np.linalg.det(transform[:3, :3]) < 0:
            own = own[:, ::-1]
        faces.append(own + base)
        base += len(stored)
        for name, index in attributes.items():
            if name not in ("POSITION", "NORMAL"):
                parts.setdefault(name, []).append(accessor(index))
    columns = {name: np.concatenate(arrays) for name, arrays in parts.items()
               if len(arrays) == len(placed)}
    metadata = asset.get("extras", {})
    return Table(columns, "gltf", np.concatenate(positions),
                 np.concatenate(normals) if len(normals) == len(placed) else None,
                 np.concatenate(faces), metadata if isinstance(metadata, dict) else {}, [])


def _list(value) -> list:
    if not isinstance(value, list):
        raise Unreadable(f"{type(value).__name__} where the glTF JSON has a list")
    return value


def _scaled(gltf: dict, binary: bytes | None, index: int, max_bytes: int) -> np.ndarray:
    """Accessor ``index`` as (count,) or (count, k); normalised integers scaled to [0, 1]."""
    values = accessor_array(gltf, binary, index, max_bytes=max_bytes)
    accessor = gltf["accessors"][index]
    if accessor.get("normalized") and values.dtype.kind in "iu":
        values = np.maximum(values / float(np.iinfo(values.dtype).max), -1.0)
    return values
