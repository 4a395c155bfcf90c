"""Readers of aobake's own output files, for the tests (the package only writes them).

The parsing is ``aobake.outputs``' (each format's reader beside its writer; the glTF
container is ``aobake.outputs.gltf``), so it exists once; these adapters keep the tests'
stricter checks (only what aobake's writers lay out) and their return values.

``read_glb`` / ``read_view`` / ``read_accessor``: the GLB container and its accessors;
``read_ply``: the binary PLY layout ``aobake.outputs.ply`` writes; ``read_image``:
EXR/PNG/TIFF through OpenImageIO with unassociated alpha.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from aobake.errors import InputError, OutputError
from aobake.outputs.gltf import accessor_array, parse_glb, view_bytes
from aobake.outputs.image import read_pixels
from aobake.outputs.ply import parse_ply
from aobake.outputs.table import Unreadable


def read_glb(path: str | os.PathLike) -> tuple[dict, bytes]:
    """Read a GLB file.

    Returns
    -------
    gltf : the JSON chunk, parsed
    bin : bytes of the BIN chunk (including its padding), b"" if there is none

    Raises ``InputError`` if the container is malformed (bytes after the last chunk included).
    """
    try:
        gltf, binary = parse_glb(Path(path).read_bytes(), strict=True)
        return gltf, b"" if binary is None else binary
    except Unreadable as exc:
        raise InputError(f"{path}: {exc}") from None


def read_view(gltf: dict, binary: bytes, index: int) -> bytes:
    """Bytes of bufferView ``index`` (e.g. an embedded image) of a GLB's BIN chunk.

    Raises ValueError for a buffer outside the file or a view past its end.
    """
    return view_bytes(gltf, binary, index)


def read_accessor(gltf: dict, binary: bytes, index: int) -> np.ndarray:
    """Values of accessor ``index``, as stored (normalised integers are not rescaled).

    Supports SCALAR and VEC2..VEC4 accessors, interleaved or not; not sparse ones.  Raises
    ValueError if the accessor does not lie within its bufferView.

    Returns
    -------
    values : (count,) for SCALAR, else (count, k), with the accessor's component
      dtype (float32, uint32 ...); a copy, safe to modify
    """
    return accessor_array(gltf, binary, index, strict=True)


def read_ply(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, dict]:
    """Read a PLY file as ``write`` lays it out (binary little-endian, triangles).

    Not a general PLY reader: it accepts scalar vertex properties of any type
    and a face element whose only property is a ``list uchar int|uint`` of 3.

    Returns
    -------
    vertex : (n,) structured array, one field per vertex property, in file order
    faces : (f, 3) int64
    metadata : dict from the ``comment aobake-metadata`` line, {} if none
    """
    data = Path(path).read_bytes()
    if not data.startswith(b"ply\n") or b"end_header\n" not in data:
        raise ValueError(f"{path}: not a PLY file with a header")
    header = data[:data.find(b"end_header\n")]
    if not header.isascii():
        raise ValueError(f"{path}: the header is not ASCII")
    if "format binary_little_endian 1.0" not in header.decode("ascii").splitlines():
        raise ValueError(f"{path}: only binary_little_endian PLY is supported")
    try:
        ply = parse_ply(data)
    except Unreadable as exc:
        raise ValueError(f"{path}: {exc}") from None
    face_props = next((props for name, _, props in ply.elements if name == "face"), [])
    if len(face_props) != 1 or len(face_props[0]) != 3 or face_props[0][1] != "u1":
        raise ValueError(f"{path}: expected one face property 'list uchar int vertex_indices'")
    if ply.faces is None:  # a face list not all of 3, or truncated
        raise ValueError(f"{path}: only triangle faces are supported")
    return ply.vertex.copy(), ply.faces, ply.metadata


def read_image(path) -> tuple[np.ndarray, list[str], dict[str, Any]]:
    """Read an image back (mainly for tests and inspection).

    Returns (pixels (H, W, C) float32, channel_names, attributes).  Float files
    come back as stored; integer files in OIIO's normalised scale, x / (2**bits
    - 1), so ``np.rint(pixels * (2**bits - 1))`` recovers the stored integers
    exactly ('oiio:BitsPerSample' or the format says how many bits).  Alpha is
    read unassociated (colour is not multiplied by alpha).  attributes includes
    'oiio:format' (e.g. 'uint8', 'half'), 'oiio:channelformats' (per-channel
    formats of a mixed file, [] when uniform) and, for EXR, channel names in the
    reader's order.
    """
    try:
        return read_pixels(path)
    except Unreadable as exc:
        raise OutputError(f"{path}: {exc}") from None
