"""Scenes whose meshes stand in many places: glTF nodes that share a mesh, and the copies of
``EXT_mesh_gpu_instancing``, kept as one copy of each mesh plus one transform per placement.

Data flow: a glTF file (trimesh's scene graph) -> :func:`read` -> an :class:`Instances`
record (the unique meshes, each instance's mesh, 4x4 transform and name, which instances
are baked) and the baked instances' meshes placed in scene units (what ``Scene.vertices``
and ``Scene.faces`` hold: ``aobake.scene``).  The occluders trace every instance
(``aobake.occluders``: Embree instances through ``aobake._embree``, one child scene per
unique mesh, so the acceleration structure grows with the unique triangles; flattened
where the backend has no instances); the targets sample only the scene's own vertices, the
baked instances', in instance order, each instance's in its mesh's vertex order.

What counts as an instance: one placement of one glTF primitive (trimesh's geometry: a
mesh with several primitives places each as its own instance, all named after the node);
with ``EXT_mesh_gpu_instancing``, each of its copies (named ``NODE#k``, k from 0 in the
extension's order; placed at node transform x the copy's TRS, as the extension says).
Instances are listed in the order trimesh's ``Scene.dump`` lists the nodes, so baking
every instance gives the flattened loader's vertices, faces and normals, bit for bit.

Which instances are baked (``--bake NODE_GLOB``, :func:`select`): a glob (``fnmatch``,
case-sensitive) matched against each instance's name and its node's name, or with a prefix
against one kind only: ``node:tree*``, ``mesh:ogre``.  No pattern: every instance is baked.
A lightmap of the baked instances is one atlas with a region per instance
(``aobake.targets.texels.instanced``).

An OBJ has no placements, but ``--bake`` chooses its objects and groups the same way
(:func:`subset`, a :class:`Subset` as ``Scene.instances``): the chosen faces are the scene,
every face of the file occludes.  Either way ``source()`` says where the baked vertices
stand in the whole set's bake (every instance flattened, or the whole file), which the
outputs carry (the NPZ's ``source_vertex``) and ``aobake compare`` lines a subset up by.
"""

from __future__ import annotations

import fnmatch
import logging
import math
from dataclasses import dataclass, field

import numpy as np

from aobake.errors import InputError

log = logging.getLogger(__name__)

#: the kinds of names a ``--bake`` pattern may be restricted to with a "kind:" prefix
KINDS = ("node", "mesh")
#: names listed in a "matches no instance" message (then how many more)
LISTED = 20
#: the glTF extension read for per-node copies
EXTENSION = "EXT_mesh_gpu_instancing"
#: the targets that can bake some instances only (their points are the scene's vertices, or
#: a lightmap of the set: one region per baked instance, every ray through the occluders):
#: see :func:`check`
TARGETS = ("vertices", "points", "texels")


@dataclass(frozen=True)
class Instances:
    """Every mesh of a scene once, and where each of its copies stands.

    meshes : tuple of (vertices (v, 3) float64 mesh units, faces (f, 3) int64) per unique
    mesh, as the file gives them; mesh_names : tuple of str; mesh : (n,) int64 each
    instance's mesh; transforms : (n, 4, 4) float64 mesh units -> scene units; names : n
    str (the node's, ``NODE#k`` for a copy of EXT_mesh_gpu_instancing); nodes : n str (the
    node each instance belongs to); baked : (b,) int64 the instances whose triangles are the
    scene's own (in this order); vertex_offsets, face_offsets : (b + 1,) int64 where each
    baked instance's vertices and faces start in the scene's arrays; bounds : (2, 3)
    float64 min and max corner over every instance's used vertices (scene units);
    patterns : the ``--bake`` patterns that chose ``baked`` (() : every instance); uvs :
    per unique mesh its own UVs ((v, 2) float64, OBJ convention: v = 0 at the bottom) or
    None (() : not read), what a lightmap of the set lays out per instance
    (``aobake.targets.texels.instanced``).
    """

    meshes: tuple
    mesh_names: tuple
    mesh: np.ndarray
    transforms: np.ndarray
    names: tuple
    nodes: tuple
    baked: np.ndarray
    vertex_offsets: np.ndarray = field(repr=False)
    face_offsets: np.ndarray = field(repr=False)
    bounds: np.ndarray = field(repr=False)
    patterns: tuple = ()
    uvs: tuple = field(default=(), repr=False)

    #: traced as Embree instances where the backend has them
    instanced = True

    def __len__(self) -> int:
        return len(self.mesh)

    @property
    def everything(self) -> bool:
        """Every instance is baked, in order: the scene's faces are the whole flattened scene."""
        return len(self.baked) == len(self.mesh) and bool(np.all(self.baked == np.arange(len(self))))

    def triangles(self) -> np.ndarray:
        """(n,) int64 each instance's triangle count."""
        counts = np.array([len(faces) for _, faces in self.meshes], dtype=np.int64)
        return counts[self.mesh]

    def record(self) -> dict:
        """The report's summary (``scene.instances``): counts, and the baked instances with
        where their vertices and faces lie in the outputs (``layout``)."""
        unique = int(sum(len(faces) for _, faces in self.meshes))
        return {"instances": int(len(self)), "meshes": int(len(self.meshes)),
                "unique_triangles": unique,
                "instanced_triangles": int(self.triangles().sum()),
                "baked": int(len(self.baked)), "patterns": list(self.patterns)}

    def source(self) -> dict:
        """Where the baked vertices and faces stand in the whole set's flattened arrays (what
        a bake of every instance, or of the flattened scene, holds: instance after instance,
        each mesh's every vertex): {"vertices": V, "faces": F, the whole set's counts;
        "vertex_runs", "face_runs": [[start, stop), ...] of the whole set's arrays that the
        bake's arrays are, one after the other}.  ``aobake compare`` lines a subset bake up
        with the whole set's bake by it."""
        vertex_counts = np.array([len(v) for v, _ in self.meshes], dtype=np.int64)[self.mesh]
        face_counts = np.array([len(f) for _, f in self.meshes], dtype=np.int64)[self.mesh]
        vertex_start = np.concatenate([[0], np.cumsum(vertex_counts)])
        face_start = np.concatenate([[0], np.cumsum(face_counts)])
        return {"vertices": int(vertex_start[-1]), "faces": int(face_start[-1]),
                "vertex_runs": runs(vertex_start[self.baked], vertex_start[self.baked + 1]),
                "face_runs": runs(face_start[self.baked], face_start[self.baked + 1])}

    def layout(self) -> list:
        """One entry per baked instance: its name, node, mesh (name), transform (4x4 rows,
        mesh -> scene units) and the ranges [start, stop) of its vertices and faces in the
        bake's arrays."""
        out = []
        for k, i in enumerate(self.baked):
            out.append({"name": self.names[i], "node": self.nodes[i],
                        "mesh": self.mesh_names[self.mesh[i]],
                        "transform": self.transforms[i].tolist(),
                        "vertices": [int(self.vertex_offsets[k]), int(self.vertex_offsets[k + 1])],
                        "faces": [int(self.face_offsets[k]), int(self.face_offsets[k + 1])]})
        return out


def runs(starts, stops) -> list:
    """[[start, stop), ...] of the ranges given, adjacent ones merged (JSON-ready ints)."""
    out = []
    for start, stop in zip(np.asarray(starts).tolist(), np.asarray(stops).tolist()):
        if out and out[-1][1] == start:
            out[-1][1] = stop
        elif stop > start:
            out.append([int(start), int(stop)])
    return out


def expand_runs(given) -> np.ndarray:
    """(n,) int64 the indices of runs [[start, stop), ...] one after the other."""
    pairs = np.asarray(given, dtype=np.int64).reshape(-1, 2)
    if not len(pairs):
        return np.zeros(0, dtype=np.int64)
    lengths = pairs[:, 1] - pairs[:, 0]
    offsets = np.repeat(pairs[:, 0] - np.concatenate([[0], np.cumsum(lengths)[:-1]]), lengths)
    return np.arange(int(lengths.sum()), dtype=np.int64) + offsets


# ---------------------------------------------------------------------------------------------
# some faces of a flat file (an OBJ's objects and groups)


@dataclass(frozen=True)
class Subset:
    """The faces of a flat file (an OBJ) that ``--bake`` chose, every other face occluding:
    ``Scene.instances`` of the scene of the chosen faces (:func:`subset`).

    vertices (V, 3) float64, faces (F, 3) int64 : the whole file's, what the occluders trace;
    baked_faces : (b,) int64 the file's faces that are the scene's, in file order;
    source_vertex : (n,) int64 the file's vertex of each of the scene's (in file order);
    bounds : (2, 3) float64 the whole file's used vertices' corners (the diagonal, relative
    distances and the ground plane are the file's); patterns : ``--bake``'s; names : {kind:
    [the chosen faces' names]}.
    """

    vertices: np.ndarray = field(repr=False)
    faces: np.ndarray = field(repr=False)
    baked_faces: np.ndarray = field(repr=False)
    source_vertex: np.ndarray = field(repr=False)
    bounds: np.ndarray = field(repr=False)
    patterns: tuple = ()
    names: dict = field(default_factory=dict)

    #: traced as the file's triangles (a flat file has no placements to instance)
    instanced = False

    @property
    def everything(self) -> bool:
        return len(self.baked_faces) == len(self.faces)

    def record(self) -> dict:
        return {"file_faces": int(len(self.faces)), "file_vertices": int(len(self.vertices)),
                "baked_faces": int(len(self.baked_faces)),
                "baked_vertices": int(len(self.source_vertex)),
                "baked": {kind: list(given) for kind, given in self.names.items()},
                "patterns": list(self.patterns)}

    def layout(self) -> list:
        """No per-instance cut: the scene's arrays are the chosen faces' (``source``)."""
        return []

    def source(self) -> dict:
        """As ``Instances.source``: the scene's vertices and faces as runs of the file's (what a
        bake of the whole file holds, in file order)."""
        vertex = self.source_vertex
        face = self.baked_faces
        return {"vertices": int(len(self.vertices)), "faces": int(len(self.faces)),
                "vertex_runs": runs(*_consecutive(vertex)),
                "face_runs": runs(*_consecutive(face))}


def _consecutive(index: np.ndarray):
    """(starts, stops) of the runs of consecutive integers in ``index``."""
    index = np.asarray(index, dtype=np.int64)
    if not len(index):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    breaks = np.flatnonzero(np.diff(index) != 1) + 1
    starts = index[np.concatenate([[0], breaks])]
    stops = index[np.concatenate([breaks - 1, [len(index) - 1]])] + 1
    return starts, stops


def subset(whole, patterns):
    """The scene of the faces of flat scene ``whole`` (an OBJ, loaded whole: its normals,
    repairs and areas are the whole file's) that ``patterns`` name (``groups.bake_faces``),
    the rest occluding: its vertices the ones those faces use, in file order, each with the
    whole file's normal, so each baked vertex is the whole file's bake's vertex; its
    ``instances`` a :class:`Subset`.  InputError for a pattern that names nothing."""
    from dataclasses import replace

    from aobake import groups

    chosen = groups.bake_faces(whole, tuple(patterns))
    baked = np.flatnonzero(chosen)
    used = np.zeros(len(whole.vertices), dtype=bool)
    used[whole.faces[baked].ravel()] = True
    source_vertex = np.flatnonzero(used)
    remap = np.full(len(whole.vertices), -1, dtype=np.int64)
    remap[source_vertex] = np.arange(len(source_vertex))
    names = None if whole.names is None else {
        kind: (given, index[baked]) for kind, (given, index) in whole.names.items()}
    chosen_names = {kind: [given[j] for j in np.unique(index[baked]).tolist() if j >= 0]
                    for kind, (given, index) in (whole.names or {}).items()
                    if kind in groups.BAKE_KINDS}
    record = Subset(whole.vertices, whole.faces, baked, source_vertex,
                    np.array(whole.bounds, dtype=np.float64), tuple(patterns), chosen_names)
    log.info("%s: %d of %d faces baked (%s), the rest occluding", whole.source, len(baked),
             len(whole.faces), ", ".join(patterns))
    return replace(whole, vertices=whole.vertices[source_vertex],
                   faces=remap[whole.faces[baked]],
                   vertex_normals=whole.vertex_normals[source_vertex],
                   face_normals=whole.face_normals[baked],
                   faces_uv=None if whole.faces_uv is None else whole.faces_uv[baked],
                   face_material=None if whole.face_material is None
                   else whole.face_material[baked],
                   face_areas=None if whole.face_areas is None else whole.face_areas[baked],
                   names=names, occluding=None, instances=record)


# ---------------------------------------------------------------------------------------------
# reading a glTF scene graph


@dataclass
class Read:
    """What :func:`read` found: ``instances`` (offsets and bounds filled in) and the
    trimesh scene, whose ``place(k)`` makes the k-th baked instance's mesh placed in scene
    units (a trimesh copy, as ``Scene.dump`` makes it, with ``metadata`` node and name):
    made one at a time by the loader (``aobake.placed``), never all at once."""

    instances: Instances
    loaded: object = field(repr=False)

    def place(self, k: int):
        """The k-th baked instance's mesh, placed (a new trimesh copy)."""
        instances = self.instances
        i = int(instances.baked[k])
        name = instances.mesh_names[instances.mesh[i]]
        current = self.loaded.geometry[name].copy()
        current.apply_transform(instances.transforms[i])  # Scene.dump's own step, bit for bit
        current.metadata["name"] = name
        current.metadata["node"] = instances.names[i]
        return current


def read(loaded, path, patterns=()) -> Read | None:
    """The instances of trimesh scene ``loaded`` (read from glTF file ``path``), the ones
    matching ``patterns`` baked (every one without patterns), or None when nothing in it is
    instanced (no mesh placed twice, no EXT_mesh_gpu_instancing) and no pattern was given:
    then the flattened loader's scene is the same, and cheaper to make.  InputError for a
    pattern that matches no instance."""
    import trimesh

    placed = _placements(loaded, path)
    if not placed:
        raise InputError(f"{path}: mesh has no faces")
    geometry_names = []
    for entry in placed:
        if entry[0] not in geometry_names:
            geometry_names.append(entry[0])
    shared = len(geometry_names) < len(placed)
    if not shared and not patterns:
        return None
    index = {name: k for k, name in enumerate(geometry_names)}
    meshes = tuple((np.asarray(loaded.geometry[name].vertices, dtype=np.float64),
                    np.asarray(loaded.geometry[name].faces, dtype=np.int64))
                   for name in geometry_names)
    mesh = np.array([index[entry[0]] for entry in placed], dtype=np.int64)
    transforms = np.array([entry[1] for entry in placed], dtype=np.float64).reshape(-1, 4, 4)
    names = tuple(entry[2] for entry in placed)
    nodes = tuple(entry[3] for entry in placed)
    chosen = select(names, nodes, tuple(geometry_names), mesh, patterns, path)
    vertex_offsets, face_offsets = [0], [0]
    for i in chosen:  # (a placed copy has its mesh's counts)
        vertex_offsets.append(vertex_offsets[-1] + len(meshes[mesh[i]][0]))
        face_offsets.append(face_offsets[-1] + len(meshes[mesh[i]][1]))
    assert all(isinstance(loaded.geometry[name], trimesh.Trimesh) for name in geometry_names)
    instances = Instances(meshes, tuple(geometry_names), mesh, transforms, names, nodes,
                          np.asarray(chosen, dtype=np.int64),
                          np.asarray(vertex_offsets, dtype=np.int64),
                          np.asarray(face_offsets, dtype=np.int64),
                          world_bounds(meshes, mesh, transforms), tuple(patterns),
                          tuple(_own_uv(loaded.geometry[name]) for name in geometry_names))
    log.info("%s: %d instances of %d meshes (%d triangles placed, %d unique), %d baked",
             path, len(mesh), len(meshes), int(instances.triangles().sum()),
             sum(len(f) for _, f in meshes), len(chosen))
    return Read(instances, loaded)


def _own_uv(geometry) -> np.ndarray | None:
    """(v, 2) float64 a trimesh mesh's own UVs (OBJ convention, as trimesh gives them), or
    None where it has none (or not one per vertex)."""
    uv = getattr(getattr(geometry, "visual", None), "uv", None)
    if uv is None or len(uv) != len(geometry.vertices):
        return None
    return np.asarray(uv, dtype=np.float64)


def _placements(loaded, path) -> list:
    """[(geometry name, transform (4, 4) float64, instance name, node name)] of every
    triangle mesh ``loaded`` places, in ``Scene.dump``'s order, each copy of
    EXT_mesh_gpu_instancing one entry."""
    import trimesh

    graph = loaded.graph
    parents = graph.transforms.parents
    edges = graph.transforms.edge_data
    document = None
    out = []
    for node in graph.nodes_geometry:
        transform, name = graph[node]
        geometry = loaded.geometry.get(name)
        if not isinstance(geometry, trimesh.Trimesh) or not len(geometry.faces):
            continue
        parent = parents.get(node)
        # one primitive of a mesh with several: trimesh names its frame NODE_<random>
        label = parent if geometry.metadata.get("from_gltf_primitive") and parent is not None \
            and parent != graph.base_frame else node
        extensions = edges.get((parent, node), {}).get("metadata", {}).get("gltf_extensions")
        copies = extensions.get(EXTENSION) if isinstance(extensions, dict) else None
        if copies is None:
            out.append((name, np.asarray(transform, dtype=np.float64), str(label), str(label)))
            continue
        if document is None:
            from aobake.outputs.gltf import read_gltf

            document = read_gltf(path)
        for k, local in enumerate(_copies(copies, document, path, label)):
            out.append((name, np.asarray(transform, dtype=np.float64) @ local,
                        f"{label}#{k}", str(label)))
    return out


#: a normalised integer rotation's scale (glTF 2.0, EXT_mesh_gpu_instancing: byte, short)
_NORMALISED = {5120: 127.0, 5122: 32767.0}


def _copies(extension, document, path, node) -> np.ndarray:
    """(k, 4, 4) float64 the TRS matrices of one node's EXT_mesh_gpu_instancing copies
    (translation x rotation x scale, as glTF composes a node's own)."""
    from trimesh import transformations

    from aobake.outputs.gltf import accessor_array
    from aobake.outputs.table import Unreadable

    header, binary = document
    attributes = extension.get("attributes") if isinstance(extension, dict) else None
    if not isinstance(attributes, dict) or not attributes:
        raise InputError(f"{path}: node {node!r}: {EXTENSION} without attributes")
    arrays = {}
    for key, width in (("TRANSLATION", 3), ("ROTATION", 4), ("SCALE", 3)):
        if key not in attributes:
            continue
        try:
            values = accessor_array(header, binary, attributes[key], base=path.parent)
        except (Unreadable, OSError) as exc:
            raise InputError(f"{path}: node {node!r}: {EXTENSION} {key}: {exc}") from None
        component = header["accessors"][attributes[key]].get("componentType")
        values = np.asarray(values, dtype=np.float64).reshape(len(values), -1)
        if key == "ROTATION" and component in _NORMALISED:
            values = np.maximum(values / _NORMALISED[component], -1.0)
        if values.shape[1] != width or not np.isfinite(values).all():
            raise InputError(f"{path}: node {node!r}: {EXTENSION} {key} must be finite "
                             f"VEC{width}, got {values.shape[1]} components")
        arrays[key] = values
    counts = {len(v) for v in arrays.values()}
    if len(counts) != 1:
        raise InputError(f"{path}: node {node!r}: {EXTENSION} attributes have different "
                         f"counts {sorted(counts)}")
    k = counts.pop()
    out = np.tile(np.eye(4), (k, 1, 1))
    for j in range(k):
        matrix = np.eye(4)
        if "TRANSLATION" in arrays:
            matrix = matrix @ transformations.translation_matrix(arrays["TRANSLATION"][j])
        if "ROTATION" in arrays:
            quaternion = arrays["ROTATION"][j][[3, 0, 1, 2]]  # glTF xyzw -> trimesh wxyz
            matrix = matrix @ transformations.quaternion_matrix(quaternion)
        if "SCALE" in arrays:
            matrix = matrix @ np.diag(np.concatenate([arrays["SCALE"][j], [1.0]]))
        out[j] = matrix
    return out


# ---------------------------------------------------------------------------------------------
# choosing the baked instances


def _split(pattern: str) -> tuple[tuple, str]:
    kind, sep, glob = pattern.partition(":")
    if sep and kind in KINDS:
        return (kind,), glob
    return KINDS, pattern


def match(names, nodes, mesh_names, mesh, pattern: str) -> np.ndarray:
    """(n,) bool the instances ``pattern`` names: its glob against each instance's name or
    its node's (kind ``node``), or its mesh's name (kind ``mesh``)."""
    kinds, glob = _split(pattern)
    hit = np.zeros(len(mesh), dtype=bool)
    if "node" in kinds:
        hit |= np.array([fnmatch.fnmatchcase(a, glob) or fnmatch.fnmatchcase(b, glob)
                         for a, b in zip(names, nodes)], dtype=bool)
    if "mesh" in kinds:
        by_mesh = np.array([fnmatch.fnmatchcase(name, glob) for name in mesh_names], dtype=bool)
        hit |= by_mesh[mesh]
    return hit


def select(names, nodes, mesh_names, mesh, patterns, path) -> list:
    """The instances ``patterns`` bake, in instance order (every one for no pattern).
    InputError naming the file's nodes and meshes for a pattern that matches none."""
    if not patterns:
        return list(range(len(mesh)))
    chosen = np.zeros(len(mesh), dtype=bool)
    for pattern in patterns:
        hit = match(names, nodes, mesh_names, mesh, pattern)
        if not hit.any():
            raise InputError(f"{path}: --bake {pattern!r} matches no instance "
                             f"({_available(nodes, mesh_names)})")
        chosen |= hit
    return np.flatnonzero(chosen).tolist()


def _available(nodes, mesh_names) -> str:
    parts = []
    for kind, given in (("node", list(dict.fromkeys(nodes))), ("mesh", list(mesh_names))):
        more = len(given) - LISTED
        parts.append(f"{kind} {', '.join(repr(n) for n in given[:LISTED])}"
                     f"{f' and {more} more' if more > 0 else ''}")
    return "its names: " + "; ".join(parts)


# ---------------------------------------------------------------------------------------------
# geometry of the placed meshes


def used_vertices(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(u, 3) the vertices some face uses."""
    referenced = np.zeros(len(vertices), dtype=bool)
    referenced[faces.ravel()] = True
    return vertices[referenced]


def _support(points: np.ndarray) -> np.ndarray:
    """The rows of ``points`` (u, 3) an affine map's extreme values can come from: its
    convex hull's vertices (every point when qhull cannot make a hull: a flat mesh)."""
    if len(points) <= 64:
        return points
    try:
        from scipy.spatial import ConvexHull, QhullError

        try:
            return points[ConvexHull(points).vertices]
        except (QhullError, ValueError):
            return points
    except ImportError:  # pragma: no cover - scipy comes with trimesh's extras here
        return points


def world_bounds(meshes, mesh: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """(2, 3) float64 min and max corner of every instance's used vertices in scene units.

    Exact up to rounding: an affine map's extremes over a point set lie at its convex
    hull's vertices, so each instance transforms only those (the ogre's hull: ~1% of its
    vertices)."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for k, (vertices, faces) in enumerate(meshes):
        which = np.flatnonzero(mesh == k)
        if not len(which):
            continue
        hull = _support(used_vertices(vertices, faces))
        linear, shift = transforms[which, :3, :3], transforms[which, :3, 3]
        for start in range(0, len(which), 256):  # (256, h, 3) at a time
            part = np.einsum("nij,hj->nhi", linear[start:start + 256], hull) \
                + shift[start:start + 256, None, :]
            lo = np.minimum(lo, part.min(axis=(0, 1)))
            hi = np.maximum(hi, part.max(axis=(0, 1)))
    return np.stack([lo, hi])


def flattened(instances: Instances) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64 scene units, faces (F, 3) int64) of every instance placed,
    in instance order, as ``Scene.dump`` places them (trimesh's ``apply_transform``: the same
    bits, faces reversed where a transform mirrors): what a backend without instances
    traces.  Its memory grows with the instances.  A :class:`Subset`: the whole file's."""
    import trimesh

    if isinstance(instances, Subset):
        return instances.vertices, instances.faces
    vertices, faces, offset = [], [], 0
    for i in range(len(instances)):
        v, f = instances.meshes[instances.mesh[i]]
        placed = trimesh.Trimesh(v, f, process=False, validate=False)
        placed.apply_transform(instances.transforms[i])
        vertices.append(np.asarray(placed.vertices, dtype=np.float64))
        faces.append(np.asarray(placed.faces, dtype=np.int64) + offset)
        offset += len(v)
    return np.concatenate(vertices), np.concatenate(faces)


def local_placements(instances: Instances, center: np.ndarray, scale: float):
    """Every unique mesh and instance transform in the tracer's local frame, for Embree.

    Each mesh is rebased on the per-axis median of its used vertices and scaled by a power
    of two to span [-1, 1] (float32 keeps its precision whatever the mesh's own origin);
    each instance's matrix maps those coordinates into the local frame ((world - center) x
    scale), composed in float64 and rounded once to float32.  Returns (meshes [(vertices
    (v, 3) float32, faces (f, 3) uint32)], mesh_of (n,) int32 (-1 for an instance whose
    3x3 part is singular: its triangles have no area and occlude nothing), transforms (n,
    12) float32 3x4 row-major, linear (n, 3, 3) float64 each instance's 3x3 part from the
    mesh's local coordinates to the tracer's, mesh_faces (M + 1,) int64 offsets of each
    mesh's faces in the concatenation of their face lists)."""
    meshes, frames = [], []
    for vertices, faces in instances.meshes:
        used = used_vertices(vertices, faces)
        own = np.median(used, axis=0)
        reach = float(np.abs(used - own).max()) if len(used) else 0.0
        own_scale = 2.0 ** -math.frexp(reach)[1] if reach > 0 else 1.0
        meshes.append((np.ascontiguousarray(((vertices - own) * own_scale).astype(np.float32)),
                       np.ascontiguousarray(faces, dtype=np.uint32)))
        frames.append((own, own_scale))
    n = len(instances)
    out = np.zeros((n, 3, 4))
    linear = np.zeros((n, 3, 3))
    for i in range(n):
        own, own_scale = frames[instances.mesh[i]]
        a, t = instances.transforms[i, :3, :3], instances.transforms[i, :3, 3]
        linear[i] = a * (scale / own_scale)
        out[i, :, :3] = linear[i]
        out[i, :, 3] = (a @ own + t - center) * scale
    determinant = np.linalg.det(instances.transforms[:, :3, :3])
    mesh_of = np.where(np.isfinite(determinant) & (determinant != 0), instances.mesh,
                       -1).astype(np.int32)
    counts = [len(faces) for _, faces in instances.meshes]
    mesh_faces = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return (meshes, mesh_of, np.ascontiguousarray(out.reshape(n, 12).astype(np.float32)),
            linear, mesh_faces)


# ---------------------------------------------------------------------------------------------
# what can bake some instances only


def check(method: str, target: str, config) -> None:
    """UsageError before any work for a ``--bake`` a bake cannot honour: a method that does
    not trace every ray through the occluders (it would see only the baked instances), a
    target whose points are not the baked faces' (a view's first hits may land on instances
    not baked; a high-to-low bake projects onto its own source), a lightmap of a UV set other
    than 0 (the set's atlas lays each instance's own set-0 UVs out in a region)."""
    from aobake import capabilities
    from aobake.errors import UsageError

    if not getattr(config, "bake", ()):
        return
    if method in capabilities.METHODS and not capabilities.METHODS[method].traces_scene:
        raise UsageError(f"--bake samples some instances and lets the others occlude: "
                         f"--method {method} builds its occluders from the baked mesh alone "
                         "(use --method rays)")
    if target not in TARGETS:
        what = capabilities.TARGETS[target].what if target in capabilities.TARGETS else target
        raise UsageError(f"--bake bakes the instances it names, per vertex or in a lightmap "
                         f"of the set: not {what} ({target}); write .npz, .ply, .glb or an "
                         "image")
    if target == "texels" and getattr(config, "uv_set", 0):
        raise UsageError(f"--bake: a lightmap of the baked instances lays each one's UV set "
                         f"0 out in a region of the set's atlas: not --uv-set "
                         f"{config.uv_set}")
