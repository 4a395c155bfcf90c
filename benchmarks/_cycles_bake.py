"""Blender Cycles' AO bake of a mesh into a float image, for bench_renderers_lightmap.py
(run as its own process with a Python that has ``bpy``).

    BPY_PYTHON benchmarks/_cycles_bake.py MESH.obj --out OUT.npz --size 1024 --samples N
        [--seed K] [--threads 2] [--distance D] [--warmup] [--shading smooth|flat]
        [--terminator-offset 0]
    BPY_PYTHON benchmarks/_cycles_bake.py --version

Needs ``bpy`` (``pip install bpy==5.0.1``: Python 3.11 only; docs/renderers.md).  One bake
per process, so no row inherits another's state and Blender's memory stays out of the
other measurements.  What it does, in an empty scene (factory settings):

* imports the OBJ with Blender's importer, axes untouched (forward Y, up Z): the mesh's
  ``vt`` become its UV map (v up, as OBJ's), its ``vn`` its custom normals;
* shades every face smooth (``--shading smooth``, the default): Cycles' AO pass samples the
  hemisphere of the *shading* normal, which is then the file's ``vn`` interpolated over the
  triangle, as aobake's lightmap samples take the interpolated vertex normal
  (docs/conventions.md, Lightmaps). ``--shading flat`` is the face normal (for a mesh
  without ``vn``, compared with aobake's ``--normals`` of its faces: not used here);
* gives it one material whose active node is an Image Texture holding a new float image
  of ``--size`` (RGBA, 32-bit float, Non-Color: the baked values are written unchanged),
  filled with -1 and baked without clearing, so a texel still at -1 was not baked (the
  alpha channel cannot tell: Cycles writes alpha 1 to every texel);
* sets the object's ``shadow_terminator_geometry_offset`` to ``--terminator-offset``
  (default 0; Blender's own default is 0.1): for a grazing ray off a smooth-shaded
  triangle Cycles otherwise lifts the origin off the flat triangle towards the curved
  surface its normals describe, so rays that leave below the flat triangle's plane escape
  where aobake, tracing from the flat triangle, finds them blocked.  At 0.1 Cycles read
  the bunny lighter by +0.0016 on average (standard error 0.00005; 256^2, 256 samples);
  at 0, +0.00005 (0.00004);
* bakes Cycles' AO pass into it: ``bpy.ops.object.bake(type='AO')`` on the CPU, render
  threads FIXED at ``--threads``, ``cycles.samples`` = N, seed K, no adaptive sampling, no
  denoising, bake margin 0 (no gutter: the caller compares the texels both tools bake), and
  the world's AO distance (``world.light_settings.distance``) = ``--distance`` (default
  1e10: unbounded, aobake's default ``--max-distance inf``).

What Cycles computes per texel (Cycles' ``init_from_bake``): Blender rasterises each
triangle into the image with texel centres at ((x + 0.5) / W, (y + 0.5) / H) in UV (y up
from the bottom row), so a texel is baked when its centre lies in a triangle; sample 0 is
at that centre and every later one jittered uniformly over a box around it, retried
until it falls inside the same triangle.  The box is half a texel wide (+-0.25 texel:
Blender's bake differentials are half the barycentric derivatives per texel; measured by
baking the UV through an emission shader at 2 samples: offsets within +-0.25, standard
deviation 0.133 texel, 0.144 for a uniform +-0.25).  Each sample casts one AO ray,
cosine-distributed about the shading normal; the texel is the fraction that escape
(1 = open).  So a Cycles texel is the mean AO over the central quarter of the texel's
area, within its centre's triangle; aobake's is the mean over the whole covered texel,
every triangle.  Where AO varies linearly across the texel the two agree; the rest is a
difference of definitions that shrinks with the texel (bench_renderers_lightmap.py
measures it: its "floor").

``--warmup``: first an untimed 1-sample bake of the same object into a 64 x 64 image, so the
timed bake does not pay Cycles' one-time set-up in this process (its seconds are reported
as ``warmup_s``).

OUT.npz: ``ao`` (H, W) float32 the baked R channel (-1 where the bake wrote nothing),
``baked`` (H, W) bool (the texels it wrote), rows top first (aobake's convention:
Blender's row 0, the bottom, is flipped), and scalars ``bake_s`` (wall seconds of the bake call),
``bake_cpu_s`` (this process's CPU seconds over it, all threads), ``warmup_s``,
``import_s`` (the OBJ import), ``bpy_import_s`` (``import bpy``), ``samples``, ``seed``,
``threads``, ``version``, and ``info`` (a JSON string: the normals and shading found).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings

#: the AO distance for aobake's unbounded default: far beyond any mesh here
UNBOUNDED = 1e10
#: what the image holds before the bake: a texel still holding it was not baked
UNBAKED = -1.0


def _setup(mesh: str, size: int, distance: float, threads: int, shading: str,
           terminator: float):
    import bpy

    from _blender_scene import import_one_mesh

    obj, import_s = import_one_mesh(mesh)
    me = obj.data
    custom = bool(getattr(me, "has_custom_normals", False))
    # Cycles lifts a shadow ray's origin off a smooth-shaded triangle towards the curved
    # surface its normals describe, for grazing rays (the "shadow terminator" fix); aobake
    # traces from the flat triangle: matched by setting the lift to 0 (default 0.1)
    obj.shadow_terminator_geometry_offset = terminator
    if shading == "smooth":
        for polygon in me.polygons:
            polygon.use_smooth = True
    else:
        for polygon in me.polygons:
            polygon.use_smooth = False
    if not me.uv_layers:
        raise SystemExit(f"{mesh}: no UVs (bake an atlas with aobake --mesh-out first)")

    material = bpy.data.materials.new("aobake_bake")
    with warnings.catch_warnings():  # Blender 5: always true, deprecated, still needed in 4
        warnings.simplefilter("ignore", DeprecationWarning)
        material.use_nodes = True
    me.materials.clear()
    me.materials.append(material)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.render.threads_mode = "FIXED"
    scene.render.threads = threads
    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
    scene.world.light_settings.distance = distance
    bake = scene.render.bake
    bake.target = "IMAGE_TEXTURES"
    bake.save_mode = "INTERNAL"
    bake.margin = 0
    bake.use_clear = False  # texels the bake does not write keep the fill below
    info = {"custom_normals": custom, "shading": shading, "terminator_offset": terminator,
            "normals_domain": getattr(me, "normals_domain", None),
            "vertices": len(me.vertices), "triangles": sum(len(p.vertices) - 2
                                                          for p in me.polygons)}
    return scene, obj, material, import_s, info


def _image(material, name: str, size: int):
    """A new float image of ``size`` as the material's active Image Texture node."""
    import bpy

    import numpy as np

    image = bpy.data.images.new(name, size, size, alpha=True, float_buffer=True)
    image.colorspace_settings.name = "Non-Color"
    image.pixels.foreach_set(np.full(size * size * 4, UNBAKED, dtype=np.float32))
    nodes = material.node_tree.nodes
    for node in nodes:
        node.select = False
    node = nodes.new("ShaderNodeTexImage")
    node.image = image
    node.select = True
    nodes.active = node
    return image


def _bake(scene, samples: int, seed: int) -> tuple[float, float]:
    import bpy

    scene.cycles.samples = samples
    scene.cycles.seed = seed
    clock, used = time.perf_counter(), time.process_time()
    result = bpy.ops.object.bake(type="AO")
    seconds, cpu = time.perf_counter() - clock, time.process_time() - used
    if "FINISHED" not in result:
        raise SystemExit(f"Blender's bake returned {result}")
    return seconds, cpu


def bake(mesh: str, size: int, samples: int, seed: int, threads: int, distance: float,
         warmup: bool, shading: str, terminator: float = 0.0) -> dict:
    start = time.perf_counter()
    import bpy
    import numpy as np

    bpy_import_s = time.perf_counter() - start
    scene, obj, material, import_s, info = _setup(mesh, size, distance, threads, shading,
                                                  terminator)
    warmup_s = 0.0
    if warmup:
        small = _image(material, "aobake_warmup", 64)
        warmup_s = _bake(scene, 1, seed + 7919)[0]
        for node in list(material.node_tree.nodes):
            if node.type == "TEX_IMAGE":
                material.node_tree.nodes.remove(node)
        bpy.data.images.remove(small)
    image = _image(material, "aobake_ao", size)
    bake_s, bake_cpu_s = _bake(scene, samples, seed)

    pixels = np.empty(size * size * 4, dtype=np.float32)
    image.pixels.foreach_get(pixels)
    pixels = pixels.reshape(size, size, 4)[::-1]  # Blender's row 0 is the bottom
    return {"ao": np.ascontiguousarray(pixels[..., 0]),
            "baked": np.ascontiguousarray(pixels[..., 0] != UNBAKED),
            "bake_s": bake_s, "bake_cpu_s": bake_cpu_s, "warmup_s": warmup_s,
            "import_s": import_s, "bpy_import_s": bpy_import_s, "samples": samples,
            "seed": seed, "threads": threads, "version": bpy.app.version_string,
            "info": json.dumps(info)}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("mesh", nargs="?")
    parser.add_argument("--out")
    parser.add_argument("--size", type=int, default=1024)
    parser.add_argument("--samples", type=int)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--distance", type=float, default=UNBOUNDED)
    parser.add_argument("--warmup", action="store_true")
    parser.add_argument("--shading", choices=["smooth", "flat"], default="smooth")
    parser.add_argument("--terminator-offset", type=float, default=0.0,
                        help="the object's shadow_terminator_geometry_offset (Blender's "
                             "default 0.1; 0 traces from the flat triangle, as aobake)")
    parser.add_argument("--version", action="store_true", help="print bpy's version and exit")
    args = parser.parse_args(argv)
    if args.version:
        import bpy

        print(bpy.app.version_string)
        return 0
    if not (args.mesh and args.samples and args.out):
        parser.error("MESH, --samples and --out are required")
    import numpy as np

    out = bake(args.mesh, args.size, args.samples, args.seed, args.threads, args.distance,
               args.warmup, args.shading, args.terminator_offset)
    np.savez(args.out, **out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
