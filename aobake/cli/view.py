"""``aobake view MESH --out view.exr``: a camera's G-buffer with the method's values per pixel.

The bake options are generated from the settings' specs like the main command's (the
same flags, defaults, help and checks: nothing typed twice), less the lightmap target's;
only the camera's options are new here.
"""

from __future__ import annotations

from pathlib import Path

import click

from aobake import capabilities
from aobake.cli.common import guarded
from aobake.cli.options import (FiniteRange, PanelCommand, checked, given, in_panel,
                                method_for, run_options, settings)

#: settings that mean nothing for a camera view (kept distances are an NPZ's; a view sees
#: the scene, it is not projected from another mesh, so no low mesh occludes)
NOT_FOR_VIEWS = ("keep_distances", "source", "cage_offset", "cage", "low_occludes")
#: the methods a view can run (``aobake.capabilities``): --method's choices
METHODS = capabilities.methods_for(("view",))


class _VectorType(click.ParamType):
    name = "X,Y,Z"

    def convert(self, value, param, ctx):
        from aobake.camera import parse_vector
        from aobake.errors import InputError

        try:
            return parse_vector(value)
        except InputError as exc:
            self.fail(str(exc), param, ctx)


class _SizeType(click.ParamType):
    name = "WxH"

    def convert(self, value, param, ctx):
        from aobake.camera import parse_size
        from aobake.errors import InputError

        try:
            return parse_size(value)
        except InputError as exc:
            self.fail(str(exc), param, ctx)


def _camera_options() -> list:
    return in_panel("camera", [
        click.Option(["--look-from"], type=_VectorType(), default=None,
                     help="Eye position X,Y,Z (scene units)."),
        click.Option(["--look-at"], type=_VectorType(), default=None,
                     help="Point looked at X,Y,Z (with --look-from)."),
        click.Option(["--up"], type=_VectorType(), default=None,
                     help="Up direction X,Y,Z. Default: the --up-axis."),
        click.Option(["--fov"], type=FiniteRange(0.0, 180.0, min_open=True, max_open=True),
                     default=40.0, show_default=True, help="Vertical field of view, degrees."),
        click.Option(["--size"], type=_SizeType(), default="960x540", show_default=True,
                     help="Image size WxH pixels."),
        click.Option(["--camera"], default=None,
                     help="Use the glTF camera node of this name in MESH (a .gltf/.glb); "
                          "'first' for the first camera."),
        click.Option(["--truths"], is_flag=True, default=False,
                     help="The two ray-traced truths a screen-space method is scored against, "
                          "in one .exr: ao bounded at --ssao-radius (what the method can see) "
                          "and ao_unbounded, with the G-buffer and camera "
                          "(docs/screen-space.md)."),
    ])


def _output_options() -> list:
    return in_panel("output", [
        click.Option(["--out", "-o", "out"], required=True,
                     type=click.Path(dir_okay=False, path_type=Path),
                     help="Output: .exr (G-buffer + AO channels, float32; --half for 16-bit) "
                          "or .png/.tif (the AO as a picture; coverage in alpha)."),
        click.Option(["--report", "report_path"],
                     type=click.Path(dir_okay=False, path_type=Path),
                     help="Write the JSON report (configuration, camera, parameters, "
                          "statistics) here."),
        click.Option(["--quiet"], is_flag=True, help="No progress bar or warnings."),
        click.Option(["--half"], is_flag=True, help="EXR: 16-bit half floats instead of "
                                                    "32-bit."),
        click.Option(["--bit-depth"], default="8", show_default=True,
                     type=click.Choice(["8", "16"]),
                     help="PNG/TIFF integer depth: value = round(clip(x, 0, 1) * "
                          "(2^bits - 1))."),
        click.Option(["--export-camera", "export_camera"],
                     type=click.Path(dir_okay=False, path_type=Path), default=None,
                     help="Also write the mesh and the view's camera as a glTF (.gltf or "
                          ".glb) other tools import: a camera node with yfov, aspectRatio, "
                          "znear/zfar; `aobake view FILE --camera first` reads the same "
                          "camera back (docs/renderers.md)."),
        click.Option(["--export-mitsuba", "export_mitsuba"],
                     type=click.Path(dir_okay=False, path_type=Path), default=None,
                     help="Also write a Mitsuba 3 scene (.xml, the mesh beside it as "
                          "<stem>.ply) that renders this view's AO: box filter, "
                          "fov_axis y, face normals (docs/renderers.md)."),
    ])


def view_command() -> click.Command:
    """The ``view`` command: camera and output options, the settings a view can use, and
    the methods a view can run."""
    params = ([click.Argument(["mesh"], type=click.Path(path_type=Path))] + _output_options()
              + _camera_options() + settings(("view",), METHODS, exclude=NOT_FOR_VIEWS)
              + run_options(METHODS))
    return PanelCommand(
        "view", params=params, callback=_view, shown=("output", "camera", "common", "rays"),
        context_settings={"help_option_names": ["-h", "--help"]},
        help="Render a camera view of MESH: one primary ray per pixel centre (Embree; "
             "--pixel-filter box: positions spread over each pixel's area, the mean AO "
             "over the pixel as a box-filtered renderer computes it), the "
             "G-buffer (depth, distance, hardware depths, view-space position and normals, "
             "ids, coverage) and the method's values (ao, its stderr and interval, rays) "
             "at each first hit, about the geometric normal facing the eye. Default camera: "
             "a three-quarter view framing the bounding box. Conventions: "
             "docs/conventions.md.")


def _view(mesh, out, look_from, look_at, up, fov, size, camera, truths, threads, half,
          bit_depth, report_path, quiet, quantities, method, executor, workers, chunk_points,
          scheduler, export_camera, export_mitsuba, **config):
    if (look_from is None) != (look_at is None):
        raise click.UsageError("give --look-from and --look-at together")
    if camera is not None and look_from is not None:
        raise click.UsageError("give --camera or --look-from/--look-at, not both")
    look = None
    if look_from is not None:
        look = {"look_from": look_from, "look_at": look_at, "fov": fov}
        if up is not None:
            look["up"] = up
    elif up is not None:
        raise click.UsageError("--up goes with --look-from/--look-at")
    gltf = None if camera is None else (mesh, None if camera == "first" else camera)
    method = method_for(method, config)
    if truths:
        _check_truths(out, method, quantities)
    view = dict(look=look, gltf=gltf, size=size, fov=fov)
    request = dict(view=view, truths=truths, method=method, report=report_path, half=half,
                   bit_depth=int(bit_depth), threads=threads, executor=executor,
                   workers=workers, chunk_points=chunk_points, scheduler=scheduler)
    exports = dict(gltf=export_camera, mitsuba=export_mitsuba)
    guarded(quiet, _run, mesh, out, request, quiet,
            checked(given(dict(config, quantities=quantities))), exports)


def _check_truths(out: Path, method: str, quantities) -> None:
    """Usage errors of --truths: one EXR of the ray-traced AO, its radius --ssao-radius."""
    context = click.get_current_context()
    if out.suffix.lower() != ".exr":
        raise click.UsageError(f"--truths writes several AO channels: the output must be .exr, "
                               f"not {out.suffix or 'no suffix'}")
    if method != "rays":
        raise click.UsageError(f"--truths are ray traced: not with --method {method}")
    if context.get_parameter_source("max_distance") == click.core.ParameterSource.COMMANDLINE:
        raise click.UsageError("--truths bounds its first truth at --ssao-radius: give that, "
                               "not --max-distance")
    if quantities is not None and tuple(quantities) != ("ao",):
        raise click.UsageError("--truths bakes ao only")


def _run(mesh, out, request, quiet, config, exports):
    from aobake import job
    from aobake.outputs import camera_export
    from aobake.outputs.atomic import transaction

    planned = job.plan(mesh, out, config, **request)
    where = planned.outputs  # the exports may not overwrite these, nor the input
    from aobake.settings import INPUT_FILES

    taken = {"--out": where.out, "--report": where.report,
             "the camera file (<out>.camera.json)": where.camera, "the input mesh": mesh,
             **{f"the input {flag}": getattr(planned.config, name)
                for name, flag in INPUT_FILES.items()}}
    exports = camera_export.plan(**exports, config=planned.config, taken=taken)
    result = planned.bake()
    # the exports join the transaction of the image, its camera file and the report:
    # all appear together, or none (write() nests inside this one)
    with transaction():
        written = planned.save(result)
        written += camera_export.write_view(result, mesh, exports)
    if not quiet:
        report = result.report
        cam = report["camera"]
        cost = (f"{report['rays_cast']} rays" if "rays_cast" in report
                 else f"method {report['parameters']['method']}, no rays")
        if "truths" in report:
            cost += (f" bounded at {report['truths']['bounded']['max_distance']:.6g} + "
                     f"{report['truths']['unbounded']['rays_cast']} unbounded")
        click.echo(f"aobake: view {cam['width']}x{cam['height']}, "
                   f"{report['pixels_covered']} pixels see the scene, {cost} in "
                   f"{report['wall_time_s']:.2f} s -> {', '.join(map(str, written))}", err=True)
