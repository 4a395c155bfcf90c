"""One file's values of one quantity: ``read(path, quantity)``, the one way to read a bake
file (aobake's or another tool's) for its values, on the reader the format registry lists
beside the format's writer (``aobake.outputs.registry``).

Per vertex (``.npz``, ``.ply``, ``.glb``) a file gives (n,) values with the positions,
normals and faces it holds; per texel or pixel (``.exr``, ``.png``, ``.tif``) (H, W) values
with the coverage where it says which texels it covers.  ``aobake compare`` and
``--method file`` read through here.

An image's values are linearised as its colour tags say (``aobake.outputs.image.Transfer``:
an sRGB or gamma PNG, a TIFF with an ICC profile); an 8/16-bit PNG or TIFF without tags
holds display-referred values by convention and is refused unless the caller states its
transfer (``transfer='srgb' | 'linear'``).  aobake's own images hold linear values (its
PNGs say so with gAMA 1.0; its metadata says it is aobake's).  Channels of a layered or
multi-part image (``layer.pass.channel``, Blender's ``ViewLayer.AO.R``) are found by their
full name, by a pass's name (``ViewLayer.AO``: its R, X or Y channel) or by a unique end
of the name (``AO.R``); without a name, Blender's AO pass is found by its name.
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
    transfer : how the stored values were turned into ``value``: 'linear' (as stored),
      'srgb', 'gamma 2.2', 'ICC curve' (``aobake.outputs.image.Transfer.name``)
    alpha : (H, W) float64 the alpha channel ``value`` (and ``stderr``) were divided by, the
      file's values being associated with it (multiplied by coverage), or None
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
    transfer: str = "linear"
    #: the alpha channel ``value`` was divided by (associated alpha), or None
    alpha: np.ndarray | None = None


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


#: how an image's values relate to its alpha (``read``'s ``alpha``)
ALPHAS = {
    "auto": "associated where another tool's EXR has an alpha channel for the value "
            "(OpenEXR's convention: colour multiplied by alpha), else straight",
    "associated": "the values are multiplied by the alpha (a renderer's AO times coverage): "
                  "divided by it, pixels of alpha 0 not compared",
    "straight": "the values are not multiplied by the alpha (aobake's own, PNG's convention)",
}


def read(path, quantity: str = "ao", *, key: str | None = None, role: str = "reference",
         transfer: str | None = None, alpha: str = "auto",
         alpha_key: str | None = None) -> Values:
    """Read ``quantity`` (and its stderr, positions, coverage where the file has them) from an
    NPZ, PLY, GLB, EXR, PNG or TIFF file.

    key : the name of the array / property / attribute / channel holding it (default:
    aobake's name for it; in a layered image also a pass's name or a unique end of a
    channel's name); role : 'reference' | 'candidate' (for the messages; a candidate's grey
    vertex colours are read as the quantity when it has no column of that name);
    transfer : None (as the file's colour tags say; an untagged 8/16-bit PNG or TIFF is
    refused) | 'linear' | 'srgb' (how the values are encoded, whatever the tags say: a
    warning when they say otherwise) (``aobake.outputs.image.TRANSFERS``);
    alpha : ``ALPHAS``: whether an image's values are associated with (multiplied by) an
    alpha channel, which ``alpha_key`` names (default: the value's layer's ``A``, Blender's
    ``<view layer>.Combined.A`` for a render pass, or a lone ``A``); associated values are
    divided by it (``Values.alpha``).
    Raises InputError('FILE: problem').
    """
    from aobake.outputs.image import TRANSFERS

    if not isinstance(alpha, str) or alpha not in ALPHAS:
        raise InputError(f"alpha must be one of {tuple(ALPHAS)}, got {alpha!r}")
    if alpha_key is not None and not isinstance(alpha_key, str):
        raise InputError(f"alpha_key must be a channel name (str), got {alpha_key!r}")

    if transfer is not None and (not isinstance(transfer, str) or transfer not in TRANSFERS):
        raise InputError(f"transfer must be one of {tuple(TRANSFERS)} or None (as the file's "
                         f"tags say), got {transfer!r}")
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
    linearise(values, table, role, transfer)
    unassociate(values, table, role, alpha, alpha_key)
    for text in values.warnings:
        log.warning("%s", text)
    for text in values.notes:
        log.info("%s", text)
    log.debug("%s: %s from %r, %s", path, quantity, values.key, values.value.shape)
    return values


def pick(path: Path, table: Table, quantity: str, key, role: str, target: str) -> Values:
    """The quantity's column (``key``, else its aobake name) and its stderr (aobake's name
    for it, or ``NAME_stderr`` beside another column NAME)."""
    q = QUANTITIES[quantity]
    standard = getattr(q.value, table.naming)
    standard = standard[0] if isinstance(standard, tuple) else standard
    columns = table.columns
    mask, notes = None, []
    name = key if key is not None else standard
    if key is not None and key not in columns and target == "texels":
        name = _layered(path, columns, key, role)
    if key is None and standard not in columns and target == "texels":
        name = _image_channel(path, table, quantity, role, notes)
    grey = None
    if key is None and standard not in columns and target == "vertices" and role == "candidate":
        grey = _grey_colour(columns, table.naming)
        if grey is not None and grey[1]:
            name = grey[0]
            notes.append(f"{path}: has no {standard!r}: its grey vertex colours "
                         f"({_COLOUR_NAMES[table.naming]}, equal) are read as {quantity} "
                         "(white = 1)")
    if name not in columns:
        have = _listing(table)
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
    else:  # another column (a view's ao_unbounded, another tool's): NAME_stderr beside it
        error_name = f"{name}_stderr"
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


def _image_channel(path: Path, table: Table, quantity: str, role: str, notes: list) -> str:
    """The channel of an image without one named after the quantity: an aobake PNG/TIFF's R
    (its metadata says which map it is), else a layered channel ending in the quantity's
    name (``layer.ao``), else Blender's ambient occlusion pass (``ViewLayer.AO.R``, named
    'AO' or 'Ambient Occlusion': when there is exactly one), else the only channel (an
    alpha ``A`` beside it aside), else R of a grey image."""
    columns, meta = table.columns, table.metadata
    if "map" in meta:
        if meta["map"] != quantity:
            raise InputError(f"{path}: holds {meta['map']}, not {quantity}")
        return "R"
    standard = QUANTITIES[quantity].value.exr[0]
    ending = [name for name in columns if name.endswith("." + standard)]
    if len(ending) == 1:
        return ending[0]
    if quantity == "ao":
        passes = sorted({name.rsplit(".", 1)[0] for name in columns if "." in name
                         and name.rsplit(".", 1)[0].rsplit(".", 1)[-1].lower() in AO_PASSES})
        if len(passes) > 1:
            raise InputError(f"{path}: has {len(passes)} ambient occlusion passes "
                             f"({', '.join(passes)}): name the one to read with "
                             f"--{role}-key PASS (or one of its channels)")
        if passes:
            name = _pass_channel(path, columns, passes[0], role)
            notes.append(f"{path}: has no {standard!r} channel: its ambient occlusion pass "
                         f"{passes[0]!r} is read as ao (channel {name!r})")
            return name
    names = [name for name in columns if name != "A"]  # an alpha beside one value channel
    if len(names) == 1:
        return names[0]
    if {"R", "G", "B"} <= set(names) and np.array_equal(columns["R"], columns["G"]) \
            and np.array_equal(columns["R"], columns["B"]):
        return "R"
    return standard  # not there: pick names what there is


#: how renderers name an ambient occlusion pass (Blender: 'AO' in render results and
#: multi-part files, 'Ambient Occlusion' after the compositor's File Output node), lower case
AO_PASSES = ("ao", "ambient occlusion", "ambient_occlusion", "ambientocclusion")
#: the channel of a pass read as its value, in this order of preference (a grey pass has
#: R = G = B; Blender names some passes' channels X, Y, Z)
_PASS_CHANNELS = ("R", "X", "Y", "V", "L")


def _pass_channel(path: Path, columns, prefix: str, role: str) -> str:
    """The column read from the pass (or layer) ``prefix``: its R (X, Y, ...) channel, or its
    only one; InputError when its R, G and B differ (not grey: which one is AO?) or it has
    no channel to take."""
    members = {name[len(prefix) + 1:]: name for name in columns
               if name.startswith(prefix + ".") and "." not in name[len(prefix) + 1:]}
    for channel in _PASS_CHANNELS:
        if channel in members:
            if channel == "R" and {"G", "B"} <= set(members):
                r, g, b = (columns[members[c]] for c in "RGB")
                if not (np.array_equal(r, g) and np.array_equal(r, b)):
                    raise InputError(f"{path}: the pass {prefix!r} is not grey (its R, G and B "
                                     f"differ): name its channel with --{role}-key "
                                     f"{prefix}.R (or .G, .B)")
            return members[channel]
    if len(members) == 1:
        return next(iter(members.values()))
    raise InputError(f"{path}: the pass {prefix!r} has channels {', '.join(members) or 'none'}: "
                     f"name one with --{role}-key {prefix}.CHANNEL")


def _layered(path: Path, columns, key: str, role: str) -> str:
    """The column a key names in a layered image when it is no column's full name: a pass
    or layer (``ViewLayer.AO``: its channel by ``_pass_channel``), else the one column whose
    name ends in ``.key`` (``AO.R`` for ``ViewLayer.AO.R``); the key itself when neither
    (the caller's message lists what there is)."""
    if any(name.startswith(key + ".") for name in columns):
        return _pass_channel(path, columns, key, role)
    ending = [name for name in columns if name.endswith("." + key)]
    if len(ending) > 1:
        raise InputError(f"{path}: {len(ending)} channels end in {key!r} "
                         f"({', '.join(ending)}): name one in full with --{role}-key")
    return ending[0] if ending else key


def _listing(table: Table) -> str:
    """What a file has, for a message: its columns, by part in a multi-part image."""
    if table.parts:
        return "; ".join(f"part {part!r}: {', '.join(names)}"
                         for part, names in table.parts.items())
    return ", ".join(sorted(table.columns)) or "nothing"


def alpha_channel(columns, key: str) -> str | None:
    """The alpha channel of the channel ``key``: its layer's ``A`` (``layer.R`` ->
    ``layer.A``; ``R`` -> ``A``), else Blender's Combined pass's of its view layer
    (``ViewLayer.AO.R`` -> ``ViewLayer.Combined.A``: a render pass has no alpha of its own,
    the film's is the Combined pass's); None when the file has neither."""
    parts = key.split(".")
    names = [".".join(parts[:-1] + ["A"]) if len(parts) > 1 else "A"]
    if len(parts) >= 2:
        names.append(".".join(parts[:-2] + ["Combined", "A"]))
    return next((name for name in names if name in columns and name != key), None)


def divided_by_alpha(array: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """(H, W) float64 ``array`` divided by ``alpha`` (H, W) where alpha > 0, 0 elsewhere
    (pixels no sample saw: not compared)."""
    seen = alpha > 0
    return np.where(seen, array / np.where(seen, alpha, 1.0), 0.0)


def unassociate(values: Values, table: Table, role: str, mode: str,
                key: str | None) -> None:
    """Divide an image's values associated with an alpha (multiplied by it: a renderer's AO
    times its coverage) by that alpha, so they compare with aobake's unassociated ones (the
    mean over the part of the pixel that sees the scene); pixels of alpha 0 are masked out.

    ``mode`` 'auto': associated where another tool's EXR has an alpha for the value
    (OpenEXR's convention), straight for aobake's files and PNG/TIFF (straight by their
    convention; the image reader asks for unassociated alpha); a named ``key`` means
    associated.  'associated' without an alpha channel, or for an aobake file, is refused.
    """
    flag = f"--{role}-alpha" if role in ("reference", "candidate") else "alpha="
    if values.target != "texels" or mode == "straight":
        return
    path = values.path
    if table.metadata:  # aobake's own: unassociated, whatever is asked
        if mode == "associated" or key is not None:
            raise InputError(f"{path}: is an aobake output, whose values are not multiplied "
                             f"by its coverage; {flag} associated is for another tool's render")
        return
    columns = table.columns
    name = key if key is not None else alpha_channel(columns, values.key)
    if key is not None and key not in columns:
        raise InputError(f"{path}: no alpha channel {key!r} (it has {_listing(table)})")
    if mode == "auto" and key is None and (name is None or path.suffix.lower() != ".exr"):
        return
    if name is None:
        raise InputError(f"{path}: no alpha channel beside {values.key!r} (it has "
                         f"{_listing(table)}): name it with {flag}-key NAME")
    alpha = np.asarray(columns[name], dtype=np.float64)
    if alpha.shape != values.value.shape:
        raise InputError(f"{path}: its alpha {name!r} is {alpha.shape}, {values.key!r} "
                         f"{values.value.shape}")
    bad = ~(np.isfinite(alpha) & (alpha >= 0.0) & (alpha <= 1.0 + 1e-6))
    if bad.any():
        raise InputError(f"{path}: {int(bad.sum())} values of its alpha {name!r} are not in "
                         "[0, 1]")
    seen = alpha > 0
    values.value = divided_by_alpha(values.value, alpha)
    if values.stderr is not None:
        values.stderr = divided_by_alpha(values.stderr, alpha)
    values.mask = seen if values.mask is None else values.mask & seen
    values.alpha = alpha
    values.notes.append(f"{path}: {values.key!r} is read as associated with the alpha "
                        f"{name!r} (multiplied by coverage, OpenEXR's convention: {flag} "
                        f"straight says not) and divided by it; {int((~seen).sum())} pixels "
                        "of alpha 0 are not compared")


def linearise(values: Values, table: Table, role: str, stated: str | None) -> None:
    """Turn ``values``' value (and stderr) into linear values, as the file's tags say
    (``table.transfers``) or as ``stated``; refuse what cannot be known to be linear.

    An aobake file holds linear values whatever its tags (its metadata says it is
    aobake's; stating 'srgb' for it is refused).  A stated transfer wins over the tags (a
    warning when they say otherwise: a renderer may tag a raw view's values sRGB).  Without
    one, a display-referred file (an 8/16-bit PNG or TIFF without tags) and one whose tags
    this reader cannot invert are refused with what to do.  Per-vertex files hold numbers
    (linear) unless a transfer is stated.  A stderr is carried through the curve by its
    slope (the delta method).
    """
    from aobake.outputs.image import TRANSFERS

    path = values.path
    flag = f"--{role}-transfer" if role in ("reference", "candidate") else "transfer="
    tagged = None if table.transfers is None else table.transfers.get(values.key)
    if table.metadata:  # aobake's file: linear by aobake's convention
        if stated == "srgb":
            raise InputError(f"{path}: is an aobake output, which holds linear values; "
                             f"{flag} srgb is for files that hold sRGB-encoded ones")
        values.transfer = "linear"
        return
    if stated is not None:
        use = TRANSFERS[stated]
        if tagged is not None and tagged.kind not in (use.kind, "display"):
            says = "" if tagged.kind == "unsupported" else f" says it holds {tagged.says} values"
            values.warnings.append(f"{path}: {tagged.source}{says}; read as {use.says}, as "
                                   f"stated ({flag} {stated})")
    elif tagged is None:  # numbers, not colours
        return
    elif not tagged.known:
        say = f"{flag} srgb|linear" if flag != "transfer=" else "transfer='srgb' | 'linear'"
        python = f" (Python: {role}_transfer=)" if flag != "transfer=" else ""
        problem = (" holds display-referred values by convention (sRGB, or a view "
                   "transform's), not linear ones" if tagged.kind == "display" else "")
        raise InputError(f"{path}: {tagged.source}{problem}; compare needs linear values: "
                         "save them linear (an EXR, or a PNG tagged gAMA 1.0) or state how "
                         f"they are encoded with {say}{python}")
    else:
        use = tagged
    values.transfer = use.name
    if use.kind == "linear":
        return
    if values.stderr is not None:
        values.stderr = values.stderr * np.abs(use.slope(values.value))
    values.value = use.to_linear(values.value)
    source = "as stated" if stated is not None else f"as {tagged.source} says"
    values.notes.append(f"{path}: {values.key!r} holds {use.says} values ({source}): "
                        "linearised before comparing")


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
