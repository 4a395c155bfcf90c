"""Output writers, chosen by file extension.

Every per-vertex writer has the signature
``write(path, positions, faces, fields, metadata) -> None`` (see
``aobake.outputs.npz`` for the fields, their shapes and dtypes) and writes
atomically: on failure no file, complete or partial, is left at ``path``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from aobake.errors import OutputError
from aobake.outputs import glb, npz, ply

#: lower-case suffix -> per-vertex writer
VERTEX_WRITERS = {".npz": npz.write, ".ply": ply.write, ".glb": glb.write}


def write_vertices(
    path: str | os.PathLike,
    positions: np.ndarray,
    faces: np.ndarray,
    fields: Mapping[str, np.ndarray],
    metadata: Mapping | None,
) -> None:
    """Write a vertex bake with the writer for ``path``'s (case-insensitive) suffix.

    Parameters
    ----------
    positions : (n, 3) float
    faces : (f, 3) int
    fields : dict of per-vertex arrays, any of ``npz.VERTEX_FIELDS``
    metadata : JSON-serialisable dict

    Raises ``OutputError`` for an unsupported suffix, ``ValueError`` for bad arrays.
    """
    suffix = Path(path).suffix.lower()
    writer = VERTEX_WRITERS.get(suffix)
    if writer is None:
        raise OutputError(
            f"{path}: unsupported output extension {suffix or '(none)'!r}; "
            f"use one of {', '.join(sorted(VERTEX_WRITERS))}"
        )
    writer(path, positions, faces, fields, metadata)
