"""Command line: parses and prints; everything else is a library call.

Defaults come from ``aobake.settings.DEFAULTS`` and choices from the registries
(samplers, weightings, quantities, backends, output formats), so no name or
default is typed twice.  Only this module talks to the terminal.

Exit codes: 0 success, 1 a problem with the input or output (one-line message,
no traceback), 2 invalid usage (click's own errors).
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from aobake.cli.common import guarded
from aobake.cli.options import (BAKE_METHODS as METHODS, BAKE_TARGETS as TARGETS,
                                PanelCommand, checked, given, in_panel, method_for, run_options,
                                settings)
from aobake.outputs.registry import MESH_OUTPUTS, suffixes

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


class _WithSubcommands(PanelCommand):
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
    from aobake.cli.refit import refit_main

    return refit_main


#: sub-command name -> function returning its click command (imported when used)
def _view_command():
    from aobake.cli.view import view_command

    return view_command()


def _batch_command():
    from aobake.cli.batch import batch_command

    return batch_command()


SUBCOMMANDS = {"compare": _compare_command, "refit": _refit_command, "view": _view_command,
               "batch": _batch_command}


def _own_options() -> list:
    """The main command's options beyond the settings: the output and its formats."""
    output = in_panel("output", [
        click.Option(["--out", "-o", "out"], required=True,
                     type=click.Path(dir_okay=False, path_type=Path),
                     help=f"Output file; the extension picks the format. Per vertex: {_VERTEX}. "
                          f"Lightmap: {_TEXEL} (.glb with --target texels: occlusionTexture)."),
        click.Option(["--target"], type=click.Choice(TARGETS), default=None,
                     help="Bake per vertex or per lightmap texel. Default: vertices for "
                          f"{_VERTEX}, texels otherwise."),
        click.Option(["--report", "report_path"], type=click.Path(dir_okay=False,
                                                                   path_type=Path),
                     help="Write the JSON report (configuration, parameters, statistics) "
                          "here."),
        click.Option(["--quiet"], is_flag=True, help="No progress bar or warnings."),
    ])
    lightmap = in_panel("texels", [
        click.Option(["--mesh-out"], type=click.Path(dir_okay=False, path_type=Path),
                     default=None,
                     help=f"Where to write the mesh with its new atlas "
                          f"({' or '.join(MESH_OUTPUTS)}). Default: <out>.obj beside --out "
                          "whenever a new atlas was made."),
        click.Option(["--half"], is_flag=True, help="EXR: 16-bit half floats instead of "
                                                    "32-bit."),
        click.Option(["--bit-depth"], default="8", show_default=True,
                     type=click.Choice(["8", "16"]),
                     help="PNG/TIFF integer depth: value = round(clip(x, 0, 1) * "
                          "(2^bits - 1))."),
        click.Option(["--r-only"], is_flag=True,
                     help="PNG/TIFF: AO in R only (glTF occlusion convention) instead of R, G "
                          "and B."),
        click.Option(["--orm"], is_flag=True,
                     help="Lightmap: pack as ORM, R = AO, G = roughness, B = metalness "
                          "(PNG/TIFF: RGB; EXR: orm.R/G/B channels added; GLB: one image as "
                          "occlusionTexture and metallicRoughnessTexture). G/B from "
                          "--orm-from, else the glTF input's metallicRoughnessTexture, else "
                          "roughness 1, metalness 0."),
        click.Option(["--orm-from"], type=click.Path(exists=True, dir_okay=False,
                                                     path_type=Path), default=None,
                     help="The texture whose G (roughness) and B (metalness) --orm copies, "
                          "laid out in the baked UVs and of the lightmap's size (implies "
                          "--orm)."),
    ])
    return output, lightmap


def _command() -> click.Command:
    output, lightmap = _own_options()
    params = ([click.Argument(["mesh"], type=click.Path(path_type=Path))] + output
              + settings(TARGETS, METHODS) + run_options(METHODS) + lightmap)
    command = _WithSubcommands(
        "aobake", params=params, callback=_main, epilog=EPILOG,
        context_settings={"help_option_names": ["-h", "--help"]},
        help="Bake ambient occlusion of MESH (OBJ, PLY, STL, OFF, GLB/glTF) per vertex or "
             "into a UV lightmap, written to --out.\n\nOther commands: aobake view (a "
             "camera's G-buffer and per-pixel AO), aobake batch (many assets), aobake "
             "compare (score one bake against another), aobake refit (a kept bake at "
             "another distance). Each has its own --help.")
    return click.version_option(package_name="aobake")(command)


def _main(mesh, out, target, threads, mesh_out, half, bit_depth, r_only, orm, orm_from,
          report_path, quiet, method, executor, workers, chunk_points, scheduler, **config):
    source = click.get_current_context().get_parameter_source("resolution")
    if source == click.core.ParameterSource.COMMANDLINE and config["texel_density"] is not None:
        raise click.UsageError("give --resolution or --texel-density, not both")
    run = dict(threads=threads, executor=executor, workers=workers,
               chunk_points=chunk_points, scheduler=scheduler)
    request = dict(target=target, method=method_for(method, config), mesh_out=mesh_out,
                   report=report_path, half=half, bit_depth=int(bit_depth), r_only=r_only,
                   orm=orm, orm_from=orm_from, **run)
    guarded(quiet, _run, mesh, out, request, quiet, checked(given(config)))


main = _command()


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


def _run(mesh, out, request, quiet, config):
    from aobake import job

    planned = job.plan(mesh, out, config, **request)  # every check before any work
    progress, finish = _progress_bar(quiet)
    if planned.outputs.target == "texels":
        progress = _prefetching(progress)
    try:
        result = planned.bake(progress)
    finally:
        finish()
    written = planned.save(result)
    where = planned.outputs
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
