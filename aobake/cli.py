"""Command line: parses and prints; everything else is a library call.

Defaults come from ``aobake.config.DEFAULTS`` and choices from the registries
(samplers, weightings, quantities, backends, output formats), so no name or
default is typed twice.  Only this module talks to the terminal.

Exit codes: 0 success, 1 a problem with the input or output (one-line message,
no traceback), 2 invalid usage (click's own errors).
"""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

import click

from aobake.cli_common import guarded
from aobake.cli_options import (RUN_OPTIONS, DistanceType, FiniteRange, TauType,  # noqa: F401
                                given, settings)
from aobake.outputs.registry import MESH_OUTPUTS, suffixes
from aobake.targets import CLI_TARGETS

EPILOG = """\b
Conventions (also written into every output's metadata):
  AO is cosine-weighted visibility (1/pi) int V cos dw: 1 = fully open, 0 = fully occluded.
  A hit beyond --max-distance is a miss.  Obscurance uses rho(L) = 1 - exp(-tau L)
  and counts a miss as rho = 1.  The bent normal is the normalised mean of the
  unoccluded sample directions (the surface normal when no ray escapes).
  Every value comes with its standard error (*_stderr).  --weighting uniform bakes
  the libigl/xNormal convention instead: (1/2pi) int V dw, the open solid angle.
"""


def _progress_bar(quiet: bool):
    """(callback, finish) drawing progress on stderr when it is a terminal: each stage's name
    as it starts (unwrapping and rasterising can take seconds), then a bar while tracing."""
    if quiet or not sys.stderr.isatty():
        return None, lambda: None
    state = {}

    def callback(done, total):
        if "bar" not in state:
            click.echo("\r\033[K", nl=False, err=True)
            state["bar"] = click.progressbar(length=total, label="tracing", file=sys.stderr)
            state["bar"].__enter__()
            state["last"] = 0
        state["bar"].update(done - state["last"])
        state["last"] = done

    def phase(name):
        if "bar" not in state and name != "tracing":
            click.echo(f"\r\033[Kaobake: {name} ...", nl=False, err=True)

    callback.phase = phase

    def finish():
        if "bar" in state:
            state["bar"].__exit__(None, None, None)
        else:
            click.echo("\r\033[K", nl=False, err=True)

    return callback, finish


_VERTEX, _TEXEL = ", ".join(suffixes("vertices")), ", ".join(suffixes("texels"))


class _WithSubcommands(click.Command):
    """``aobake MESH --out ...`` bakes (unchanged); ``aobake compare ...`` and
    ``aobake refit ...`` run those tools.  A mesh named like a sub-command is ``./compare``."""

    def main(self, args=None, prog_name=None, **extra):
        args = list(sys.argv[1:] if args is None else args)
        if args and args[0] in SUBCOMMANDS:
            command = SUBCOMMANDS[args[0]]()
            return command.main(args[1:], prog_name=f"{prog_name or 'aobake'} {args[0]}",
                                **extra)
        return super().main(args, prog_name=prog_name, **extra)


def _compare_command():
    from aobake.compare import main as compare

    return compare


def _refit_command():
    from aobake.cli_refit import refit_main

    return refit_main


#: sub-command name -> function returning its click command (imported when used)
def _view_command():
    from aobake.cli_view import view_command

    return view_command(main)


def _batch_command():
    from aobake.cli_batch import batch_command

    return batch_command()


SUBCOMMANDS = {"compare": _compare_command, "refit": _refit_command, "view": _view_command,
               "batch": _batch_command}


def _with(options):
    """Decorate a command with click options made elsewhere (``cli_options.settings``)."""
    def decorate(function):
        # as click's own decorators do: parameters gather on the function, last first
        params = function.__dict__.setdefault("__click_params__", [])
        params.extend(reversed(options))
        return function
    return decorate


@click.command(cls=_WithSubcommands, epilog=EPILOG,
               context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("mesh", type=click.Path(path_type=Path))
@click.option("--out", "-o", "out", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help=f"Output file; the extension picks the format. Per vertex: {_VERTEX}. "
                   f"Lightmap: {_TEXEL} (.glb with --target texels: occlusionTexture).")
@click.option("--target", type=click.Choice(CLI_TARGETS), default=None,
              help="Bake per vertex or per lightmap texel. Default: vertices for "
                   f"{_VERTEX}, texels otherwise.")
@_with(settings() + RUN_OPTIONS)
@click.option("--mesh-out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help=f"Where to write the mesh with its new atlas ({' or '.join(MESH_OUTPUTS)}). "
                   "Default: <out>.obj beside --out whenever a new atlas was made.")
@click.option("--half", is_flag=True, help="EXR: 16-bit half floats instead of 32-bit.")
@click.option("--bit-depth", default="8", show_default=True, type=click.Choice(["8", "16"]),
              help="PNG/TIFF integer depth: value = round(clip(x, 0, 1) * (2^bits - 1)).")
@click.option("--r-only", is_flag=True,
              help="PNG/TIFF: AO in R only (glTF occlusion convention) instead of R, G and B.")
@click.option("--orm", is_flag=True,
              help="Lightmap: pack as ORM, R = AO, G = roughness, B = metalness (PNG/TIFF: "
                   "RGB; EXR: orm.R/G/B channels added; GLB: one image as occlusionTexture and "
                   "metallicRoughnessTexture). G/B from --orm-from, else the glTF input's "
                   "metallicRoughnessTexture, else roughness 1, metalness 0.")
@click.option("--orm-from", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              default=None,
              help="The texture whose G (roughness) and B (metalness) --orm copies, laid out "
                   "in the baked UVs and of the lightmap's size (implies --orm).")
@click.option("--report", "report_path", type=click.Path(dir_okay=False, path_type=Path),
              help="Write the JSON report (configuration, parameters, statistics) here.")
@click.option("--quiet", is_flag=True, help="No progress bar or warnings.")
@click.version_option(package_name="aobake")
def main(mesh, out, target, threads, mesh_out, half, bit_depth, r_only, orm, orm_from,
         report_path, quiet, method, executor, workers, chunk_points, scheduler, **config):
    """Bake ambient occlusion of MESH (OBJ, PLY, STL, OFF, GLB/glTF) per vertex or into a
    UV lightmap, written to --out."""
    source = click.get_current_context().get_parameter_source("resolution")
    if source == click.core.ParameterSource.COMMANDLINE and config["texel_density"] is not None:
        raise click.UsageError("give --resolution or --texel-density, not both")
    from aobake.cli_view import _method_for

    run = dict(threads=threads, method=_method_for(method, config), executor=executor,
               workers=workers, chunk_points=chunk_points, scheduler=scheduler)
    guarded(quiet, _run, mesh, out, target, run, quiet, given(config),
             dict(mesh_out=mesh_out, report=report_path, half=half, bit_depth=int(bit_depth),
                  r_only=r_only, orm=orm or orm_from is not None, orm_from=orm_from))


def entry() -> None:
    """The process entry of the ``aobake`` command, ``python -m aobake`` and ``cli.py``:
    ``main`` and its exit status, then the process ends without the interpreter's teardown.

    Once the outputs are closed and renamed, the teardown only frees what the bake held
    (every array one by one, the modules' objects) for memory the system takes back anyway:
    0.18 s after a 1024^2 lightmap of the bunny.  The streams and logging are flushed first;
    the library, and ``main`` run inside another program (click's test runner), end as
    usual.
    """
    code = 0
    try:
        main()  # click's standalone mode ends with SystemExit, 0 included
    except SystemExit as exc:
        code = exc.code
    if code is None:
        code = 0
    elif not isinstance(code, int):  # sys.exit("message"): the message, status 1
        click.echo(str(code), err=True)
        code = 1
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            if stream is not None:  # None: no console (pythonw, a detached process)
                stream.flush()
        except Exception:  # noqa: BLE001 - a closed or broken pipe: nothing more to say
            pass
    # atexit hooks do not run (the CLI registers none; a coverage tool's would be skipped).
    os._exit(code)


def _prefetching(progress):
    """``progress`` (or a silent stand-in) whose phase("unwrapping") also starts importing
    the image writer: every lightmap output is written through OpenImageIO, and while
    xatlas's child unwraps, this process only waits."""
    from aobake.outputs import image

    def callback(done, total):
        if progress is not None:
            progress(done, total)

    def phase(name):
        if name == "unwrapping":
            image.prefetch()
        if progress is not None:
            progress.phase(name)

    callback.phase = phase
    return callback


def _run(mesh, out, target, run, quiet, config, files):
    import aobake

    config = aobake.BakeConfig(**config)  # validated before any file is touched
    where = aobake.outputs.plan(out, target, mesh=mesh, mesh_out=files["mesh_out"],
                                report=files["report"], quantities=config.quantities,
                                inputs=(config.source, config.cage, files["orm_from"]),
                                orm=files["orm"])
    if files["orm_from"] is not None and config.texel_density is None:
        from aobake.outputs.orm import check_source

        check_source(files["orm_from"], config.resolution)  # before the bake, not after
    if config.keep_distances and where.out.suffix.lower() != ".npz":
        raise click.UsageError(f"--keep-distances needs an .npz --out (got {where.out.name})")
    if config.denoise and (where.target != "texels" or where.out.suffix.lower() != ".exr"):
        # The denoised map goes beside the raw one, never instead: only EXR has the channels.
        raise click.UsageError(f"--denoise adds channels to a lightmap: it needs an .exr --out "
                               f"(got {where.out.name})")
    progress, finish = _progress_bar(quiet)
    if where.target == "texels":
        progress = _prefetching(progress)
    from aobake.targets import TARGETS

    scene = mesh
    if config.source is not None:  # high-to-low: the source is the scene, MESH the low mesh
        target, scene = config.target(where.target, mesh), config.source
    else:
        target = TARGETS[where.target]()  # the CLI's targets need nothing beyond the config
    unwrapping = None
    if where.target == "texels" and config.unwrap != "never":
        from aobake.targets.texels import unwrap as unwrapping

        unwrapping.prestart()  # its start overlaps the loading; ended if own UVs are baked
    try:
        result = aobake.run(config, scene, target, progress=progress, **run)
    finally:
        finish()
        if unwrapping is not None:
            unwrapping.discard_prestarted()
    written = aobake.write(result, out, mesh=mesh, **files)
    if not quiet:
        report = result.report
        what = "vertices" if where.target == "vertices" else "texel samples"
        if "tolerance" in report:
            t = report["tolerance"]
            saving = t["saving_vs_fixed"] or 0.0
            versus = (f"{saving:.1f}x fewer than" if saving >= 1 else
                      f"{1 / saving:.1f}x more than" if saving > 0 else "against")
            click.echo(f"aobake: tolerance {t['tolerance']:g}: {t['points_met']} {what} met "
                       f"it, {t['points_missed']} missed, {t['points_capped']} capped at "
                       f"{t['max_rays']} rays; {t['rays_total']} rays, {versus} a fixed "
                       "count for the same worst case", err=True)
        cost = (f"{report['rays_cast']} rays in {report['wall_time_s']:.2f} s "
                f"({report['rays_per_second'] / 1e6:.2f} Mrays/s)" if "rays_cast" in report
                else f"method {report['parameters']['method']}, no rays, in "
                     f"{report['wall_time_s']:.2f} s")
        click.echo(f"aobake: {report['points']} {what}, {cost} -> "
                   f"{', '.join(map(str, written))}", err=True)
        texture = report.get("texture")
        if texture:
            density = texture.get("chart_density") or {}
            click.echo(f"aobake: lightmap {texture['width']}x{texture['height']}, padding "
                       f"{texture['padding']}: {texture['charts'] or density.get('islands', 0)} "
                       f"charts ({texture['atlas']}) cover {texture['covered_fraction']:.1%} of "
                       f"the texels; texel density {density.get('p5', 0):.4g}-"
                       f"{density.get('p95', 0):.4g} per scene unit (p5-p95, ratio "
                       f"{density.get('spread') or 0:.3f})", err=True)
