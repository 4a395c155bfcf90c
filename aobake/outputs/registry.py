"""Output formats: (file extension, result kind) -> writer and reader, the one table the
CLI, ``aobake.write``, ``aobake.outputs.read`` and the README's output table read.

Two kinds of result (``aobake.records``): ``points`` (BakeResult: per vertex or query
point) and ``image`` (ImageResult: lightmap texels, TexelResult, and camera pixels,
ViewResult, share it).  A writer serves one kind, and the targets listed in its
``targets`` (a lightmap GLB needs the atlas a view does not have).
A writer is ``write(path, result, metadata, options)`` with ``metadata`` the JSON dict
every output carries and ``options`` the :class:`WriteOptions`; it writes
atomically (nothing, complete or partial, is left at ``path`` on failure).

Beside each writer, its reader (meshio's ``register_format(name, extensions, reader,
writers)``): ``read(path) -> aobake.outputs.table.Table``, the format module's own ``read``,
so a format aobake writes is one it reads, and no other package reaches into a format
module to read a file.  A new format is one module with both functions plus one line in
``WRITERS``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from aobake.errors import InputError, OutputError
from aobake.outputs.texture import ORM_CHANNELS, write_texture
from aobake.quantities import FIELDS


@dataclass(frozen=True)
class WriteOptions:
    """half : EXR half floats; bit_depth : PNG/TIFF 8 or 16; r_only : PNG/TIFF AO in R only;
    orm : a lightmap packed as ORM (``aobake.outputs.orm``); orm_from : the texture whose G
    and B it copies (None: the input's metallicRoughnessTexture, else "empty")."""

    half: bool = False
    bit_depth: int = 8
    r_only: bool = False
    orm: bool = False
    orm_from: str | None = None


@dataclass(frozen=True)
class Writer:
    """suffix : lower-case extension, kind : 'points' | 'image' (the result kind it writes),
    write : the function, read : its reader (path -> ``Table``), what / contents : the
    README's output table row, targets : the targets whose results it writes ('vertices'
    and 'points' make points; 'texels' and 'view' make images)."""

    suffix: str
    kind: str
    write: Callable
    read: Callable
    what: str
    contents: Callable[[], str]
    targets: tuple = ()

    @property
    def target(self) -> str:
        """The CLI target this format implies (the first of ``targets``)."""
        return self.targets[0]


def _vertex(module_name: str):
    def write(path, result, metadata, options):
        import importlib

        module = importlib.import_module(f"aobake.outputs.{module_name}")
        # query points (bake_points) have no faces: written as a point set
        faces = result.faces if result.faces is not None else np.zeros((0, 3), np.int64)
        if result.faces is None and module_name == "glb":
            raise OutputError(f"{path}: query points have no faces, and a .glb mesh needs "
                              "them: write .npz or .ply (a point set)")
        if module_name == "npz":  # the one format that holds kept ray distances
            module.write(path, result.positions, faces, result.fields(), metadata,
                         kept=getattr(result, "kept", None))
        else:
            module.write(path, result.positions, faces, result.fields(), metadata)
    return write


def _reader(module_name: str):
    """The ``read`` of ``aobake.outputs.<module_name>``, imported when first called (as the
    vertex writers are: a bake that writes one format loads no other)."""
    def read(path):
        import importlib

        return importlib.import_module(f"aobake.outputs.{module_name}").read(path)
    read.__qualname__ = f"{module_name}.read"
    return read


def _texture(path, result, metadata, options):
    write_texture(path, result, metadata, half=options.half, bit_depth=options.bit_depth,
                  r_only=options.r_only, orm=options.orm, orm_from=options.orm_from)


def _names(names) -> str:
    return ", ".join(f"`{n}`" for n in names)


def _npz_contents() -> str:
    return (f"{_names(['positions', 'faces', *FIELDS])} (as computed; `rays` int32, "
            "estimates float32; with `--from` the projection: `missed`, `back_hit` uint8, "
            "`projection_distance` float32, 0 where missed), `metadata` (JSON)")


def _ply_contents() -> str:
    props = [p for f in FIELDS.values() for p in f.ply]
    return (f"the mesh (positions float64) with properties {_names(props)} (float32; `rays`, "
            "`missed`, `back_hit` int32; the last three with `--from`) and 8-bit colours "
            "`round(255 * ao)`")


def _glb_contents() -> str:
    attrs = [f.gltf for f in FIELDS.values() if f.gltf]
    return f"the mesh with `COLOR_0` = AO (linear) and custom attributes {_names(attrs)}"


def _exr_contents() -> str:
    channels = [c for f in FIELDS.values() for c in f.exr]
    denoised = [f"{name}{suffix}" for name in ("ao", "obscurance")
                for suffix in ("_denoised", "_denoised_stderr")]
    return (f"float32 (`--half`) channels {_names([*channels, 'coverage'])} (with `--denoise` "
            f"also {_names(denoised)}; with `--orm` also {_names(ORM_CHANNELS)}); "
            "configuration in the header")


#: every output format, in the README's order
_POINTS = ("vertices", "points")
_IMAGES = ("texels", "view")

_IMAGE = _reader("image")

WRITERS = (
    Writer(".npz", "points", _vertex("npz"), _reader("npz"), "per vertex", _npz_contents,
           _POINTS),
    Writer(".ply", "points", _vertex("ply"), _reader("ply"), "per vertex", _ply_contents,
           _POINTS),
    Writer(".glb", "points", _vertex("glb"), _reader("glb"), "per vertex", _glb_contents,
           _POINTS),
    Writer(".exr", "image", _texture, _IMAGE, "lightmap", _exr_contents, _IMAGES),
    Writer(".png", "image", _texture, _IMAGE, "lightmap",
           lambda: "AO in RGB (`--r-only`: R), coverage in alpha, 8/16 bit (`--bit-depth`); "
                   "`--orm`: RGB = AO, roughness, metalness",
           _IMAGES),
    Writer(".tif", "image", _texture, _IMAGE, "lightmap", lambda: "as `.png`", _IMAGES),
    Writer(".tiff", "image", _texture, _IMAGE, "lightmap", lambda: "as `.png`", _IMAGES),
    # read as what its vertices carry (the occlusion texture is the same map as the .png)
    Writer(".glb", "image", _texture, _reader("glb"), "lightmap",
           lambda: "the atlas mesh with the AO map as `occlusionTexture` of every input "
                   "material (each keeps its base colour; one primitive per material); "
                   "`--uv-set N`: on `TEXCOORD_N`, the other sets kept; `--orm`: one ORM "
                   "image as `occlusionTexture` and `metallicRoughnessTexture`",
           ("texels",)),
)

#: formats the mesh of a new atlas can be written in (``--mesh-out``)
MESH_OUTPUTS = (".obj", ".glb")


def suffixes(target: str) -> tuple:
    """The extensions a target's result can be written as."""
    return tuple(w.suffix for w in WRITERS if target in w.targets)


def default_target(path) -> str:
    """The target an output extension implies: vertices unless only a lightmap can be it."""
    suffix = Path(path).suffix.lower()
    return "vertices" if suffix in suffixes("vertices") else "texels"


def writer_for(path, target: str) -> Writer:
    """The writer of ``path``'s (case-insensitive) extension for ``target``; OutputError if none."""
    suffix = Path(path).suffix.lower()
    for writer in WRITERS:
        if writer.suffix == suffix and target in writer.targets:
            return writer
    if target == "view":
        raise OutputError(f"{path}: unsupported output format {suffix or '(none)'!r} for a "
                          f"view; use one of {', '.join(suffixes('view'))}")
    kind = "a vertex bake" if target in _POINTS else "a lightmap"
    raise OutputError(f"{path}: unsupported output format {suffix or '(none)'!r} for {kind} "
                      f"(--target {target}); use one of {', '.join(suffixes(target))}; "
                      f"formats: per vertex {', '.join(suffixes('vertices'))}, lightmap "
                      f"{', '.join(suffixes('texels'))} (.glb lightmap with --target texels)")


def reader_for(path) -> Callable:
    """The reader of ``path``'s (case-insensitive) extension (path -> ``Table``): the first
    format listed with it; InputError if none."""
    suffix = Path(path).suffix.lower()
    for writer in WRITERS:
        if writer.suffix == suffix:
            return writer.read
    raise InputError(f"{path}: unsupported format {suffix or '(none)'!r}; aobake reads "
                     f"{', '.join(dict.fromkeys(w.suffix for w in WRITERS))}")


def markdown_table() -> str:
    """The README's output table, made from ``WRITERS`` (a test keeps the README equal to it)."""
    rows = ["| `--out` | what | contents |", "|---|---|---|"]
    for writer in WRITERS:
        target = " + `--target texels`" if writer.suffix in suffixes("vertices") and \
            writer.kind == "image" else ""
        rows.append(f"| `{writer.suffix}`{target} | {writer.what} | {writer.contents()} |")
    return "\n".join(rows)
