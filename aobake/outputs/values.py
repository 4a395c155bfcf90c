"""One file's values of one quantity: ``read(path, quantity)``, the one way to read a bake
file (aobake's or another tool's) for its values, on the reader the format registry lists
beside the format's writer (``aobake.outputs.registry``).

Per vertex (``.npz``, ``.ply``, ``.glb``) a file gives (n,) values with the positions,
normals and faces it holds; per texel or pixel (``.exr``, ``.png``, ``.tif``) (H, W) values
with the coverage where it says which texels it covers.  ``aobake compare`` and
``--method file`` read through here.
"""

from __future__ import annotations

import logging
import os
import struct
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aobake.errors import InputError
from aobake.outputs.registry import reader_for, suffixes
from aobake.outputs.table import Table, Unreadable
from aobake.quantities import QUANTITIES

log = logging.getLogger(__name__)

VERTEX_SUFFIXES = suffixes("vertices")  # .npz .ply .glb
TEXEL_SUFFIXES = tuple(s for s in suffixes("texels") if s not in VERTEX_SUFFIXES)  # .exr .png .tif


@dataclass
class Values:
    """One file's values of a quantity.

    target : 'vertices' | 'texels'
    value : (n,) float64 per vertex | (H, W) float64 per texel
    stderr : same shape, the file's standard error of ``value``, or None
    positions, normals : (n, 3) float64 or None (texels: None)
    faces : (f, 3) int64 or None
    mask : (H, W) bool texels the file covers, or None (no coverage: per vertex, or an image
      without a coverage channel)
    metadata : the aobake metadata the file carries ({} for another tool's file)
    key : the array / property / attribute / channel the value was read from
    warnings : what the reader could not honour (e.g. a GLB's node transforms)
    notes : what was assumed to read it (grey vertex colours taken as the quantity)
    columns : every channel of a camera view's image (name -> (H, W)), its G-buffer; None
      for other files
    """

    path: Path
    target: str
    value: np.ndarray
    stderr: np.ndarray | None = None
    positions: np.ndarray | None = None
    normals: np.ndarray | None = None
    faces: np.ndarray | None = None
    mask: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)
    key: str = ""
    warnings: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    columns: dict | None = None


def target_of(path: Path) -> str:
    """'vertices' | 'texels' by the suffix; InputError for a format no reader is listed for."""
    suffix = path.suffix.lower()
    if suffix in VERTEX_SUFFIXES:
        return "vertices"
    if suffix in TEXEL_SUFFIXES:
        return "texels"
    raise InputError(f"{path}: unsupported format {suffix or '(none)'!r}; aobake reads "
                     f"{', '.join(VERTEX_SUFFIXES)} (per vertex) and {', '.join(TEXEL_SUFFIXES)} "
                     "(per texel)")


def file_path(path, role: str = "file", who: str = "read") -> Path:
    """``path`` as a Path; InputError ("WHO: the ROLE must be a file path ...") for what is no
    file path (None, a number, a dict, bytes, a result object: a reader reads files)."""
    if isinstance(path, (str, os.PathLike)) and not isinstance(path, bytes):
        path = os.fspath(path)
        if isinstance(path, str) and path:
            return Path(path)
    hint = (" (write it with aobake.write first)"
            if type(path).__name__.endswith("Result") else "")
    raise InputError(f"{who}: the {role} must be a file path, got "
                     f"{type(path).__name__}{hint}")


def read(path, quantity: str = "ao", *, key: str | None = None, role: str = "reference") -> Values:
    """Read ``quantity`` (and its stderr, positions, coverage where the file has them) from an
    NPZ, PLY, GLB, EXR, PNG or TIFF file.

    key : the name of the array / property / attribute / channel holding it (default:
    aobake's name for it); role : 'reference' | 'candidate' (for the messages; a candidate's
    grey vertex colours are read as the quantity when it has no column of that name).
    Raises InputError('FILE: problem').
    """
    path = file_path(path, role)
    target = target_of(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, not a {path.suffix} file")
    if not os.access(path, os.R_OK):
        raise InputError(f"{path}: permission denied")
    suffix = path.suffix.lower()
    try:
        table = reader_for(path)(path)
    except InputError:
        raise
    except MemoryError:  # the readers bound what they make by the file; this is the last net
        raise InputError(f"{path}: cannot read as {suffix[1:].upper()}: it needs more memory "
                         "than this machine has") from None
    except (Unreadable, ValueError, LookupError, TypeError, AttributeError, ArithmeticError,
            EOFError, OSError, struct.error, zipfile.BadZipFile, zlib.error,
            RecursionError) as exc:
        reason = f"no {exc}" if isinstance(exc, KeyError) else \
            " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(f"{path}: cannot read as {suffix[1:].upper()}: {reason}") from None
    values = pick(path, table, quantity, key, role, target)
    values.warnings = [f"{path}: {text}" for text in table.warnings]
    for text in values.warnings:
        log.warning("%s", text)
    for text in values.notes:
        log.info("%s", text)
    log.debug("%s: %s from %r, %s", path, quantity, values.key, values.value.shape)
    return values


def pick(path: Path, table: Table, quantity: str, key, role: str, target: str) -> Values:
    """The quantity's column (``key``, else its aobake name) and, with aobake's names, its stderr."""
    q = QUANTITIES[quantity]
    standard = getattr(q.value, table.naming)
    standard = standard[0] if isinstance(standard, tuple) else standard
    columns = table.columns
    mask, notes = None, []
    name = key if key is not None else standard
    if key is None and standard not in columns and target == "texels":
        name = _image_channel(path, table, quantity)
    grey = None
    if key is None and standard not in columns and target == "vertices" and role == "candidate":
        grey = _grey_colour(columns, table.naming)
        if grey is not None and grey[1]:
            name = grey[0]
            notes.append(f"{path}: has no {standard!r}: its grey vertex colours "
                         f"({_COLOUR_NAMES[table.naming]}, equal) are read as {quantity} "
                         "(white = 1)")
    if name not in columns:
        have = ", ".join(sorted(columns)) or "nothing"
        hint = "; name the candidate's with --candidate-key NAME" if role == "candidate" else ""
        what = {"name": "array", "ply": "vertex property", "gltf": "vertex attribute",
                "exr": "channel"}[table.naming]
        extra = ""
        if table.naming == "gltf" and "TEXCOORD_0" in columns:
            extra = " (a lightmap GLB's AO is a texture: compare its .exr or .png)"
        if grey is not None:
            extra += " (its vertex colours are not grey: R, G and B differ)"
        raise InputError(f"{path}: no {what} {name!r} (it has {have}){extra}{hint}")
    value = _scalar(path, name, columns[name], target)
    stderr = None
    if name == standard:  # aobake's own names: its stderr sits beside it
        error_name = getattr(q.error, table.naming)
        error_name = error_name[0] if isinstance(error_name, tuple) else error_name
    else:  # another channel of aobake's (a view's ao_unbounded): NAME_stderr beside it
        error_name = f"{name}_stderr" if table.metadata else None
    if error_name is not None:
        if error_name in columns:
            stderr = _scalar(path, error_name, columns[error_name], target)
            if stderr.shape != value.shape:
                raise InputError(f"{path}: {error_name!r} is {stderr.shape}, {name!r} "
                                 f"{value.shape}: one standard error per value")
    if target == "texels":
        mask = _coverage(table)
    else:
        n = len(value)
        for label, array in (("positions", table.positions), ("normals", table.normals)):
            if array is not None and array.shape != (n, 3):
                raise InputError(f"{path}: {label} are {array.shape}, expected ({n}, 3)")
            if array is not None and not np.isfinite(array).all():
                bad = int(np.count_nonzero(~np.isfinite(array).all(axis=1)))
                raise InputError(f"{path}: {bad} of its {n} vertex {label} are not finite")
        if table.faces is not None and len(table.faces) and \
                (table.faces.min() < 0 or table.faces.max() >= n):
            raise InputError(f"{path}: faces index vertices {table.faces.min()}.."
                             f"{table.faces.max()}, but there are {n}")
    view = target == "texels" and isinstance(table.metadata.get("camera"), dict)
    return Values(path, target, value, stderr, table.positions, table.normals, table.faces, mask,
                  table.metadata, name, notes=notes, columns=columns if view else None)


#: each format's names of a vertex colour (PLY properties, the glTF attribute)
_COLOUR_NAMES = {"ply": "red, green, blue", "gltf": "COLOR_0"}


def _grey_colour(columns, naming: str):
    """(column, grey) of a per-vertex colour another tool wrote (trimesh's PLY red/green/
    blue, a glTF COLOR_0): grey when R, G and B agree at every vertex.  None without one."""
    if naming == "ply" and {"red", "green", "blue"} <= set(columns):
        grey = np.array_equal(columns["red"], columns["green"]) and \
            np.array_equal(columns["red"], columns["blue"])
        return "red", grey
    if naming == "gltf" and "COLOR_0" in columns:
        colour = np.asarray(columns["COLOR_0"])
        grey = colour.ndim == 2 and colour.shape[1] in (3, 4) and \
            np.array_equal(colour[:, 0], colour[:, 1]) and \
            np.array_equal(colour[:, 0], colour[:, 2])
        return "COLOR_0", grey
    return None


def _image_channel(path: Path, table: Table, quantity: str) -> str:
    """The channel of an image without one named after the quantity: an aobake PNG/TIFF's R
    (its metadata says which map it is), else the only channel, else R of a grey image."""
    columns, meta = table.columns, table.metadata
    if "map" in meta:
        if meta["map"] != quantity:
            raise InputError(f"{path}: holds {meta['map']}, not {quantity}")
        return "R"
    names = list(columns)
    if len(names) == 1:
        return names[0]
    if {"R", "G", "B"} <= set(names) and np.array_equal(columns["R"], columns["G"]) \
            and np.array_equal(columns["R"], columns["B"]):
        return "R"
    return QUANTITIES[quantity].value.exr[0]  # not there: pick names what there is


def _coverage(table: Table) -> np.ndarray | None:
    """(H, W) bool texels an aobake image covers: its coverage channel (> 0), else ray counts
    (> 0), else an aobake PNG/TIFF's alpha (the coverage, quantised); None for other files."""
    columns = table.columns
    if "coverage" in columns:
        return columns["coverage"] > 0
    if "rays" in columns:
        return columns["rays"] > 0
    if "map" in table.metadata and "A" in columns:
        return columns["A"] > 0
    return None


def _scalar(path: Path, name: str, array, target: str) -> np.ndarray:
    """(H, W) float64 from a channel, (n,) float64 from a per-vertex column: (n, 1) squeezed,
    an RGB(A) colour whose R, G, B agree gives R (aobake's grey COLOR_0), other vectors refused."""
    array = np.asarray(array)
    if array.dtype.kind not in "biuf":
        raise InputError(f"{path}: {name!r} holds {array.dtype} values, not numbers")
    if target == "vertices" and array.ndim == 2:
        grey = array.shape[1] in (3, 4) and np.array_equal(array[:, 0], array[:, 1]) \
            and np.array_equal(array[:, 0], array[:, 2])
        if array.shape[1] != 1 and not grey:
            raise InputError(f"{path}: {name!r} has {array.shape[1]} components per vertex; "
                             "compare needs one number per vertex")
        array = array[:, 0]
    if array.ndim != (2 if target == "texels" else 1):
        raise InputError(f"{path}: {name!r} is {array.shape}, not one number per "
                         f"{'texel' if target == 'texels' else 'vertex'}")
    return array.astype(np.float64)
