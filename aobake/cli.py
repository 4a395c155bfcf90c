"""Command line: a thin layer over :func:`aobake.bake`.  Only this module talks to the terminal.

Exit codes: 0 success, 1 a problem with the input or output (one-line message,
no traceback), 2 invalid usage (click's own errors).
"""

from __future__ import annotations

import logging
import math
import sys
from pathlib import Path

import click

from aobake.config import AXES, BACKFACES, NORMALS, QUANTITIES, BakeConfig, parse_distance
from aobake.errors import AobakeError, OutputError
from aobake.samplers import SAMPLERS
from aobake.warp import WEIGHTINGS

VERTEX_OUTPUTS = (".npz", ".ply", ".glb")
TEXTURE_OUTPUTS = (".exr", ".png", ".tif", ".tiff", ".glb")

EPILOG = """\b
Conventions (also written into every output's metadata):
  AO is cosine-weighted visibility (1/pi) int V cos dw: 1 = fully open, 0 = fully occluded.
  A hit beyond --max-distance is a miss.  Obscurance uses rho(L) = 1 - exp(-tau L)
  and counts a miss as rho = 1.  The bent normal is the normalised mean of the
  unoccluded sample directions (the surface normal when no ray escapes).
  Every value comes with its standard error (*_stderr).  --weighting uniform bakes
  the libigl/xNormal convention instead: (1/2pi) int V dw, the open solid angle.
"""


class DistanceType(click.ParamType):
    """A number in scene units, 'inf', or 'P%' of the bounding-box diagonal."""

    name = "distance"

    def convert(self, value, param, ctx):
        try:
            return parse_distance(value)
        except ValueError as exc:
            self.fail(str(exc), param, ctx)


class TauType(click.ParamType):
    name = "tau"

    def convert(self, value, param, ctx):
        try:
            tau = float(value)
        except ValueError:
            self.fail(f"{value!r} is not a number", param, ctx)
        if math.isnan(tau) or tau < 0:
            self.fail(f"tau must be >= 0 (or inf), got {value}", param, ctx)
        return tau


def _progress_bar(quiet: bool):
    """(callback, finish) drawing a progress bar on stderr when it is a terminal."""
    if quiet or not sys.stderr.isatty():
        return None, lambda: None
    state = {}

    def callback(done, total):
        if "bar" not in state:
            state["bar"] = click.progressbar(length=total, label="baking", file=sys.stderr)
            state["bar"].__enter__()
            state["last"] = 0
        state["bar"].update(done - state["last"])
        state["last"] = done

    def finish():
        if "bar" in state:
            state["bar"].__exit__(None, None, None)

    return callback, finish


@click.command(epilog=EPILOG, context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("mesh", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out", "-o", "out", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Output file; the extension picks the format. Per vertex: .npz, .ply, .glb "
                   "(COLOR_0). Lightmap: .exr (all channels), .png, .tif/.tiff, or .glb with "
                   "--target texels (occlusionTexture).")
@click.option("--target", type=click.Choice(["vertices", "texels"]), default=None,
              help="Bake per vertex or per lightmap texel. Default: texels for .exr/.png/.tif, "
                   "vertices otherwise.")
@click.option("--quantity", "-q", "quantities", multiple=True, type=click.Choice(QUANTITIES),
              help="What to bake (repeatable). Default: ao.")
@click.option("--rays", default=256, show_default=True, type=click.IntRange(min=1),
              help="Rays per vertex, or per texel (split over --texel-samples). The QMC "
                   "samplers round up to a multiple of 8 replicates.")
@click.option("--max-distance", default="inf", show_default=True, type=DistanceType(),
              help="Occluder search distance: scene units, 'inf', or 'P%' of the bounding-box "
                   "diagonal. Default inf: AO as defined, with no cut-off.")
@click.option("--tau", type=TauType(), default=None,
              help="Obscurance decay per scene unit in rho(L) = 1 - exp(-tau L). "
                   "Default: 10 / bounding-box diagonal.")
@click.option("--seed", default=0, show_default=True, type=click.IntRange(0, 2**63 - 1),
              help="Same inputs + seed = bit-identical outputs, for any --threads.")
@click.option("--sampler", default="sobol", show_default=True, type=click.Choice(sorted(SAMPLERS)),
              help="random: i.i.d.; stratified: jittered grid; sobol: Sobol net. "
                   "All randomised, all unbiased.")
@click.option("--weighting", default="cosine", show_default=True,
              type=click.Choice(sorted(WEIGHTINGS)),
              help="What AO averages over: cosine ((1/pi) int V cos, the default) or "
                   "uniform ((1/2pi) int V: libigl's and xNormal's convention, a different "
                   "number).")
@click.option("--normals", default="file", show_default=True, type=click.Choice(NORMALS),
              help="Vertex normals: the file's (angle-weighted where it has none), or computed.")
@click.option("--ground-plane", is_flag=True,
              help="Add an infinite solid ground plane at the scene's lowest point along --up-axis.")
@click.option("--up-axis", default="y", show_default=True, type=click.Choice(AXES),
              help="Up axis for --ground-plane.")
@click.option("--backfaces", default="occlude", show_default=True, type=click.Choice(BACKFACES),
              help="ignore: rays pass through back faces (costs closest-hit queries).")
@click.option("--ray-offset", default=1e-5, show_default=True, type=click.FloatRange(0, 0.1, min_open=True, max_open=True),
              help="Ray origin offset along the normal, as a fraction of the diagonal.")
@click.option("--threads", default=None, type=click.IntRange(min=1),
              help="Worker threads. Default: all cores.")
@click.option("--resolution", default="1024", show_default=True,
              help="Lightmap size: N (square) or WxH.")
@click.option("--padding", default=8, show_default=True, type=click.IntRange(min=0),
              help="Texels of dilation into the gutters (seamless bilinear/mip lookups).")
@click.option("--texel-samples", default=4, show_default=True, type=click.IntRange(min=1),
              help="Surface positions per texel, jittered over the covered part (antialiased "
                   "edges). --rays is per texel, split over these.")
@click.option("--unwrap/--no-unwrap", default=None,
              help="Always make a new xatlas atlas / never (fail without usable UVs). "
                   "Default: the mesh's own UVs when valid for baking, else a new atlas.")
@click.option("--mesh-out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Where to write the mesh with its new atlas (.obj or .glb). Default: "
                   "<out>.obj beside --out whenever a new atlas was made.")
@click.option("--half", is_flag=True, help="EXR: 16-bit half floats instead of 32-bit.")
@click.option("--bit-depth", default=8, show_default=True, type=click.Choice(["8", "16"]),
              help="PNG/TIFF integer depth: value = round(clip(x, 0, 1) * (2^bits - 1)).")
@click.option("--r-only", is_flag=True,
              help="PNG/TIFF: AO in R only (glTF occlusion convention) instead of R, G and B.")
@click.option("--bent-space", default="object", show_default=True,
              type=click.Choice(["object", "tangent"]),
              help="Lightmap bent normals in object space or tangent space (MikkTSpace-style "
                   "frames of the atlas UVs).")
@click.option("--report", "report_path", type=click.Path(dir_okay=False, path_type=Path),
              help="Write the JSON report (configuration, parameters, statistics) here.")
@click.option("--quiet", is_flag=True, help="No progress bar or warnings.")
@click.version_option(package_name="aobake")
def main(mesh, out, target, quantities, rays, max_distance, tau, seed, sampler, weighting,
         normals, ground_plane, up_axis, backfaces, ray_offset, threads, resolution, padding,
         texel_samples, unwrap, mesh_out, half, bit_depth, r_only, bent_space, report_path, quiet):
    """Bake ambient occlusion of MESH (OBJ, PLY, STL, OFF, GLB/glTF) per vertex or into a
    UV lightmap, written to --out."""
    logging.basicConfig(level=logging.ERROR if quiet else logging.WARNING,
                        format="aobake: warning: %(message)s", stream=sys.stderr)
    try:
        config = BakeConfig(quantities=quantities or ("ao",), rays=rays,
                            max_distance=max_distance, tau=tau, seed=seed, sampler=sampler,
                            weighting=weighting, normals=normals, ground_plane=ground_plane,
                            up_axis=up_axis, backfaces=backfaces, ray_offset=ray_offset)
        if target is None:
            target = "vertices" if out.suffix.lower() in VERTEX_OUTPUTS else "texels"
        texture = dict(resolution=resolution, padding=padding, texel_samples=texel_samples,
                       unwrap={None: "auto", True: "always", False: "never"}[unwrap],
                       bent_space=bent_space)
        files = dict(mesh_out=mesh_out, half=half, bit_depth=int(bit_depth), r_only=r_only)
        _run(mesh, out, target, config, texture, files, threads, report_path, quiet)
    except (AobakeError, ValueError) as exc:
        click.echo(f"aobake: error: {exc}", err=True)
        sys.exit(1)


def _check_outputs(mesh: Path, out: Path, target: str, *extra: Path | None):
    suffix = out.suffix.lower()
    allowed = VERTEX_OUTPUTS if target == "vertices" else TEXTURE_OUTPUTS
    if suffix not in allowed:
        raise OutputError(f"{out}: unsupported output format {suffix or '(none)'!r} for "
                          f"--target {target}; use one of {', '.join(allowed)}")
    for path in (out, *extra):
        if path is None:
            continue
        if mesh.exists() and path.exists() and path.resolve() == mesh.resolve():
            raise OutputError(f"{path}: refusing to overwrite the input mesh")
        if not path.parent.resolve().is_dir():
            raise OutputError(f"{path}: directory {path.parent} does not exist")


def _run(mesh, out, target, config, texture, files, threads, report_path, quiet):
    from aobake.bake import bake, bake_texels, parse_resolution
    from aobake.outputs.report import write_report

    mesh_out = files["mesh_out"]
    if target == "texels":
        from aobake.outputs.texture import MESH_OUTPUTS, default_mesh_out

        parse_resolution(texture["resolution"])  # fail before loading anything
        if mesh_out is not None and mesh_out.suffix.lower() not in MESH_OUTPUTS:
            raise OutputError(f"{mesh_out}: unsupported --mesh-out format; use .obj or .glb")
        if mesh_out is None and out.suffix.lower() != ".glb":
            mesh_out = default_mesh_out(out)
    _check_outputs(mesh, out, target, report_path, mesh_out)
    progress, finish = _progress_bar(quiet)
    try:
        if target == "vertices":
            result = bake(mesh, config, threads=threads, progress=progress)
        else:
            result = bake_texels(mesh, config, threads=threads, progress=progress, **texture)
    finally:
        finish()
    report = result.report
    metadata = {"conventions": report["conventions"], "config": report["config"],
                "parameters": report["parameters"], "versions": report["versions"]}
    written = [out]
    if target == "vertices":
        from aobake.outputs import write_vertices

        write_vertices(out, result.positions, result.faces, result.fields(), metadata)
    else:
        from aobake.outputs.texture import write_atlas_mesh, write_texture

        metadata["texture"] = report["texture"]
        write_texture(out, result, metadata, half=files["half"], bit_depth=files["bit_depth"],
                      r_only=files["r_only"])
        if mesh_out is not None and (result.atlas.new or files["mesh_out"] is not None):
            write_atlas_mesh(mesh_out, result, metadata)
            written.append(mesh_out)
    if report_path is not None:
        report["outputs"] = [str(p) for p in written]
        write_report(report_path, report)
    if not quiet:
        what = "vertices" if target == "vertices" else "texel samples"
        click.echo(f"aobake: {report['points']} {what}, {report['rays_cast']} rays "
                   f"in {report['wall_time_s']:.2f} s ({report['rays_per_second'] / 1e6:.2f} Mrays/s) "
                   f"-> {', '.join(map(str, written))}", err=True)
