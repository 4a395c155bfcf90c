"""Every UV set of a glTF / GLB file (``TEXCOORD_0``, ``TEXCOORD_1``, ...), read through trimesh.

trimesh reads ``TEXCOORD_0`` alone (and only for primitives with a material), but it keeps
any vertex attribute whose name starts with ``_`` as it is.  So the file's JSON is given to
trimesh with one alias per UV set, ``_AOBAKE_TEXCOORD_k`` -> the accessor of ``TEXCOORD_k``,
added to every triangle primitive that has the set; each loaded mesh then carries its sets
in ``mesh.vertex_attributes``, in the same vertex order as its positions (trimesh loads
with ``process=False``: no vertex is merged or dropped).  Nothing else in the file changes.
A plain load (set 0) whose meshes trimesh left without the ``TEXCOORD_0`` of a primitive with
no material is read again this way, and those meshes get their set 0
(:func:`dropped_first_set`, :func:`keep_first_set`).

UVs are returned in the OBJ convention (v = 0 at the bottom of the image), as everywhere in
aobake: glTF's (u, v) becomes (u, 1 - v).  Normalised integer UVs (KHR_mesh_quantization)
are scaled to [0, 1] as the glTF spec says.
"""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import numpy as np

from aobake.errors import InputError
from aobake.outputs.gltf import MAGIC, write_glb
from aobake.outputs.gltf import read_gltf as read_json

#: the alias prefix of a UV set in the attributes handed to trimesh
ALIAS = "_AOBAKE_TEXCOORD_"
_SET = re.compile(r"^TEXCOORD_(\d+)$")
_TRIANGLES = (4, 5)  # TRIANGLES, TRIANGLE_STRIP: what trimesh loads as meshes
#: normalised integer component types -> their largest value (glTF 2.0, 3.11)
_NORMALISED = {5121: 255.0, 5123: 65535.0}


def _primitives(header, path=None):
    """Every primitive of the glTF JSON ``header`` as (primitive dict, its attributes dict);
    InputError naming ``path`` where a hand-edited file has the wrong JSON types."""
    where = f"{path}: " if path is not None else ""
    if not isinstance(header, dict):
        raise InputError(f"{where}glTF JSON must be an object, got {type(header).__name__}")
    meshes = header.get("meshes", [])
    if not isinstance(meshes, list):
        raise InputError(f"{where}glTF 'meshes' must be a list, got {type(meshes).__name__}")
    for i, mesh in enumerate(meshes):
        primitives = mesh.get("primitives", []) if isinstance(mesh, dict) else None
        if not isinstance(primitives, list):
            raise InputError(f"{where}glTF meshes[{i}] has no list of primitives")
        for j, primitive in enumerate(primitives):
            attributes = primitive.get("attributes", {}) if isinstance(primitive, dict) else None
            if not isinstance(attributes, dict):
                raise InputError(f"{where}glTF meshes[{i}].primitives[{j}].attributes must "
                                 "be an object")
            yield primitive, attributes


def sets_of(header: dict, path=None) -> tuple[list[int], list[int]]:
    """(sets every triangle primitive has, sets some triangle primitive has), sorted."""
    every, some = None, set()
    for primitive, attributes in _primitives(header, path):
        if primitive.get("mode", 4) not in _TRIANGLES:
            continue
        have = {int(m.group(1)) for m in map(_SET.match, attributes) if m}
        some |= have
        every = have if every is None else every & have
    return sorted(every or ()), sorted(some)


def aliased(path: Path) -> tuple[io.BytesIO, str, list[int]]:
    """The file's bytes with every UV set aliased for trimesh (module docstring).

    Returns (file object, file type "glb" | "gltf", the sets every triangle primitive has).
    """
    header, binary = read_json(path)
    every, _ = sets_of(header, path)
    for _, attributes in _primitives(header, path):
        for name in list(attributes):
            match = _SET.match(name)
            if match:
                attributes[ALIAS + match.group(1)] = attributes[name]
    if binary is None and path.read_bytes()[:4] != MAGIC:
        return io.BytesIO(json.dumps(header).encode("utf-8")), "gltf", every
    packed = io.BytesIO()
    write_glb(packed, header, binary, allow_nan=True)
    packed.seek(0)
    return packed, "glb", every


def mesh_uv(mesh, k: int) -> np.ndarray | None:
    """(v, 2) float64 UV set ``k`` of one loaded trimesh mesh (OBJ convention), or None."""
    attributes = getattr(mesh, "vertex_attributes", None) or {}
    values = attributes.get(ALIAS + str(k))
    if values is None:
        return None
    uv = np.asarray(values)
    if uv.ndim != 2 or uv.shape[1] != 2 or len(uv) != len(mesh.vertices):
        return None
    if uv.dtype.kind in "iu":  # normalised integers (the only integer UVs glTF allows)
        uv = uv.astype(np.float64) / float(np.iinfo(uv.dtype).max)
    uv = uv.astype(np.float64)
    return np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])


def _triangle_meshes(loaded) -> list:
    """The trimesh meshes with faces of a ``trimesh.load`` result (a Scene or a mesh)."""
    geometry = getattr(loaded, "geometry", None)
    meshes = list(geometry.values()) if geometry is not None else [loaded]
    return [m for m in meshes if len(getattr(m, "faces", ())) and hasattr(m, "visual")]


def _has_uv(mesh) -> bool:
    uv = getattr(mesh.visual, "uv", None)
    return uv is not None and len(uv) == len(mesh.vertices)


def dropped_first_set(loaded, path: Path) -> bool:
    """Whether trimesh left a mesh of ``loaded`` (read from glTF ``path`` as it is) without
    the ``TEXCOORD_0`` every triangle primitive of the file has: trimesh reads it only for
    primitives with a material.  The JSON is read only when some mesh has no UVs."""
    if all(_has_uv(m) for m in _triangle_meshes(loaded)):
        return False
    try:
        every, _ = sets_of(read_json(path)[0], path)
    except InputError:  # JSON trimesh read but this reader refuses: trimesh's result stands
        return False
    return 0 in every


def keep_first_set(loaded) -> None:
    """Give every mesh of ``loaded`` (read from :func:`aliased` bytes) that trimesh left
    without UVs its own ``TEXCOORD_0``, with glTF's default material (a primitive without
    one is drawn with it: white, opaque): as if trimesh had read the set itself, so every
    reader of ``mesh.visual.uv`` (the flattened and the instanced loaders) sees it.  The
    material is named "default", as the OBJ loader names faces before any ``usemtl``: one
    material for all of them, not one per unnamed copy."""
    from trimesh.visual import TextureVisuals
    from trimesh.visual.material import PBRMaterial

    default = PBRMaterial(name="default")
    for mesh in _triangle_meshes(loaded):
        if _has_uv(mesh):
            continue
        uv = mesh_uv(mesh, 0)
        if uv is not None:  # OBJ convention: trimesh's own (it flips v as mesh_uv does)
            mesh.visual = TextureVisuals(uv=uv, material=default)


def missing_set_error(path, n: int, every: list[int], some: list[int]) -> InputError:
    """The error for a UV set the file does not have (on every primitive)."""
    if n in some:
        return InputError(f"{path}: TEXCOORD_{n} is missing on some of its triangle "
                          f"primitives (every primitive has {_names(every)}): --uv-set {n} "
                          "needs it on all of them")
    return InputError(f"{path}: has no TEXCOORD_{n} for --uv-set {n} (its UV sets: "
                      f"{_names(some)})")


def _names(sets: list[int]) -> str:
    return ", ".join(f"TEXCOORD_{k}" for k in sets) or "none"
