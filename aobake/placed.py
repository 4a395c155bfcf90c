"""The scene of a set's baked instances, made one instance at a time.

A glTF set loaded as instances (``aobake.instances``) bakes the instances ``--bake`` names,
every one without it: the scene's vertices, faces and vertex normals are those instances'
placed in scene units, one after the other, what the flattened loader makes of the same
file, bit for bit.  :func:`make_scene` (``aobake.scene``) makes them from the whole
concatenation at once: its winding check, normals and areas are passes over every placed
triangle, ~190 bytes a triangle at its peak, so a set of N copies of a mesh peaked at N
times the mesh's bytes before a ray was cast.  Here the same passes run over each
instance alone, in the frame ``make_scene`` would choose for the whole set, into arrays
made once at their final size:

* the placed vertices, faces and file normals: each instance's trimesh copy placed as
  ``Scene.dump`` places it (``apply_transform``), written into the set's arrays, and let
  go before the next;
* the winding check (``aobake.repair.orient``): no component spans two instances (they
  share no vertex), and every per-component sum adds its faces in face order, so each
  instance's components are found, coloured and oriented as in the whole; the counts add;
* vertex normals: a vertex's faces are its instance's, summed in face order as over the
  whole;
* face normals and areas are not kept (the scene is lean from the start, ``Scene.lean``:
  remade from the frame where read); the warnings' figures are made per instance: the
  degenerate faces are counted, and the median area of the quantisation warning is only
  needed where the smallest area could raise it (then the areas are gathered once).

The per-face name index (``Scene.names``: node and mesh, 8 bytes a face each) is made
where a selection reads it, from each instance's names.  What still grows with the baked
instances besides the outputs is listed in docs/scale.md, "Memory".
"""

from __future__ import annotations

import logging
import math

import numpy as np

from aobake import repair as repairs
from aobake.errors import InputError

log = logging.getLogger(__name__)


def _parts(vertex_offsets, face_offsets):
    """[(vertex slice, face slice)] of each part."""
    return [(slice(int(vertex_offsets[k]), int(vertex_offsets[k + 1])),
             slice(int(face_offsets[k]), int(face_offsets[k + 1])))
            for k in range(len(vertex_offsets) - 1)]


def make_placed_scene(vertices, faces, normals, normals_mode: str, parts, source: str,
                      fix_normals: str = "warn", uv=None, materials=None, face_material=None,
                      names=None):
    """:func:`aobake.scene.make_scene` of vertex-disjoint parts, a part at a time: the same
    Scene (vertices, faces, vertex normals, repair record, warnings: the same bits), lean
    (no face normals or areas held; ``Scene.lean``).

    vertices (V, 3) float64, faces (F, 3) int64 (indices into the whole; modified in place
    where ``fix_normals == "fix"`` flips faces), normals (V, 3) float64 | None, uv (V, 2)
    float64 | None (per vertex: the corners' UV indices are the faces), parts :
    (vertex_offsets, face_offsets) (k + 1,) int64 each: part j owns vertices
    [vertex_offsets[j], vertex_offsets[j + 1]) and faces [face_offsets[j], ...), and its
    faces use its vertices only (InputError otherwise).
    """
    from aobake.scene import (MAX_COORDINATE, MIN_EXTENT, QUANTISED_FRACTION, Scene,
                              checked_materials, compiled_triangle_normals,
                              compiled_vertex_normals, face_rows, repair_record,
                              replace_flipped_normals, vertex_normals)
    from aobake.vectors import normalize

    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(f"{source}: vertices must be (n, 3) and faces (n, 3), got "
                         f"{vertices.shape} and {faces.shape}")
    if len(faces) == 0:
        raise InputError(f"{source}: mesh has no faces")
    if fix_normals not in repairs.MODES:
        raise InputError(f"fix_normals must be one of {sorted(repairs.MODES)}, got {fix_normals!r}")
    pieces = _parts(*parts)
    warnings = []
    # The frame make_scene chooses: the used vertices' corners and largest magnitude
    # (min and max are exact in any order).
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    largest = 0.0
    for vs, fs in pieces:
        own = faces[fs] - vs.start
        if len(own) and (own.min() < 0 or own.max() >= vs.stop - vs.start):
            raise InputError(f"{source}: face index out of range (have {len(vertices)} "
                             "vertices)")
        if not np.isfinite(vertices[vs]).all():
            bad = int(np.count_nonzero(~np.isfinite(vertices[vs]).all(axis=1)))
            raise InputError(f"{source}: {bad} vertices have NaN or infinite coordinates")
        if not len(own):
            continue
        referenced = np.zeros(vs.stop - vs.start, dtype=bool)
        referenced[own.ravel()] = True
        used = vertices[vs][referenced]
        lo, hi = np.minimum(lo, used.min(axis=0)), np.maximum(hi, used.max(axis=0))
        largest = max(largest, float(np.abs(used).max()))
    extent = float((hi - lo).max())
    if largest > MAX_COORDINATE or 0 < extent < MIN_EXTENT:
        raise InputError(f"{source}: coordinates up to {largest:.3g} and extent {extent:.3g} are "
                         f"outside what aobake bakes: |coordinates| <= {MAX_COORDINATE:g} and "
                         f"extent >= {MIN_EXTENT:g} scene units (areas are float64; rescale "
                         "the mesh)")
    center = 0.5 * (lo + hi)
    scale = 2.0 ** -math.frexp(extent)[1] if extent > 0 else 1.0
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != vertices.shape:
            if normals_mode == "file":
                raise InputError(f"{source}: normals must be {vertices.shape}, got {normals.shape}")
            normals = None
    angles = normals_mode == "angle" or (normals_mode == "file" and normals is None)
    mode = "angle" if normals_mode == "file" and normals is None else normals_mode
    if uv is not None:  # per vertex: the corners' UV indices are the faces
        uv = np.asarray(uv, dtype=np.float64)
        if uv.shape != (len(vertices), 2):
            raise InputError(f"{source}: UV indices do not match the faces")
    vnormals = np.empty_like(vertices)
    totals = None
    flipped_total, replaced_total, n_degenerate = 0, 0, 0
    smallest = math.inf  # the smallest positive area
    for vs, fs in pieces:
        own = faces[fs] - vs.start
        local = (vertices[vs] - center) * scale
        part_normals = None if normals is None else normals[vs]
        flipped = None
        if fix_normals != "off" and len(own):
            votes = None if part_normals is None else normalize(part_normals)[0]
            orientation = repairs.orient(local, own, votes)
            counts = orientation.counts()
            totals = counts if totals is None else {k: totals[k] + counts[k] for k in totals}
            if fix_normals == "fix" and orientation.flip.any():
                flipped = orientation.flip
                own = repairs.flip_faces(own, flipped)
                faces[fs] = own + vs.start
                flipped_total += int(flipped.sum())
        compiled = compiled_triangle_normals(local, own, cosines=angles) if len(own) else None
        cosines = None
        if compiled is not None:
            fnormals, length, cosines = compiled[0], compiled[1], compiled[3]
        else:  # make_scene's numpy lines
            tri = local[own]
            cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            fnormals, length = normalize(cross)[0], np.linalg.norm(cross, axis=1)
            del tri, cross
        areas = 0.5 * length / (scale * scale)
        n_degenerate += int(np.count_nonzero(~fnormals.any(axis=1)))
        positive = areas[areas > 0]
        if len(positive):
            smallest = min(smallest, float(positive.min()))
        if mode == "file":
            out = normalize(part_normals)[0]
            if flipped is not None:
                out, replaced = replace_flipped_normals(out, local, own, flipped)
                replaced_total += replaced
            referenced = np.zeros(len(out), dtype=bool)
            referenced[own.ravel()] = True
            if not out[referenced].any(axis=1).all():
                computed = vertex_normals(local, own, "angle")
                out = np.where(out.any(axis=1, keepdims=True), out, computed)
        else:
            out = None
            if cosines is not None and mode == "angle":
                out = compiled_vertex_normals(own, len(local), fnormals, None, cosines)
            if out is None:
                out = vertex_normals(local, own, mode)
        vnormals[vs] = out
        if uv is not None and len(own) and not np.isfinite(uv[vs][own]).all():
            raise InputError(f"{source}: UV coordinates contain NaN or infinity")
        del local, fnormals, cosines, areas, out
    if fix_normals == "off":
        record = repair_record("off")
    else:
        text = repairs.orientation_warning(fix_normals, totals, flipped_total, source)
        if text:
            warnings.append(text)
        record = repair_record(fix_normals, totals, flipped_total)
        record["normals_replaced"] = replaced_total
    if n_degenerate == len(faces):
        raise InputError(f"{source}: every face has zero area")
    if n_degenerate:
        warnings.append(f"{source}: {n_degenerate} zero-area triangles (they never occlude)")
    face_material = checked_materials(face_material, materials, len(faces), source)
    step = float(np.spacing(largest))
    # make_scene's quantisation warning: typical = sqrt(2 median positive area), a
    # warning where step > QUANTISED_FRACTION * typical.  The median is at least the
    # smallest area, so where even that one raises nothing no median is needed; else the
    # positive areas are gathered (8 bytes a face, once) for make_scene's very figure.
    if math.isfinite(smallest) and step > QUANTISED_FRACTION * math.sqrt(2.0 * smallest):
        sized = []
        for vs, fs in pieces:
            areas = face_rows(vertices, faces[fs], center, scale, normals=False)[1]
            sized.append(areas[areas > 0])
        typical = math.sqrt(2.0 * float(np.median(np.concatenate(sized))))
        if typical > 0 and step > QUANTISED_FRACTION * typical:
            warnings.append(f"{source}: coordinates up to {largest:.3g} are quantised by "
                            f"float64 itself to steps of {step:.3g}, {step / typical:.2g} of "
                            "the median triangle size: the file's positions are already "
                            "rounded (translate the mesh nearer the origin before exporting "
                            "it)")
    for message in warnings:
        log.warning(message)
    if not callable(names):
        names = {kind: (tuple(str(n) for n in given), np.asarray(index, dtype=np.int64))
                 for kind, (given, index) in (names or {}).items() if len(given)} or None
    faces_uv = faces if uv is not None else None
    return Scene(vertices, faces, vnormals, None, uv, faces_uv, source, mode, warnings,
                 materials, face_material, None, record, names, frame=(center, scale))


def placed_arrays(read, path):
    """The flattened loader's arrays of the baked instances of ``read``
    (``aobake.instances.Read``), each instance placed (``Read.place``) and written into
    arrays made once at the set's size, one instance at a time:
    (vertices (V, 3) float64, faces (F, 3) int64, normals (V, 3) float64 | None: the file's,
    where every instance has them, uv (V, 2) float64 | None: where every instance has one
    per vertex, (materials, face_material (F,) int64) | None: with the UVs, names: kind ->
    (names, (F,) int64 | None)): what ``aobake.scene._load_with_trimesh`` makes of the
    placed copies all at once, the same values in the same order."""
    from aobake.scene import gltf_broken_textures, trimesh_material

    instances = read.instances
    n_vertices, n_faces = int(instances.vertex_offsets[-1]), int(instances.face_offsets[-1])
    vertices = np.empty((n_vertices, 3))
    faces = np.empty((n_faces, 3), dtype=np.int64)
    normals = uv = None
    have_normals = have_uv = True
    kinds = {"node": lambda m: m.metadata.get("node"),
             "mesh": lambda m: m.metadata.get("name"),
             "material": lambda m: getattr(getattr(m.visual, "material", None), "name", None)}
    given = {kind: [] for kind in kinds}
    rows = {kind: [] for kind in kinds}  # each instance's row in given[kind], -1: none
    materials, keys, face_material, broken = [], {}, None, None
    for k, (vs, fs) in enumerate(_parts(instances.vertex_offsets, instances.face_offsets)):
        mesh = read.place(k)
        vertices[vs] = np.asarray(mesh.vertices, dtype=np.float64)
        faces[fs] = np.asarray(mesh.faces, dtype=np.int64) + vs.start
        if have_normals and "vertex_normals" in mesh._cache:
            if normals is None:
                normals = np.empty((n_vertices, 3))
            normals[vs] = np.asarray(mesh.vertex_normals, dtype=np.float64)
        else:
            have_normals, normals = False, None
        own_uv = getattr(mesh.visual, "uv", None)
        if have_uv and own_uv is not None and len(own_uv) == len(mesh.vertices):
            if uv is None:
                uv = np.empty((n_vertices, 2))
                face_material = np.empty(n_faces, dtype=np.int64)
                broken = gltf_broken_textures(path) if path.suffix.lower() in (
                    ".gltf", ".glb") else {}
            uv[vs] = np.asarray(own_uv, dtype=np.float64)
            # scene._trimesh_materials' loop, a copy at a time: distinct by content
            material = trimesh_material(mesh, len(materials), broken)
            factor = material["base_color_factor"]
            key = (material["name"], material["base_color_png"],
                   tuple(factor) if factor else None, material["metallic_roughness_png"],
                   material["roughness_factor"], material["metallic_factor"],
                   material["alpha_mode"], material["alpha_cutoff"],
                   material.get("base_color_error"))
            if key not in keys:
                keys[key] = len(materials)
                materials.append(material)
            face_material[fs] = keys[key]
        else:
            have_uv, uv, face_material = False, None, None
        for kind, name_of in kinds.items():  # scene._trimesh_names, a copy at a time
            name = name_of(mesh)
            if name is not None and str(name) not in given[kind]:
                given[kind].append(str(name))
            rows[kind].append(-1 if name is None else given[kind].index(str(name)))
        del mesh
    names = NameRows({kind: tuple(given[kind]) for kind in kinds if given[kind]},
                     {kind: np.asarray(rows[kind], dtype=np.int64) for kind in kinds
                      if given[kind]}, np.diff(instances.face_offsets))
    return (vertices, faces, normals, uv, (materials, face_material) if uv is not None
            else None, names)


class NameRows:
    """``Scene.names`` of placed instances, made when called (``Scene.names`` calls it where
    first read: a selection by name), not with the scene: each face's row is its instance's
    (8 bytes a face a kind).

    given : kind -> tuple of str, rows : kind -> (k,) int64 each instance's row in
    ``given[kind]`` (-1: none), counts : (k,) int64 each instance's faces."""

    def __init__(self, given: dict, rows: dict, counts: np.ndarray):
        self.given, self.rows, self.counts = given, rows, counts

    def __call__(self) -> dict | None:
        return {kind: (names, np.repeat(self.rows[kind], self.counts))
                for kind, names in self.given.items()} or None
