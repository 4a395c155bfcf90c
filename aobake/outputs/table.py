"""What every reader of a bake file shares: the ``Table`` it returns, the ``Unreadable`` it
raises, and the bounded JSON parser for the metadata the writers store.

Each format module of ``aobake.outputs`` has its reader beside its writer (``npz.read``,
``ply.read``, ``glb.read``, ``image.read``: a path -> ``Table``), listed with it in
``aobake.outputs.registry.WRITERS``; ``aobake.outputs.read`` picks one quantity out of a
table.  A reader raises ``Unreadable`` (a ``ValueError``) with the reason, without the file
name (the caller names it).

What a reader allocates is bounded by what the file holds: a header's count (a PLY element,
a glTF accessor, an NPZ array's shape, an image's size) is checked against the bytes that
would hold it before anything of that size is made, so a file of a few bytes claiming
terabytes is refused, not attempted.  JSON nested beyond any real metadata is refused
(``parse_json``).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np


class Unreadable(ValueError):
    """A reader's reason a file is malformed (``aobake.outputs.read``: ``InputError('FILE:
    cannot read as NPZ: reason')``)."""


@dataclass
class Table:
    """What a reader found: columns name -> (n,) | (n, k) | (H, W) arrays, and the rest.

    naming : the ``aobake.quantities`` Field attribute that names columns in this format:
      'name' (NPZ) | 'ply' | 'gltf' | 'exr' (every image)
    positions, normals : (n, 3) float64 or None; faces : (f, 3) int64 or None
    metadata : the aobake metadata the file carries ({} for another tool's file)
    warnings : what the reader could not honour (without the file name)
    transfers : an image's columns -> how their stored values encode linear ones
      (``aobake.outputs.image.Transfer``, as the file's colour tags say); None for files of
      numbers (per-vertex formats)
    parts : a multi-part image's part names -> their channels (as the file names them), for
      messages; None for a single-part file or another format
    """

    columns: Mapping
    naming: str
    positions: np.ndarray | None = None
    normals: np.ndarray | None = None
    faces: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    transfers: Mapping | None = None
    parts: Mapping | None = None


def float64(array) -> np.ndarray | None:
    """(n, k) float64 of a numeric array (None stays None); Unreadable for text or objects."""
    if array is None:
        return None
    array = np.asarray(array)
    if array.dtype.kind not in "biuf":
        raise Unreadable(f"an array of {array.dtype} where numbers belong")
    return array.astype(np.float64)


def triangles(array) -> np.ndarray | None:
    """(f, 3) int64 of an integer (f, 3) array; None for None or any other shape or type."""
    if array is None:
        return None
    array = np.asarray(array)
    if array.ndim != 2 or array.shape[1] != 3 or array.dtype.kind not in "iu":
        return None
    return array.astype(np.int64)


#: JSON deeper than this is not metadata (aobake's is 4 levels deep); Python's parser
#: would otherwise recurse until RecursionError
JSON_DEPTH = 64


def parse_json(text, what: str = "JSON"):
    """``json.loads(text)`` (str or UTF-8 bytes), refused (``Unreadable``) when it is not JSON
    or nests deeper than ``JSON_DEPTH`` (checked on the text before parsing, so the parser
    never recurses that far)."""
    if isinstance(text, (bytes, bytearray, memoryview)):
        try:
            text = bytes(text).decode("utf-8")
        except UnicodeDecodeError:
            raise Unreadable(f"{what} is not UTF-8 text") from None
    depth = _json_depth(text)
    if depth > JSON_DEPTH:
        raise Unreadable(f"{what} nests {depth} levels deep (more than {JSON_DEPTH}: not "
                         "metadata)")
    try:
        return json.loads(text)
    except RecursionError:  # pragma: no cover - bounded above
        raise Unreadable(f"{what} nests too deeply") from None
    except ValueError as exc:
        raise Unreadable(f"{what} is not valid JSON ({exc})") from None


def _json_depth(text: str) -> int:
    """The deepest nesting of [ and { outside strings (strings are blanked first; an
    unterminated one leaves an upper bound, which is all the check needs)."""
    if "[" not in text and "{" not in text:
        return 0
    codes = np.frombuffer(_JSON_STRING.sub('""', text).encode("utf-8", "replace"), np.uint8)
    step = np.isin(codes, _OPEN).astype(np.int64) - np.isin(codes, _CLOSE)
    return int(np.max(np.cumsum(step), initial=0))


_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.S)
_OPEN, _CLOSE = np.frombuffer(b"[{", np.uint8), np.frombuffer(b"]}", np.uint8)
