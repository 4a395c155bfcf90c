"""Many assets in one process (``aobake batch``): find them, bake each, never let one stop
the others, and skip what an earlier run finished.

Assets come from mesh files, folders (searched recursively for ``scene.MESH_EXTENSIONS``),
glob patterns, or manifests (``.csv`` with a header row, or JSON lines ``.jsonl`` /
``.ndjson``): one asset per row, ``mesh`` (relative to the manifest's folder), an optional
``output`` (relative to the output folder; its extension picks the format), an optional
``target`` (vertices | texels) and any setting by its name (``rays``, ``max_distance`` or
``max-distance``, ...), which overrides the command's for that asset.

Every output stays inside the output folder: a manifest's ``output`` may not be absolute,
name ``..`` or lead through a symbolic link out of it (:func:`output_path`), so a manifest
from someone else cannot overwrite a file elsewhere.  Files are written as every bake's
are: one transaction of temporary files renamed into place (a rename replaces a link, it
never writes through it).

Resuming: beside each output goes its report, ``<output name>.report.json``, which holds
the configuration, the target, the method and the input's size and SHA-256
(``report["input"]``, with a high-to-low bake's ``source`` and ``cage``); an asset whose output files and report exist, and whose report
matches what would be baked now, is skipped (``force`` re-bakes it).
"""

from __future__ import annotations

import csv
import glob
import hashlib
import json
import logging
import os
import re
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath, PureWindowsPath

from aobake.errors import AobakeError, InputError, OutputError
from aobake.scene import MESH_EXTENSIONS

log = logging.getLogger(__name__)

#: manifest extensions: a CSV with a header row, or one JSON object per line
MANIFESTS = (".csv", ".jsonl", ".ndjson")
#: an asset whose output nothing names (no --format, no manifest column): its error's end
NO_FORMAT = "no output format: give --format"
#: where the summary goes in the output folder unless told otherwise
SUMMARY_NAME = "batch-summary.json"
#: an output's report: <output name> + this
REPORT_SUFFIX = ".report.json"
#: a manifest row's keys that are not settings
_ASSET_KEYS = ("mesh", "output", "target", "options")
#: settings that name input files (high-to-low's source and cage): read like ``mesh``, and
#: hashed with it for resuming
_PATH_SETTINGS = ("source", "cage", "ao_from")
#: bytes read at a time when hashing an input
_HASH_BLOCK = 1 << 20


@dataclass
class Asset:
    """One bake of a batch.

    mesh : the input file (None when its entry could not be read), output : the output's
    path relative to the output folder (None: not known), target : 'vertices' | 'texels' |
    None (from the output's extension), options : settings for this asset alone
    (``BakeConfig`` fields), source : the input it came from (a path, a pattern, a
    manifest's line), error : why it cannot be baked (a bad manifest row, a glob that
    matched nothing, a name taken by another asset), or None.
    """

    mesh: Path | None
    output: Path | None
    target: str | None = None
    options: dict = field(default_factory=dict)
    source: str = ""
    error: str | None = None


def output_path(out_dir, name) -> Path:
    """``out_dir / name`` when it stays inside ``out_dir``: OutputError for an absolute
    path, a ``..`` component, or a symbolic link (of a folder or of the file itself) that
    resolves outside it.  The folders on the way are made (inside ``out_dir``)."""
    text = str(name)
    if not text.strip():
        raise OutputError("an empty output name")
    if PurePosixPath(text).is_absolute() or PureWindowsPath(text).is_absolute() or \
            PureWindowsPath(text).drive:
        raise OutputError(f"{text}: an output must be a path inside the output folder, not an "
                          "absolute path")
    if ".." in re.split(r"[\\/]", text):
        raise OutputError(f"{text}: an output may not leave the output folder ('..')")
    root = Path(out_dir).resolve()
    path = Path(out_dir) / text

    def inside(candidate: Path) -> bool:
        where = candidate.resolve()  # every symbolic link on the way followed
        return where == root or root in where.parents

    if not inside(path):
        raise OutputError(f"{text}: leads out of the output folder {out_dir} through a "
                          "symbolic link")
    path.parent.mkdir(parents=True, exist_ok=True)
    if not inside(path):  # a link made meanwhile
        raise OutputError(f"{text}: leads out of the output folder {out_dir} through a "
                          "symbolic link")
    return path


def find_assets(inputs, out_dir, fmt: str | None = None, target: str | None = None) -> list:
    """The assets of ``inputs`` (paths, folders, glob patterns, manifests), in order.

    fmt : the output extension ('ply', '.exr', ...) of assets whose output is not named;
    target : 'vertices' | 'texels' | None (from each output's extension).  Files inside
    ``out_dir`` are never inputs.  Problems are assets with an ``error``, not exceptions:
    one bad input never stops the others.
    """
    suffix = None if not fmt else "." + str(fmt).lower().lstrip(".")
    root = Path(out_dir).resolve()
    assets = []
    for given in inputs:
        text = str(given)
        path = Path(text)
        if path.is_file() and path.suffix.lower() in MANIFESTS:
            assets += _manifest(path, suffix, target)
        elif path.is_dir():
            found = [p for p in sorted(path.rglob("*")) if _is_mesh(p) and not _under(p, root)]
            if not found:
                assets.append(Asset(None, None, source=text,
                                    error=f"{text}: no mesh ({', '.join(MESH_EXTENSIONS)}) in "
                                          "this folder"))
            for mesh in found:
                assets.append(_named(mesh, mesh.relative_to(path), suffix, target, text))
        elif path.is_file() or not glob.has_magic(text):
            assets.append(_named(path, Path(path.name), suffix, target, text))
        else:
            found = [Path(p) for p in sorted(glob.glob(text, recursive=True))
                     if _is_mesh(Path(p)) and not _under(Path(p), root)]
            if not found:
                assets.append(Asset(None, None, source=text,
                                    error=f"{text}: the pattern matched no mesh"))
            for mesh in found:
                assets.append(_named(mesh, Path(mesh.name), suffix, target, text))
    _refuse_shared_outputs(assets)
    return assets


def _is_mesh(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in MESH_EXTENSIONS


def _under(path: Path, root: Path) -> bool:
    where = path.resolve()
    return where == root or root in where.parents


def _named(mesh: Path, relative: Path, suffix, target, source) -> Asset:
    """An asset whose output is named after its mesh: ``relative`` with the format's
    extension."""
    if suffix is None:
        return Asset(mesh, None, target, source=source,
                     error=f"{mesh}: {NO_FORMAT}")
    return Asset(mesh, relative.with_suffix(suffix), target, source=source)


def _files(asset) -> list:
    """The files an asset writes, relative to the output folder: its output, its report
    and a lightmap's atlas mesh (``<stem>.obj``, unless the output is a .glb)."""
    from aobake.outputs.registry import default_target

    out = Path(asset.output)
    files = [out, report_path(out)]
    target = asset.target or default_target(out)
    if target == "texels" and out.suffix.lower() != ".glb":
        files.append(out.with_suffix(".obj"))
    return files


def _refuse_shared_outputs(assets) -> None:
    """A file two assets would write (an output, a report, a lightmap's atlas mesh; the
    summary's name) is the first one's; the later ones fail."""
    taken = {os.path.normcase(SUMMARY_NAME): None}
    for index, asset in enumerate(assets):
        if asset.error is not None or asset.output is None:
            continue
        keys = [os.path.normcase(os.path.normpath(str(f))) for f in _files(asset)]
        clash = next((key for key in keys if key in taken), None)
        if clash is None:
            taken.update({key: index for key in keys})
            continue
        first = None if taken[clash] is None else assets[taken[clash]]
        owner = "the batch's summary" if first is None else \
            f"{first.mesh} ({first.source})"
        asset.error = (f"{asset.output}: writes {clash}, as {owner} does; name the outputs "
                       "in a manifest")


def _manifest(path: Path, suffix, target) -> list:
    """The assets of a manifest: one per row (a row that cannot be read is an asset with
    its error)."""
    where = path.parent
    rows = []
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            if path.suffix.lower() == ".csv":
                reader = csv.DictReader(handle)
                if not reader.fieldnames or "mesh" not in [n.strip() for n in reader.fieldnames]:
                    return [Asset(None, None, source=str(path),
                                  error=f"{path}: a CSV manifest needs a header row with a "
                                        "'mesh' column")]
                for row in reader:
                    if None in row:  # more cells than the header names
                        rows.append((reader.line_num, None, f"{path} line {reader.line_num}: "
                                                            "more cells than the header has"))
                        continue
                    rows.append((reader.line_num, {k.strip(): v for k, v in row.items()
                                                   if v is not None and v.strip() != ""},
                                 None))
            else:
                for number, line in enumerate(handle, 1):
                    if not line.strip():
                        continue
                    try:
                        row = json.loads(line)
                    except RecursionError:  # nested deeper than the parser goes
                        rows.append((number, None, f"{path} line {number}: nested too deeply "
                                                   "to be a manifest row"))
                        continue
                    except json.JSONDecodeError as exc:
                        rows.append((number, None, f"{path} line {number}: not JSON ({exc.msg})"))
                        continue
                    if not isinstance(row, dict):
                        rows.append((number, None, f"{path} line {number}: not a JSON object"))
                        continue
                    rows.append((number, row, None))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        return [Asset(None, None, source=str(path), error=f"{path}: cannot read the manifest "
                                                          f"({exc})")]
    assets = []
    for number, row, error in rows:
        source = f"{path} line {number}"
        if error is not None:
            assets.append(Asset(None, None, source=source, error=error))
            continue
        try:
            assets.append(_row(row, where, suffix, target, source))
        except AobakeError as exc:
            mesh = row.get("mesh")
            assets.append(Asset(None if mesh is None else where / str(mesh), None,
                                source=source, error=f"{source}: {exc}"))
    return assets


def _row(row: dict, where: Path, suffix, target, source: str) -> Asset:
    mesh = row.get("mesh")
    if not isinstance(mesh, str) or not mesh.strip():
        raise InputError("no 'mesh'")
    mesh = where / mesh.strip()
    output = row.get("output")
    if output is not None:
        if not isinstance(output, str):
            raise InputError(f"'output' must be a path, got {output!r}")
        output = Path(output.strip())
        if not output.suffix:
            raise InputError(f"{output}: an output needs an extension (its format)")
    elif suffix is None:
        raise InputError("no 'output' and no --format")
    else:
        output = Path(mesh.name).with_suffix(suffix)
    asset_target = row.get("target", target)
    if asset_target is not None and asset_target not in ("vertices", "texels"):
        raise InputError(f"target must be vertices or texels, got {asset_target!r}")
    options = {}
    extra = row.get("options", {})
    if not isinstance(extra, dict):
        raise InputError("'options' must be an object of settings")
    for name, value in list(row.items()) + list(extra.items()):
        if name in _ASSET_KEYS:
            continue
        key, value = parse_setting(name, value)
        if key in _PATH_SETTINGS and value is not None:
            value = str(where / value)  # like the mesh: relative to the manifest's folder
        if value is not None:
            options[key] = value
    return Asset(mesh, output, asset_target, options, source)


def parse_setting(name: str, value):
    """(field name, value) of a manifest's setting: ``max-distance``, ``max_distance`` or
    a long flag (``from`` for ``source``); a text value (a CSV cell) is read as the command
    line reads it (``aobake.settings.spec.from_text``; a list separated by ``;``, ``,`` or spaces
    for a repeatable one).  InputError for an unknown
    setting or a bad value."""
    from aobake.settings import SPECS
    from aobake.settings.spec import from_text

    key = str(name).strip().lstrip("-").replace("-", "_")
    # a setting by its field name or its long flag (``from`` for ``source``)
    flags = {flag[2:].replace("-", "_"): field for field, spec in SPECS.items()
             for flag in spec.flags if flag.startswith("--") and "/" not in flag}
    key = key if key in SPECS else flags.get(key, key)
    if key not in SPECS:
        raise InputError(f"unknown setting {name!r}")
    spec = SPECS[key]
    if not isinstance(value, str):
        return key, tuple(value) if isinstance(value, list) else value
    text = value.strip()
    if text.lower() in ("", "none") and spec.optional:
        return key, None
    try:
        if spec.multiple:
            return key, tuple(from_text(key, spec, part)
                              for part in re.split(r"[;,\s]+", text) if part)
        return key, from_text(key, spec, text)
    except InputError as exc:
        raise InputError(f"{name}: {exc}") from None


def report_path(out: Path) -> Path:
    """The report beside an output: ``<output name>.report.json``."""
    return out.with_name(out.name + REPORT_SUFFIX)


def digest(path) -> dict:
    """{'path', 'bytes', 'sha256'} of an input file (what a resumed batch compares)."""
    sha = hashlib.sha256()
    size = 0
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(_HASH_BLOCK), b""):
            sha.update(block)
            size += len(block)
    return {"path": str(path), "bytes": size, "sha256": sha.hexdigest()}


def _contents(record: dict) -> tuple:
    """What identifies an asset's inputs in its report: each file's size and SHA-256 (not
    its path: a batch may run from another folder)."""
    files = [record] + [record.get(name) or {} for name in _PATH_SETTINGS]
    return tuple((f.get("bytes"), f.get("sha256")) for f in files)


def inputs(mesh, config) -> dict:
    """The report's ``input``: the mesh's ``digest``, with the digests of a high-to-low
    bake's source and cage under their names."""
    record = digest(mesh)
    for name in _PATH_SETTINGS:
        path = getattr(config, name, None)
        if path is not None:
            record[name] = digest(path)
    return record


def _jsonable(value):
    from aobake.outputs.strictjson import to_jsonable

    return json.loads(json.dumps(to_jsonable(value)))


def finished(out: Path, config, target: str, method: str, source: dict) -> str | None:
    """Why the asset at ``out`` is done (its files exist and its report matches this
    configuration, target, method and input), or None when it must be baked."""
    report = report_path(out)
    if not out.is_file() or not report.is_file():
        return None
    try:
        data = json.loads(report.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):  # unreadable or hand-edited: bake again
        return None
    if not isinstance(data, dict):
        return None
    parameters = data.get("parameters") or {}
    if data.get("config") != _jsonable(config.record(method, target)) \
            or data.get("target") != target \
            or parameters.get("method") != method \
            or _contents(data.get("input") or {}) != _contents(source):
        return None
    for written in data.get("outputs") or []:
        if not (out.parent / Path(written).name).is_file():
            return None
    if not intact(out):  # written, then damaged (truncated by a full disk, edited): again
        return None
    return f"{out.name} and its report match this configuration"


def intact(path: Path) -> bool:
    """Whether the output at ``path`` reads back whole: an NPZ's every member passes its
    CRC, an image decodes to its last scanline, a mesh loads (the cost of reading the file
    once, against baking it again)."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".npz":
            import zipfile

            with zipfile.ZipFile(path) as archive:
                return archive.testzip() is None
        if suffix in (".exr", ".png", ".tif", ".tiff"):
            import OpenImageIO as oiio

            image = oiio.ImageInput.open(str(path))
            if image is None:
                oiio.geterror()  # taken, so that it is not printed at exit
                return False
            try:
                pixels = image.read_image()
                ok = pixels is not None and not image.has_error
                if image.has_error:
                    image.geterror()
                return ok
            finally:
                image.close()
        if suffix in (".ply", ".glb"):
            import trimesh

            loaded = trimesh.load(str(path), process=False)
            return len(getattr(loaded, "vertices", [])) > 0 or bool(getattr(loaded, "geometry",
                                                                             None))
    except Exception:  # noqa: BLE001 - any failure to read it back: bake it again
        return False
    return True


def bake_assets(assets, out_dir, settings: dict, *, run: dict, write: dict,
                force: bool = False, on_asset=None) -> list:
    """Bake every asset; returns one record per asset, in order.

    settings : the command's settings (``BakeConfig`` fields; an asset's own override
    them), run : ``aobake.run`` keywords (threads, method, executor, workers, chunk_points),
    write : ``aobake.write`` keywords (half, bit_depth, r_only), force : re-bake finished
    assets, on_asset(record, index, total) : called after each.  A record: mesh, output,
    status ('ok' | 'skipped' | 'failed'), seconds, points, rays (None for a method that casts
    none), error (None unless failed), outputs (the files written), warnings.  Only an
    interrupt (KeyboardInterrupt, a signal the caller turned into an exception) stops the
    batch; every other failure is its asset's.
    """
    records = []
    for index, asset in enumerate(assets):
        clock = time.perf_counter()
        record = {"mesh": None if asset.mesh is None else str(asset.mesh),
                  "output": None if asset.output is None else str(asset.output),
                  "source": asset.source, "status": "failed", "seconds": 0.0, "points": None,
                  "rays": None, "error": None, "outputs": [], "warnings": []}
        try:
            if asset.error is not None:
                raise InputError(asset.error)
            record.update(_bake(asset, Path(out_dir), settings, run, write, force))
        except AobakeError as exc:
            record["error"] = str(exc)
        except ValueError as exc:  # the library's checks of arguments
            record["error"] = str(exc)
        except Exception as exc:  # noqa: BLE001 - a bug, reported with its traceback
            record["error"] = f"internal error: {type(exc).__name__}: {exc}"
            record["traceback"] = traceback.format_exc()
            log.debug("asset %s failed", asset.mesh, exc_info=True)
        record["seconds"] = time.perf_counter() - clock
        records.append(record)
        if on_asset is not None:
            on_asset(record, index, len(assets))
    return records


def _bake(asset: Asset, out_dir: Path, settings: dict, run: dict, write: dict,
          force: bool) -> dict:
    from aobake import job

    if not Path(asset.mesh).is_file():
        raise InputError(f"{asset.mesh}: no such file")
    out = output_path(out_dir, asset.output)
    report = output_path(out_dir, report_path(asset.output))
    # the batch's own settings apply to every asset, whatever its output: only an asset's
    # own options are held to its target (the command checks its settings against --format)
    planned = job.plan(asset.mesh, out, {**settings, **asset.options}, target=asset.target,
                       report=report, given=tuple(asset.options), **write, **run)
    config, where = planned.config, planned.outputs
    for companion in (where.mesh_out, where.camera):  # beside the output, in the folder
        if companion is not None:
            output_path(out_dir, Path(asset.output).with_name(companion.name))
    source = inputs(asset.mesh, config)
    if not force:
        why = finished(out, config, planned.target, planned.method, source)
        if why is not None:
            return {"status": "skipped", "reason": why}
    result = planned.bake()
    result.report["input"] = source
    written = planned.save(result)
    data = result.report
    return {"status": "ok", "points": int(data["points"]), "rays": data.get("rays_cast"),
            "outputs": [str(p) for p in written], "warnings": list(data.get("warnings", []))}


def check_summary(path, assets, out_dir, settings: dict) -> None:
    """OutputError when the summary at ``path`` would replace a file the batch reads (an
    asset's mesh, --from, --cage or --ao-from) or writes (an asset's output or report), or
    its folder (other than the output folder) does not exist: checked before any asset is
    baked."""
    from aobake.settings import INPUT_FILES

    where = Path(path).resolve()
    folder = Path(path).parent
    if where.parent != Path(out_dir).resolve() and not folder.is_dir():
        # (the output folder itself is made by the batch; any other must exist, as for
        # every output of the main command: found before the first asset, not after it)
        raise OutputError(f"{path}: output directory {folder} does not exist")
    for asset in assets:
        options = {**settings, **asset.options}
        named = [("the input mesh", asset.mesh)]
        named += [(f"the input {flag}", options.get(name)) for name, flag in INPUT_FILES.items()]
        if asset.output is not None:
            named += [("an asset's output", Path(out_dir) / asset.output),
                      ("an asset's report", Path(out_dir) / report_path(asset.output))]
        for role, other in named:
            if other is not None and Path(other).resolve() == where:
                raise OutputError(f"{path}: refusing to write the batch summary over {role} "
                                  f"({asset.source or asset.mesh}): choose another --summary")


def summary(records, out_dir, executor: dict, seconds: float) -> dict:
    """The batch's summary: counts, the executor, and every asset's record."""
    counts = {status: sum(r["status"] == status for r in records)
              for status in ("ok", "skipped", "failed")}
    return {"aobake_batch": 1, "out_dir": str(out_dir), "executor": executor,
            "seconds": seconds, "counts": counts, "assets": records}


__all__ = ["Asset", "MANIFESTS", "NO_FORMAT", "REPORT_SUFFIX", "SUMMARY_NAME", "bake_assets", "check_summary",
           "digest",
           "find_assets", "finished", "inputs", "output_path", "parse_setting", "report_path",
           "summary"]
