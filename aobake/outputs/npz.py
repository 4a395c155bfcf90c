"""Per-vertex results as a compressed NumPy archive (``.npz``).

The archive is the complete, lossless-where-it-matters record of a vertex bake,
one array per name:

==================== ============ ========= =====================================
name                 shape        dtype     meaning
==================== ============ ========= =====================================
``positions``        (n, 3)       float64   vertex positions, as given
``faces``            (f, 3)       int64     triangle vertex indices
``normals``          (n, 3)       float64   normals the hemispheres were built on
``ao``               (n,)         float32   ambient occlusion: 1 = fully open, 0 = fully occluded
``ao_stderr``        (n,)         float32   standard error of ``ao``
``obscurance``       (n,)         float32   distance-weighted openness: 1 = open, 0 = occluded
``obscurance_stderr`` (n,)        float32   standard error of ``obscurance``
``bent_normal``      (n, 3)       float32   mean unoccluded direction
``bent_normal_stderr`` (n,)       float32   angular standard error of ``bent_normal`` (radians)
``rays``             (n,)         int32     rays cast for each vertex
``missed``           (n,)         uint8     high-to-low (``--from``): 1 where the vertex's cage ray missed the source
``back_hit``         (n,)         uint8     high-to-low: 1 where it hit the back of a source face
``projection_distance`` (n,)      float32   high-to-low: height L - t of the projected point above the low surface (scene units); 0 where missed
``metadata``         ()           str       JSON text: conventions and configuration
``ray_distances``    (p, r)       float32   --keep-distances: every ray's hit distance (local units: scene units x ``parameters.trace_scale``; ``RAY_MISS`` = -1 on a miss) of the p traced points
``ray_point``        (n,)         int32     --keep-distances: row of ``ray_distances`` of each vertex
``instance_names``   (k,)         str       a scene of instances (``aobake.instances``): the k baked instances' names
``instance_nodes``   (k,)         str       the glTF node of each (a copy of EXT_mesh_gpu_instancing: its node)
``instance_meshes``  (k,)         str       the mesh each places
``instance_vertices`` (k, 2)      int64     [start, stop) of each instance's vertices in the arrays above (its mesh's vertex order)
``instance_faces``   (k, 2)       int64     [start, stop) of its faces
``instance_transforms`` (k, 4, 4) float64   its transform, mesh units -> scene units (rows)
``source_vertex``    (n,)         int64     a ``--bake`` bake (glTF instances, OBJ objects): each vertex's index in the whole set's bake (every instance, or every face of the file, flattened)
==================== ============ ========= =====================================

A scene of instances (glTF nodes sharing a mesh: ``aobake.instances``) stores the baked
instances' vertices one after the other, in instance order: the per-vertex arrays are laid
out as the flattened scene's bake of the same nodes (``aobake compare`` scores one against
the other vertex by vertex), and the ``instance_*`` arrays cut them per instance
(:func:`instance_slices`).  ``source_vertex`` (from the metadata's
``parameters.instances.source``) places each vertex in the whole set's bake: ``aobake
compare`` scores a bake of some instances (or of some objects of an OBJ) against the whole
set's bake by it.

A miss is stored as ``RAY_MISS`` (-1), never inf: no output holds NaN or inf, and every
hit's distance is >= 0, so the sentinel cannot be taken for one.  In memory
(``BakeResult.kept``) a miss is inf, the tracer's own convention; ``encode_ray_distances``
and ``decode_ray_distances`` convert.  Archives written before this encoding hold inf for a
miss; ``decode_ray_distances`` reads both.

Only the fields that were computed are present (the table lists today's
``aobake.quantities.FIELDS``, which is where the names come from).  Geometry stays float64; the
estimates are float32, which is far finer than their standard errors.

This module also holds the table of per-vertex fields (``VERTEX_FIELDS``) and
their validation (``check_vertex_data``) that the PLY and GLB writers share, and the
reader beside the writer: ``read`` (an archive as a ``Table``, its arrays loaded when
asked for), on ``read_npz`` / ``npz_names``, which never unpickle and check each array's
size against the bytes the archive holds for it before allocating it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import struct
import tokenize
import zipfile
import zlib
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from aobake.errors import InputError
from aobake.outputs.atomic import atomic_path
from aobake.outputs.strictjson import metadata_json
from aobake.outputs.table import Table, Unreadable, float64, parse_json, triangles
from aobake.quantities import FIELDS

log = logging.getLogger(__name__)

#: field name -> (per-vertex shape, dtype stored in the NPZ archive), from the registry
VERTEX_FIELDS: dict[str, tuple[tuple[int, ...], type]] = {
    f.name: (() if f.width == 1 else (f.width,), f.dtype) for f in FIELDS.values()
}


def check_vertex_data(
    positions, faces, fields: Mapping
) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Validate per-vertex output data; raise ``ValueError`` naming the problem.

    Parameters
    ----------
    positions : (n, 3) float, finite
    faces : (f, 3) int, each in [0, n)
    fields : dict of name -> (n,) or (n, 3) array, names from ``VERTEX_FIELDS``

    Returns
    -------
    positions : (n, 3) float64
    faces : (f, 3) int64
    fields : dict of name -> array, same keys in ``VERTEX_FIELDS`` order, dtypes as given
    """
    positions = np.asarray(positions)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise ValueError(f"positions must be (n, 3), got {positions.shape}")
    if positions.dtype.kind not in "iuf":
        raise ValueError(f"positions must be float, got {positions.dtype}")
    positions = positions.astype(np.float64, copy=False)
    if not np.isfinite(positions).all():
        raise ValueError("positions must be finite")
    n = len(positions)

    faces = np.asarray(faces)
    if faces.ndim == 1 and faces.size == 0:
        # an empty list of faces: a point set
        faces = faces.reshape(0, 3)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"faces must be (f, 3) triangles, got {faces.shape}")
    if faces.size and faces.dtype.kind not in "iu":
        raise ValueError(f"faces must be integer, got {faces.dtype}")
    faces = faces.astype(np.int64, copy=False)
    if faces.size and (faces.min() < 0 or faces.max() >= n):
        raise ValueError(
            f"faces index vertices {faces.min()}..{faces.max()}, but there are {n} positions"
        )

    if not isinstance(fields, Mapping):
        raise ValueError(f"fields must be a dict, got {type(fields).__name__}")
    unknown = sorted(set(fields) - set(VERTEX_FIELDS))
    if unknown:
        raise ValueError(f"unknown fields {unknown}; expected any of {list(VERTEX_FIELDS)}")
    checked = {}
    for name, (tail, dtype) in VERTEX_FIELDS.items():
        if name not in fields:
            continue
        value = np.asarray(fields[name])
        want = (n, *tail)
        if value.shape != want:
            shape = "(n,)" if not tail else f"(n, {tail[0]})"
            raise ValueError(f"{name} must be {shape} = {want}, got {value.shape}")
        if np.issubdtype(dtype, np.integer):
            if value.dtype.kind not in "iu":
                raise ValueError(f"{name} must be integer, got {value.dtype}")
            if n and (value.min() < 0 or value.max() > np.iinfo(np.int32).max):
                raise ValueError(f"{name} must be in [0, 2**31), got {value.min()}..{value.max()}")
        elif value.dtype.kind not in "iuf":
            raise ValueError(f"{name} must be float, got {value.dtype}")
        checked[name] = value
    if "normals" in checked and not np.isfinite(checked["normals"]).all():
        raise ValueError("normals must be finite")
    return positions, faces, checked


#: ``ray_distances`` of a ray that hit nothing within the max distance, as stored
RAY_MISS = np.float32(-1.0)


def encode_ray_distances(distances: np.ndarray) -> np.ndarray:
    """(p, r) float32 hit distances, inf for a miss -> as stored: ``RAY_MISS`` for a miss."""
    distances = np.asarray(distances, dtype=np.float32)
    return np.where(distances == np.inf, RAY_MISS, distances)


def decode_ray_distances(stored: np.ndarray) -> np.ndarray:
    """As stored (``RAY_MISS`` for a miss, or inf in archives written before) -> float32
    distances with inf for a miss.  Other values are returned as they are (a reader
    refuses negative or NaN ones: ``aobake.refit``)."""
    stored = np.asarray(stored, dtype=np.float32)
    return np.where(stored == RAY_MISS, np.float32(np.inf), stored)


def _savez(handle, arrays: dict) -> None:
    """np.savez_compressed at deflate level 1, float64 members stored: the same archive
    format (np.load reads it).  Level 1: on the bunny's arrays 0.23 -> 0.12 s (a loaded
    machine) for a 3% larger file.  Stored float64 (positions, normals): deflate shrinks
    their mantissas only to 0.75-0.93 of their size for 47 of the archive's 69 ms (bunny;
    the file grows by 0.28 MB, 14%)."""
    with zipfile.ZipFile(handle, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1,
                         allowZip64=True) as archive:
        for name, value in arrays.items():
            value = np.asanyarray(value)
            # read by open() per member (with the level given above)
            archive.compression = (zipfile.ZIP_STORED if value.dtype == np.float64
                                   else zipfile.ZIP_DEFLATED)
            with archive.open(name + ".npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, value, allow_pickle=False)


def write(
    path: str | os.PathLike,
    positions: np.ndarray,
    faces: np.ndarray,
    fields: Mapping[str, np.ndarray],
    metadata: Mapping | None,
    kept: Mapping | None = None,
) -> None:
    """Write a vertex bake to ``path`` as a compressed ``.npz`` archive, atomically.

    Parameters
    ----------
    path : output file; written as given (no ``.npz`` is appended)
    positions : (n, 3) float
    faces : (f, 3) int
    fields : dict of per-vertex arrays, any of ``VERTEX_FIELDS`` (see the module docstring)
    metadata : JSON-serialisable dict, stored as the 0-d string array ``metadata``
    kept : ``BakeResult.kept`` (ray distances for ``aobake refit``) or None

    Dtypes in the archive are listed in the module docstring.
    """
    positions, faces, fields = check_vertex_data(positions, faces, fields)
    arrays = {"positions": positions, "faces": faces}
    for name, value in fields.items():
        arrays[name] = value.astype(VERTEX_FIELDS[name][1])
    # a 0-d unicode array loads without pickling (np.load(allow_pickle=False))
    arrays["metadata"] = np.array(metadata_json(metadata))
    for name, value in (kept or {}).items():
        arrays[name] = encode_ray_distances(value) if name == "ray_distances" else value
    arrays.update(instance_arrays(metadata, len(positions), len(faces)))
    arrays.update(source_arrays(metadata, len(positions)))
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:
            _savez(handle, arrays)
    log.debug("wrote %s: %d vertices, %d faces, %s", path, len(positions), len(faces), list(fields))


def instance_arrays(metadata: Mapping | None, n_vertices: int, n_faces: int) -> dict:
    """The ``instance_*`` arrays of a bake of instances, from its metadata's
    ``parameters.instances.layout`` (``aobake.occluders``), or {} for any other bake (or a
    layout that does not cover these arrays: then nothing is claimed about them)."""
    layout = ((metadata or {}).get("parameters") or {}).get("instances", {}).get("layout")
    if not layout:
        return {}
    vertices = np.array([entry["vertices"] for entry in layout], dtype=np.int64).reshape(-1, 2)
    faces = np.array([entry["faces"] for entry in layout], dtype=np.int64).reshape(-1, 2)
    if vertices[-1, 1] != n_vertices or faces[-1, 1] != n_faces:
        log.warning("instance layout covers %d vertices and %d faces, the arrays %d and %d: "
                    "not written", vertices[-1, 1], faces[-1, 1], n_vertices, n_faces)
        return {}
    return {"instance_names": np.array([str(e["name"]) for e in layout]),
            "instance_nodes": np.array([str(e["node"]) for e in layout]),
            "instance_meshes": np.array([str(e["mesh"]) for e in layout]),
            "instance_vertices": vertices, "instance_faces": faces,
            "instance_transforms": np.array([e["transform"] for e in layout],
                                            dtype=np.float64).reshape(-1, 4, 4)}


def source_arrays(metadata: Mapping | None, n_vertices: int) -> dict:
    """``source_vertex`` of a ``--bake`` bake (each vertex's index in the whole set's bake),
    from its metadata's ``parameters.instances.source``, or {} for a bake of everything, any
    other bake, or runs that do not cover these vertices."""
    from aobake.instances import expand_runs

    source = ((metadata or {}).get("parameters") or {}).get("instances", {}).get("source")
    if not source:
        return {}
    index = expand_runs(source.get("vertex_runs", []))
    if len(index) != n_vertices:
        log.warning("the source runs cover %d vertices, the arrays %d: not written",
                    len(index), n_vertices)
        return {}
    if n_vertices == source.get("vertices") and np.array_equal(index, np.arange(n_vertices)):
        return {}  # the whole set: its own order
    return {"source_vertex": index}


def instance_slices(path) -> list:
    """[(instance name, vertex slice, face slice)] of an NPZ bake of instances (the
    ``instance_*`` arrays), in order ([] for any other bake; a mesh of several primitives
    gives one entry per primitive, under its node's name).  Faces index the whole arrays:
    subtract the vertex slice's start for an instance's own.  Raises ``Unreadable``."""
    arrays = read_npz(path, ("instance_names", "instance_vertices", "instance_faces"))
    if len(arrays) < 3:
        return []
    return [(str(name), slice(int(v0), int(v1)), slice(int(f0), int(f1)))
            for name, (v0, v1), (f0, f1) in zip(arrays["instance_names"],
                                                arrays["instance_vertices"],
                                                arrays["instance_faces"])]


# ---------------------------------------------------------------------------------------------
# reading


def read(path) -> Table:
    """The archive as a ``Table`` (``naming`` 'name'): its arrays as columns, each loaded when
    first looked up (an archive may also hold every ray's distance, which a reader of values
    seldom needs), positions, normals, faces and the metadata.  Raises ``Unreadable``."""
    path = Path(path)
    arrays = read_npz(path, ("positions", "normals", "faces", "metadata"))
    names = set(npz_names(path)) - {"metadata", "positions", "faces"}
    metadata = {}
    if "metadata" in arrays:
        text = arrays["metadata"]
        if text.shape != () or text.dtype.kind != "U":
            raise Unreadable(f"its metadata is a {text.dtype} array of shape {text.shape}, "
                             "not a JSON string")
        metadata = parse_json(str(text[()]), "its metadata")
    return Table(_LazyArchive(path, names), "name", float64(arrays.get("positions")),
                 float64(arrays.get("normals")), triangles(arrays.get("faces")),
                 metadata if isinstance(metadata, dict) else {})


class _LazyArchive(Mapping):
    """name -> array of an NPZ archive, each read from the file when first looked up."""

    def __init__(self, path: Path, names):
        self.path, self.names, self.loaded = path, sorted(names), {}

    def __iter__(self):
        return iter(self.names)

    def __len__(self):
        return len(self.names)

    def __getitem__(self, name):
        if name not in self.names:
            raise KeyError(name)
        if name not in self.loaded:
            try:
                self.loaded[name] = read_npz(self.path, [name])[name]
            except (Unreadable, OSError) as exc:
                reason = " ".join(str(exc).split()) or type(exc).__name__
                raise InputError(f"{self.path}: cannot read array {name!r}: {reason}") from None
        return self.loaded[name]


#: the most bytes one byte of deflate data can expand to (deflate's limit is 1032)
_DEFLATE_RATIO = 1040


def read_npz(path, names=None) -> dict:
    """Arrays of an NPZ archive (``np.savez``'s format): {name: array} for ``names`` (None:
    all; names it does not hold are left out), never unpickled.  Each array's size is
    checked against the bytes the archive holds for it before it is allocated.  Raises
    ``Unreadable`` for anything malformed (OSError for a file that cannot be opened)."""
    with _npz_errors():
        with zipfile.ZipFile(path) as archive:
            members = npz_members(archive)
            wanted = members if names is None else [n for n in names if n in members]
            return {name: npz_array(archive, name) for name in wanted}


def npz_names(path) -> list:
    """The array names of an NPZ archive.  Raises ``Unreadable`` (OSError: cannot open)."""
    with _npz_errors():
        with zipfile.ZipFile(path) as archive:
            return npz_members(archive)


@contextlib.contextmanager
def _npz_errors():
    """What zipfile and zlib raise on a malformed archive, as ``Unreadable``."""
    try:
        yield
    except zipfile.BadZipFile as exc:
        raise Unreadable(f"not an NPZ archive ({exc})") from None
    except zlib.error as exc:
        raise Unreadable(f"corrupt compressed data ({exc})") from None
    except NotImplementedError as exc:  # zipfile: an unknown version or feature
        raise Unreadable(f"not an NPZ archive np.savez writes ({exc})") from None
    except (EOFError, struct.error):
        raise Unreadable("truncated archive") from None


def npz_members(archive: zipfile.ZipFile) -> list:
    """The array names of an open NPZ archive (its ``.npy`` members, without the suffix)."""
    return [info.filename[:-4] for info in archive.infolist() if info.filename.endswith(".npy")]


def npz_array(archive: zipfile.ZipFile, name: str) -> np.ndarray:
    """Array ``name`` of an open NPZ archive, its header checked first: no Python objects,
    and no more bytes than the member holds (itself at most what its compressed bytes can
    expand to)."""
    info = archive.getinfo(name + ".npy")
    if info.flag_bits & 0x1:
        raise Unreadable(f"array {name!r} is encrypted (np.savez never encrypts)")
    if info.compress_type == zipfile.ZIP_STORED:
        if info.file_size != info.compress_size:
            raise Unreadable(f"array {name!r}: the archive's sizes disagree")
    elif info.compress_type == zipfile.ZIP_DEFLATED:
        if info.file_size > info.compress_size * _DEFLATE_RATIO + 1024:
            raise Unreadable(f"array {name!r}: claims {info.file_size} bytes from "
                             f"{info.compress_size} compressed ones (more than deflate makes)")
    else:
        raise Unreadable(f"array {name!r}: compression method {info.compress_type} "
                         "(np.savez writes stored or deflated members)")
    with archive.open(info) as member:
        try:
            version = np.lib.format.read_magic(member)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(member)
            elif version == (2, 0):
                shape, _, dtype = np.lib.format.read_array_header_2_0(member)
            else:
                raise Unreadable(f"array {name!r}: .npy format version {version} not read")
        except (ValueError, SyntaxError, RecursionError, tokenize.TokenError) as exc:
            if isinstance(exc, Unreadable):
                raise
            raise Unreadable(f"array {name!r}: malformed .npy header ({' '.join(str(exc).split())})"
                             ) from None
        if dtype.hasobject:
            raise Unreadable(f"array {name!r} holds Python objects (never unpickled)")
        count = 1
        for extent in shape:
            count *= int(extent)
        if count * dtype.itemsize > info.file_size:
            raise Unreadable(f"array {name!r}: its header claims {shape} of {dtype}, "
                             f"{count * dtype.itemsize} bytes, but the archive holds "
                             f"{info.file_size} for it")
    with archive.open(info) as member:
        try:
            return np.lib.format.read_array(member, allow_pickle=False)
        except ValueError as exc:  # e.g. "EOF: reading array data"
            raise Unreadable(f"array {name!r}: {' '.join(str(exc).split())}") from None
