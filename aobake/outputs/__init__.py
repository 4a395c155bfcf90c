"""Writing a bake's files, and reading them: ``write(result, path, ...)`` gives a Python user
exactly the files the CLI writes (the CLI calls it for every output); ``read(path,
quantity)`` is the one way to read one quantity back from a bake file (aobake's or another
tool's: ``aobake compare`` and ``--method file`` read through it).

The format is chosen by extension from ``aobake.outputs.registry.WRITERS``, which lists each
format's reader beside its writer.  Every output carries the conventions and configuration
in its metadata, and is written atomically (temporary file + rename).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aobake.errors import OutputError, UsageError
from aobake.outputs.registry import (MESH_OUTPUTS, WRITERS, WriteOptions, default_target,
                                     suffixes, writer_for)
from aobake.outputs.values import Values, read

__all__ = ["MESH_OUTPUTS", "Outputs", "Values", "WRITERS", "WriteOptions", "default_target",
           "metadata", "plan", "read", "write", "write_vertices"]


@dataclass(frozen=True)
class Outputs:
    """The files one bake will write: out, mesh_out (lightmaps with a new atlas, or when
    asked) and report (or None), checked before any work."""

    out: Path
    target: str
    mesh_out: Path | None
    mesh_out_given: bool
    report: Path | None
    #: a view's JSON side file (camera and conventions): <out stem>.camera.json
    camera: Path | None = None


def plan(out, target: str | None = None, *, mesh=None, mesh_out=None, report=None,
         quantities=None, inputs=(), orm: bool = False, keep_distances: bool = False,
         denoise: bool = False, half: bool = False, bit_depth: int = 8,
         r_only: bool = False, mesh_name: str = "the input mesh") -> Outputs:
    """Resolve and check a bake's output paths before baking (fail before any work).

    target : 'vertices' | 'texels' | 'view' | None (from the extension; texels with
    ``orm``); mesh : the input path, which no output may overwrite (``mesh_name``: what
    a refusal calls it, e.g. "the input bake" for ``aobake refit``); inputs : the other
    files the bake reads (a dict flag -> path, or paths), none of which an output may
    overwrite either; quantities : what will be baked (an image needs ao or obscurance);
    keep_distances : the bake keeps its rays' distances (only .npz holds them); denoise :
    the lightmap has denoised channels (only .exr holds them beside the raw ones); half,
    bit_depth, r_only : how an image is stored (each refused where the output is not such
    an image, as a setting the writer would silently not read).  Raises OutputError (or
    UsageError) naming the path and the problem.
    """
    out = Path(out)
    # the extension picks the output, --orm included: a .glb is per vertex unless the
    # target says texels (an ORM .glb without it would bake what the user did not name)
    target = target or default_target(out)
    if orm and out.suffix.lower() not in suffixes("texels"):
        raise UsageError(f"{out}: --orm packs a lightmap: write one of "
                          f"{', '.join(suffixes('texels'))}")
    writer_for(out, target)  # the format exists for this target
    suffix = out.suffix.lower()
    image = target in ("texels", "view")
    if half and not (image and suffix == ".exr"):
        raise UsageError(f"{out}: --half stores an EXR image's channels as half floats: not "
                         f"a {target} {suffix or 'suffix-less'} output")
    if int(bit_depth) != 8 and not (image and suffix in (".png", ".tif", ".tiff")):
        raise UsageError(f"{out}: --bit-depth is a PNG or TIFF image's: not a {target} "
                         f"{suffix or 'suffix-less'} output")
    if r_only and not (target == "texels" and suffix in (".png", ".tif", ".tiff")):
        raise UsageError(f"{out}: --r-only stores a PNG or TIFF lightmap's AO in R only: not "
                         f"a {target} {suffix or 'suffix-less'} output")
    if keep_distances and out.suffix.lower() != ".npz":
        raise UsageError(f"{out}: --keep-distances needs an .npz output (only it holds the "
                         f"ray distances; a {out.suffix or 'suffix-less'} file would drop them)")
    if denoise and (target != "texels" or out.suffix.lower() != ".exr"):
        # the denoised map goes beside the raw one, never instead: only EXR has the channels
        raise UsageError(f"{out}: --denoise adds channels beside the raw ones: it needs an "
                         ".exr lightmap output")
    if orm and target != "texels":
        hint = " (add --target texels for a lightmap .glb)" if out.suffix.lower() == ".glb" \
            else ""
        raise UsageError(f"{out}: --orm packs a lightmap (--target texels), not a {target} "
                         f"bake{hint}")
    if orm and out.suffix.lower() in (".png", ".tif", ".tiff") and quantities is not None \
            and "ao" not in quantities and "obscurance" not in quantities:
        raise OutputError(f"{out}: an ORM map's R is ao or obscurance; add -q ao")
    if target in ("texels", "view") and quantities is not None \
            and out.suffix.lower() != ".exr" \
            and not {"ao", "obscurance"} & set(quantities):
        raise OutputError(f"{out}: a {out.suffix} lightmap holds ao or obscurance; add -q ao "
                          "(or write .exr, which holds every channel)")
    given = mesh_out is not None
    if target == "texels":
        if given and Path(mesh_out).suffix.lower() not in MESH_OUTPUTS:
            raise OutputError(f"{mesh_out}: unsupported --mesh-out format; use "
                              f"{' or '.join(MESH_OUTPUTS)}")
        if mesh_out is None and out.suffix.lower() != ".glb":
            mesh_out = out.with_suffix(".obj")  # beside --out, as <stem>.obj
    else:
        mesh_out = None
    mesh_out = None if mesh_out is None else Path(mesh_out)
    report = None if report is None else Path(report)
    mesh = None if mesh is None or not isinstance(mesh, (str, os.PathLike)) else Path(mesh)
    camera = out.with_name(out.stem + ".camera.json") if target == "view" else None
    roles = [("--out", out), ("--mesh-out" if given else "the default --mesh-out (<out>.obj)",
                              mesh_out), ("--report", report),
             ("the camera file (<out>.camera.json)", camera)]
    seen = {}
    if mesh is not None:
        seen[mesh.resolve()] = mesh_name
    named = inputs.items() if isinstance(inputs, Mapping) else (("an input", p) for p in inputs)
    for flag, other in named:
        if isinstance(other, (str, os.PathLike)):
            seen.setdefault(Path(other).resolve(), f"the input {flag}" if flag.startswith("-")
                            else flag if flag.startswith("the ") else "the input mesh")
    for role, path in roles:
        if path is None:
            continue
        if not path.parent.resolve().is_dir():
            raise OutputError(f"{path}: directory {path.parent} does not exist")
        if path.is_dir():
            raise OutputError(f"{path}: is a directory; {role} needs a file name")
        where = path.resolve()  # symlinks and .. resolved: one file, one role
        if where in seen:
            hint = (" (choose another with --mesh-out PATH)" if "default" in role else "")
            what = "overwrite " + seen[where] if seen[where].startswith("the input") else \
                f"write {role} over {seen[where]}"
            raise OutputError(f"{path}: refusing to {what}: every output needs its own file"
                              f"{hint}")
        seen[where] = role
    return Outputs(out, target, mesh_out, given, report, camera)


def metadata(result) -> dict:
    """The metadata every output of ``result`` carries: conventions, config, parameters,
    versions (and the texture statistics of a lightmap)."""
    report = result.report
    meta = {"conventions": report["conventions"], "config": report["config"],
            "parameters": report["parameters"], "versions": report["versions"]}
    for section in ("texture", "camera", "truths"):
        if section in report:
            meta[section] = report[section]
    return meta


def write(result, out, *, mesh_out=None, report=None, half: bool = False, bit_depth: int = 8,
          r_only: bool = False, mesh=None, orm: bool = False, orm_from=None) -> list[Path]:
    """Write ``result`` (BakeResult or TexelResult) to ``out``, as the CLI does.

    mesh_out : where the mesh of a lightmap's new atlas goes (.obj or .glb; default
    ``<out>.obj`` when the atlas is new; given explicitly it is always written);
    report : path of the JSON report (with the list of files written); half, bit_depth,
    r_only, orm, orm_from : see :class:`WriteOptions` (``orm_from`` implies ``orm``); mesh :
    the input path (never overwritten).
    Returns the paths written, ``out`` first.
    """
    from aobake.outputs.atomic import transaction
    from aobake.outputs.strictjson import write_report
    from aobake.outputs.texture import prepare_atlas_mesh

    _check_write_arguments(result, out, mesh_out, report, half, bit_depth, r_only)
    orm = orm or orm_from is not None
    target = result.target  # each result says what made it: no guessing from its attributes
    config = result.report.get("config", {}) if isinstance(result.report, dict) else {}
    from aobake.settings import INPUT_FILES

    read = {flag: config.get(name) for name, flag in INPUT_FILES.items()}
    read["--orm-from"] = orm_from
    where = plan(out, target, mesh=mesh, mesh_out=mesh_out, report=report, orm=orm,
                 half=half, bit_depth=bit_depth, r_only=r_only,
                 inputs={k: v for k, v in read.items() if v is not None},
                 # a bake asked to keep its distances (a refit keeps them for another
                 # refit, and may be written to any format: ``aobake refit``'s help)
                 keep_distances=bool(getattr(result, "kept", None))
                 and "refit" not in result.report,
                 denoise=bool(config.get("denoise")),
                 mesh_name="the input bake" if "refit" in (result.report or {})
                 else "the input mesh")
    options = WriteOptions(half=half, bit_depth=int(bit_depth), r_only=r_only, orm=orm,
                           orm_from=None if orm_from is None else str(orm_from))
    meta = metadata(result)
    written = [where.out]
    # One transaction: the files appear together once all are written, or none does.
    import time

    clock = time.perf_counter()
    if where.mesh_out is not None and not where.mesh_out_given \
            and getattr(getattr(result, "atlas", None), "instances", None) is not None:
        # a set's atlas: its mesh is the set, each mesh once (a GLB of instances), not every
        # instance flattened into an OBJ (which grows with the copies)
        where = _set_mesh(where, target, mesh, orm,
                          {k: v for k, v in read.items() if v is not None})
    write_mesh = None  # the atlas mesh's writer, its text formatted while `out` is written
    if where.mesh_out is not None and (result.atlas.new or where.mesh_out_given):
        write_mesh = prepare_atlas_mesh(where.mesh_out, result, meta, options.orm,
                                        options.orm_from)
    with transaction():
        with _naming(where.out):
            writer_for(where.out, target).write(where.out, result, meta, options)
        if write_mesh is not None:
            with _naming(where.mesh_out):
                write_mesh()
            written.append(where.mesh_out)
        if where.camera is not None:  # a view: its camera and conventions beside the image
            from aobake.outputs.strictjson import write_report

            with _naming(where.camera):
                write_report(where.camera, {"camera": meta["camera"],
                                            "conventions": meta["conventions"],
                                            "image": where.out.name})
            written.append(where.camera)
        if where.report is not None:
            full = dict(result.report, outputs=[str(p) for p in written])
            # the outputs before the report (their renames come with the transaction's end)
            full["timings"] = {**full.get("timings", {}),
                               "write_s": time.perf_counter() - clock}
            with _naming(where.report):
                write_report(where.report, full)
    return written


def _set_mesh(where: Outputs, target: str, mesh, orm: bool, inputs: dict) -> Outputs:
    """``where`` with the default mesh of a set's lightmap: ``<out stem>.glb`` (or, where that
    is taken by an input or another output, ``<out stem>.set.glb``), the set's instances
    each reading its region (``aobake.outputs.glb.write_textured_instances``); the OBJ of
    ``plan`` where neither can be written."""
    from dataclasses import replace

    for name in (where.out.stem + ".glb", where.out.stem + ".set.glb"):
        candidate = where.out.with_name(name)
        try:
            plan(where.out, target, mesh=mesh, mesh_out=candidate, report=where.report,
                 orm=orm, inputs=inputs)
        except OutputError:
            continue
        return replace(where, mesh_out=candidate)
    return where


def _check_write_arguments(result, out, mesh_out, report, half, bit_depth, r_only) -> None:
    """InputError naming the argument for anything ``write`` cannot take."""
    from aobake.errors import InputError
    from aobake.records import BakeResult, ImageResult

    if not isinstance(result, (BakeResult, ImageResult)):
        raise InputError(f"write: result must be a bake's result (BakeResult, TexelResult or "
                         f"ViewResult), got {type(result).__name__}")
    for name, path in (("out", out), ("mesh_out", mesh_out), ("report", report)):
        if path is None and name == "out" or path is not None and \
                not isinstance(path, (str, os.PathLike)):
            raise InputError(f"write: {name} must be a file path, got {path!r}")
    for name, flag in (("half", half), ("r_only", r_only)):
        if not isinstance(flag, (bool, np.bool_)):
            raise InputError(f"write: {name} must be True or False, got {flag!r}")
    if isinstance(bit_depth, bool) or bit_depth not in (8, 16, "8", "16"):
        raise InputError(f"write: bit_depth must be 8 or 16, got {bit_depth!r}")


@contextlib.contextmanager
def _naming(path):
    """An operating-system failure while writing ``path`` (a full disk, a lost mount) becomes
    an OutputError naming the file and the OS's reason (the CLI's one-line message)."""
    try:
        yield
    except OutputError:
        raise
    except OSError as exc:
        reason = (exc.strerror or str(exc)).lower()
        raise OutputError(f"{path}: {reason}") from None


def write_vertices(path: str | os.PathLike, positions: np.ndarray, faces: np.ndarray,
                   fields: Mapping[str, np.ndarray], metadata: Mapping | None) -> None:
    """Write per-vertex arrays with the writer for ``path``'s suffix (no result needed).

    positions : (n, 3) float, faces : (f, 3) int, fields : per-vertex arrays named as in
    ``aobake.quantities.FIELDS``, metadata : JSON-serialisable dict.
    Raises ``OutputError`` for an unsupported suffix, ``ValueError`` for bad arrays.
    """
    import importlib

    suffix = writer_for(path, "vertices").suffix
    module = importlib.import_module(f"aobake.outputs.{suffix[1:]}")
    module.write(path, positions, faces, fields, metadata)
