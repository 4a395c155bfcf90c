"""Reading an NPZ, PLY, GLB or image file into compare's ``Table``: its columns by the name
the format gives them, and the positions, normals, faces and aobake metadata it carries.

The byte-level parsing is ``parsing``'s; this module decides what compare makes of it
(colour bytes mean [0, 1], normalised glTF integers are rescaled, positions are float64).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aobake.compare.parsing import (Unreadable, glb_accessor, npz_names, parse_glb, parse_json,
                                    parse_ply, read_npz, read_pixels)
from aobake.errors import InputError


@dataclass
class Table:
    """What a reader found: columns name -> (n,) | (n, k) | (H, W) arrays, and the rest.

    positions, normals : (n, 3) float64 or None; faces : (f, 3) int64 or None
    metadata : the aobake metadata the file carries ({} for another tool's file)
    warnings : what the reader could not honour (without the file name)
    """

    columns: Mapping
    naming: str  # the Field attribute that names columns in this format: name | ply | gltf | exr
    positions: np.ndarray | None = None
    normals: np.ndarray | None = None
    faces: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)


def read_table(path: Path) -> Table:
    """The table of ``path`` by its suffix (.npz, .ply, .glb; anything else is an image).
    Raises ``Unreadable`` and the parsers' ValueError, KeyError, OSError ... on a bad file."""
    reader = {".npz": npz_table, ".ply": ply_table, ".glb": glb_table}
    return reader.get(path.suffix.lower(), image_table)(path)


def npz_table(path: Path) -> Table:
    """The archive's arrays, loaded when asked for (an archive may also hold every ray's
    distance, which compare never needs), positions, normals, faces and metadata."""
    arrays = read_npz(path, ("positions", "normals", "faces", "metadata"))
    names = set(npz_names(path)) - {"metadata", "positions", "faces"}
    metadata = {}
    if "metadata" in arrays:
        text = arrays["metadata"]
        if text.shape != () or text.dtype.kind != "U":
            raise Unreadable(f"its metadata is a {text.dtype} array of shape {text.shape}, "
                             "not a JSON string")
        metadata = parse_json(str(text[()]), "its metadata")
    return Table(_LazyArchive(path, names), "name", _float(arrays.get("positions")),
                 _float(arrays.get("normals")), _faces(arrays.get("faces")),
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


def _float(array):
    """(n, k) float64 of a numeric array (None stays None); Unreadable for text or objects."""
    if array is None:
        return None
    array = np.asarray(array)
    if array.dtype.kind not in "biuf":
        raise Unreadable(f"an array of {array.dtype} where numbers belong")
    return array.astype(np.float64)


def _faces(array):
    if array is None:
        return None
    array = np.asarray(array)
    if array.ndim != 2 or array.shape[1] != 3 or array.dtype.kind not in "iu":
        return None
    return array.astype(np.int64)


def ply_table(path: Path) -> Table:
    """PLY in any of its three formats: every scalar vertex property, triangle faces when the
    face element is a list of 3 (else None), the ``aobake-metadata`` comment."""
    ply = parse_ply(path.read_bytes())
    vertex, metadata = ply.vertex, ply.metadata
    columns = {name: vertex[name] for name in vertex.dtype.names}
    for name, array in columns.items():  # colour bytes mean [0, 1]
        if array.dtype.kind == "u" and array.dtype.itemsize <= 2:
            columns[name] = array / float(np.iinfo(array.dtype).max)
    positions = normals = None
    if {"x", "y", "z"} <= set(columns):
        positions = np.column_stack([columns.pop(a) for a in "xyz"]).astype(np.float64)
    if {"nx", "ny", "nz"} <= set(columns):
        normals = np.column_stack([columns[a] for a in ("nx", "ny", "nz")]).astype(np.float64)
    return Table(columns, "ply", positions, normals, ply.faces,
                 metadata if isinstance(metadata, dict) else {})


def glb_table(path: Path) -> Table:
    """Every vertex attribute of the file's triangle primitives (primitives sharing a POSITION
    accessor share their vertices, as in aobake's files), positions as stored (node
    transforms are not applied), ``asset.extras`` as metadata when aobake wrote it."""
    from aobake.outputs.glb import GENERATOR

    data = path.read_bytes()
    gltf, binary = parse_glb(data)
    # Every accessor read takes from one budget, a few times the file's size: accessors
    # sharing bytes (or all zeros, without a bufferView) cannot multiply what is allocated.
    budget = [4 * len(data) + (1 << 20)]

    def accessor(index):
        values = _accessor(gltf, binary, index, budget[0])
        budget[0] -= values.nbytes
        return values

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
    return Table(columns, "gltf", positions, _float(normals), np.concatenate(faces),
                 metadata if isinstance(metadata, dict) else {}, warnings)


def _list(value) -> list:
    if not isinstance(value, list):
        raise Unreadable(f"{type(value).__name__} where the glTF JSON has a list")
    return value


def _accessor(gltf: dict, binary: bytes, index: int, max_bytes: int) -> np.ndarray:
    """Accessor ``index`` as (count,) or (count, k); normalised integers scaled to [0, 1]."""
    values = glb_accessor(gltf, binary, index, max_bytes=max_bytes)
    accessor = gltf["accessors"][index]
    if accessor.get("normalized") and values.dtype.kind in "iu":
        values = np.maximum(values / float(np.iinfo(values.dtype).max), -1.0)
    return values


def image_table(path: Path) -> Table:
    """Every channel as (H, W) float (integer files scaled to [0, 1]), alpha unassociated
    (coverage is not opacity), the first subimage; aobake's metadata attribute."""
    pixels, names, attrs = read_pixels(path)
    columns = {name: pixels[:, :, i] for i, name in enumerate(names)}
    metadata = {}
    for attr in ("aobake:metadata", "ImageDescription"):  # TIFF keeps only the description
        text = attrs.get(attr)
        if not isinstance(text, str):
            continue
        try:
            candidate = parse_json(text)
        except Unreadable:  # a description that is not aobake's metadata
            continue
        if isinstance(candidate, dict) and "config" in candidate:
            metadata = candidate
            break
    return Table(columns, "exr", metadata=metadata)
