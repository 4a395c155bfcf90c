"""Blender's side of docs/renderers.md: import an ``aobake view --export-camera`` glTF and
report its camera, or render its AO pass with Cycles or EEVEE.  Run with a Python that has
``bpy`` (Blender as a module, Python 3.11, in a venv of its own: .ci/run makes one and names
it ``AOBAKE_BLENDER_PYTHON``):

    $AOBAKE_BLENDER_PYTHON tests/blender_renderers.py camera view.glb
    $AOBAKE_BLENDER_PYTHON tests/blender_renderers.py camera-record mesh.obj view.camera.json
    $AOBAKE_BLENDER_PYTHON tests/blender_renderers.py cycles view.glb cycles.exr \\
        --samples 256 --seed 1 --filter box
    $AOBAKE_BLENDER_PYTHON tests/blender_renderers.py eevee view.glb eevee.exr

Each prints one JSON line last (what Blender has, or what was rendered and how long it
took) and exits 1 with {"ok": false, "error": ...} when something fails.  ``tests/
test_renderers.py`` and ``benchmarks/bench_renderers.py`` run it.

The conventions that matter (docs/renderers.md):

- glTF import: Blender turns glTF's +Y up into its +Z up, the mesh and the camera alike
  (Blender (x, y, z) = glTF (x, -z, y)); the camera's ``yfov`` becomes ``angle_y`` with
  ``sensor_fit`` VERTICAL; the importer does not set the render size (glTF has none): it
  comes from the camera's extras ``width`` / ``height``, which the importer keeps as
  custom properties.
- Cycles' AO pass samples the hemisphere about the *shading* normal: the mesh must be
  flat-shaded (the export has no normals, which the importer takes as flat; set here
  again) for it to be aobake's geometric-normal AO.
- Pixel filter: ``box`` averages over the pixel (aobake ``--pixel-filter box``); aobake's
  centre sampling is a Blackman-Harris filter of width 0.01 px (a box ignores its width:
  Cycles' box is always one pixel wide).
- The AO pass's distance is the world's ``light_settings.distance``: set to the view's
  ``--max-distance`` (unbounded: far beyond the scene).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time


def _import(path: str, blend: bool = False):
    """The glTF (or a saved .blend) opened in an empty scene: (scene, camera object, mesh
    objects)."""
    import bpy

    if blend:
        bpy.ops.wm.open_mainfile(filepath=path)
    else:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.import_scene.gltf(filepath=path)
    scene = bpy.context.scene
    cameras = [o for o in bpy.data.objects if o.type == "CAMERA"]
    if not cameras:
        raise RuntimeError(f"{path}: Blender imported no camera")
    camera = cameras[0]
    scene.camera = camera
    # glTF has no image size: aobake's export keeps it in the camera's extras
    scene.render.resolution_x = int(camera.data["width"])
    scene.render.resolution_y = int(camera.data["height"])
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    meshes = [o for o in bpy.data.objects if o.type == "MESH"]
    return scene, camera, meshes


def _unclipped(camera, meshes) -> None:
    """aobake traces every primary ray to its first hit (nothing is clipped); the glTF's
    zfar is the record's far, fitted to the mesh, not to the ground plane's quad: open the
    far plane past everything imported (the near plane stays: nothing is nearer)."""
    reach = 0.0
    eye = camera.matrix_world.translation
    for obj in meshes:
        for corner in obj.bound_box:
            reach = max(reach, (obj.matrix_world @ type(eye)(corner) - eye).length)
    camera.data.clip_end = max(camera.data.clip_end, 1.01 * reach)


def camera(path: str, points: int = 200, blend: bool = False) -> dict:
    """What Blender made of the file's camera, and where it puts up to ``points`` of the
    mesh's vertices (Blender world coordinates and their pixel positions: x right from the
    left edge, y down from the top edge, in pixels)."""
    scene, cam, meshes = _import(path, blend)
    from bpy_extras.object_utils import world_to_camera_view  # importable once bpy is

    width, height = scene.render.resolution_x, scene.render.resolution_y
    world, pixels = [], []
    for obj in meshes:
        vertices = obj.data.vertices
        step = max(1, len(vertices) // points)
        for vertex in list(vertices)[::step][:points]:
            p = obj.matrix_world @ vertex.co
            ndc = world_to_camera_view(scene, cam, p)  # x, y in [0, 1] from bottom-left
            world.append(list(p))
            pixels.append([ndc.x * width, (1.0 - ndc.y) * height, ndc.z])
    return {"matrix_world": [list(row) for row in cam.matrix_world],
            "angle_y": cam.data.angle_y, "angle_x": cam.data.angle_x,
            "sensor_fit": cam.data.sensor_fit, "clip_start": cam.data.clip_start,
            "clip_end": cam.data.clip_end, "resolution": [width, height],
            "camera_type": cam.data.type,
            "flat": all(not p.use_smooth for o in meshes for p in o.data.polygons),
            "world": world, "pixels": pixels}


def camera_from_record(path: str, record_path: str, axes: str = "keep",
                       points: int = 200) -> dict:
    """The OBJ route: import the mesh ``path`` (an OBJ) and make the camera from aobake's
    camera record (``<out>.camera.json``), then report as :func:`camera` does.

    axes 'keep': the OBJ importer with forward_axis='Y', up_axis='Z', which leaves the
    file's coordinates as they are, so the record's matrices hold in Blender unchanged;
    'default': the importer's default conversion (Y up -> Z up), which turns the mesh and
    not the camera: the view breaks (the test shows it).
    """
    import bpy
    from mathutils import Matrix

    bpy.ops.wm.read_factory_settings(use_empty=True)
    if axes == "keep":
        bpy.ops.wm.obj_import(filepath=path, forward_axis="Y", up_axis="Z")
    else:
        bpy.ops.wm.obj_import(filepath=path)
    with open(record_path) as handle:
        record = json.load(handle)["camera"]
    data = bpy.data.cameras.new("aobake_view")
    data.sensor_fit = "VERTICAL"
    data.angle_y = math.radians(record["fov_y_deg"])
    data.clip_start, data.clip_end = record["near"], record["far"]
    cam = bpy.data.objects.new("aobake_view", data)
    bpy.context.scene.collection.objects.link(cam)
    # Blender's camera looks down its -Z with +Y up: aobake's view space, so the camera's
    # world matrix is inverse(world_to_view) as it is
    cam.matrix_world = Matrix(record["world_to_view"]).inverted()
    data["width"], data["height"] = record["width"], record["height"]
    with tempfile.TemporaryDirectory() as work:  # reuse camera()'s report on a saved file
        saved = os.path.join(work, "scene.blend")
        bpy.ops.wm.save_as_mainfile(filepath=saved)
        return camera(saved, points, blend=True)


def _ao_setup(scene, meshes, distance: float, smooth: bool = False):
    import bpy

    _unclipped(scene.camera, meshes)
    for obj in meshes:  # the AO pass uses the shading normal: make it the geometric one
        for polygon in obj.data.polygons:  # (smooth: the pitfall, for docs/renderers.md)
            polygon.use_smooth = smooth
    world = scene.world or bpy.data.worlds.new("aobake_world")
    scene.world = world
    world.light_settings.distance = distance
    layer = scene.view_layers[0]
    layer.use_pass_ambient_occlusion = True
    layer.use_pass_z = True  # Cycles' depth: aobake's `depth` (along the view axis)
    scene.render.film_transparent = True  # alpha = coverage
    settings = scene.render.image_settings
    if hasattr(settings, "media_type"):  # Blender 5: multi-layer is a media type
        settings.media_type = "MULTI_LAYER_IMAGE"
    settings.file_format = "OPEN_EXR_MULTILAYER"
    settings.color_depth = "32"
    scene.view_settings.view_transform = "Standard"  # EXR passes are linear anyway


def _outputs(out: str, renders: int) -> list:
    """``out`` itself for one render, else out with _0, _1, ... before its suffix."""
    if renders == 1:
        return [out]
    stem, dot, suffix = out.rpartition(".")
    return [f"{stem}_{k}{dot}{suffix}" for k in range(renders)]


def cycles(path: str, out: str, samples: int, seed: int, pixel_filter: str,
           distance: float, threads: int, renders: int = 1, cheap: bool = False,
           smooth: bool = False) -> dict:
    """Render the AO pass with Cycles on the CPU into the multi-layer EXR ``out``; with
    ``renders`` > 1, that many independent images (seeds seed, seed + 1, ...) into
    out_0.exr, out_1.exr, ... (one import for all).  cheap: the Combined pass Cycles always
    renders beside it made as cheap as it goes (no bounces, a black world), for timing."""
    import bpy

    scene, _, meshes = _import(path)
    _ao_setup(scene, meshes, distance, smooth)
    scene.render.engine = "CYCLES"
    c = scene.cycles
    if cheap:
        c.max_bounces = 0
        scene.world.use_nodes = False
        scene.world.color = (0.0, 0.0, 0.0)
    c.device = "CPU"
    c.samples = samples
    c.use_adaptive_sampling = False
    c.use_denoising = False
    if pixel_filter == "box":
        c.pixel_filter_type = "BOX"  # one pixel wide whatever filter_width says
    else:  # centre sampling: a filter far narrower than the pixel
        c.pixel_filter_type = "BLACKMAN_HARRIS"
        c.filter_width = 0.01
    scene.render.threads_mode = "FIXED"
    scene.render.threads = threads
    seconds, cpu, files = [], [], _outputs(out, renders)
    for k, name in enumerate(files):
        c.seed = seed + k
        scene.render.filepath = name
        clock, used = time.perf_counter(), time.process_time()
        bpy.ops.render.render(write_still=True)
        seconds.append(time.perf_counter() - clock)
        cpu.append(time.process_time() - used)
    return {"engine": "CYCLES", "seconds": seconds, "cpu_s": cpu, "samples": samples,
            "seed": seed, "filter": pixel_filter, "threads": threads, "out": files}


def eevee(path: str, out: str, samples: int, distance: float) -> dict:
    """Render the AO pass with EEVEE (horizon scan in screen space: not a ray-traced AO)."""
    import bpy

    scene, _, meshes = _import(path)
    _ao_setup(scene, meshes, distance)
    engines = {item.identifier for item in
               bpy.types.RenderSettings.bl_rna.properties["engine"].enum_items}
    scene.render.engine = "BLENDER_EEVEE_NEXT" if "BLENDER_EEVEE_NEXT" in engines \
        else "BLENDER_EEVEE"
    scene.eevee.taa_render_samples = samples
    scene.render.filepath = out
    clock = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    return {"engine": scene.render.engine, "seconds": time.perf_counter() - clock,
            "samples": samples, "out": out}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("what", choices=["camera", "camera-record", "cycles", "eevee"])
    parser.add_argument("gltf")
    parser.add_argument("out", nargs="?", help="the EXR to write; camera-record: the "
                                                 "camera record (<out>.camera.json)")
    parser.add_argument("--axes", choices=["keep", "default"], default="keep",
                        help="camera-record: the OBJ importer's axes")
    parser.add_argument("--samples", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--filter", choices=["box", "center"], default="box")
    parser.add_argument("--distance", type=float, default=1e6,
                        help="AO distance (the view's --max-distance; default: unbounded "
                             "for scenes much smaller than 1e6 units)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--bench", action="store_true",
                        help="Cycles: no bounces and a black world (the Combined pass it "
                             "renders anyway made cheap), for timing the AO pass")
    parser.add_argument("--smooth", action="store_true",
                        help="Cycles: smooth shading (what not to do: the AO pass then uses "
                             "interpolated normals, not the view's geometric one)")
    parser.add_argument("--renders", type=int, default=1,
                        help="independent images (seeds seed, seed + 1, ...): out_0, ...")
    args = parser.parse_args(argv)
    try:
        if args.what == "camera":
            result = camera(args.gltf)
        elif args.what == "camera-record":
            result = camera_from_record(args.gltf, args.out, args.axes)
        elif args.what == "cycles":
            result = cycles(args.gltf, args.out, args.samples, args.seed, args.filter,
                            args.distance, args.threads, args.renders, args.bench,
                            args.smooth)
        else:
            result = eevee(args.gltf, args.out, args.samples, args.distance)
        import bpy

        result.update(ok=True, blender=bpy.app.version_string)
    except Exception as error:  # reported as one JSON line, for the test to show
        print(json.dumps({"ok": False, "error": f"{type(error).__name__}: {error}"}))
        return 1
    print(json.dumps(result, default=lambda x: None if isinstance(x, float) and
                     not math.isfinite(x) else str(x)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
