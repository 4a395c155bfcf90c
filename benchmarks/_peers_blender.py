"""Blender Cycles' AO bake of one mesh, for bench_peers.py (run as its own process).

    python benchmarks/_peers_blender.py MESH --samples N --out OUT.npz [--threads 2]
    python benchmarks/_peers_blender.py --version

Needs ``bpy`` (``pip install bpy==5.0.1``: Python 3.11 only).  Blender runs in a process of
its own because bpy bundles its own Embree and TBB, and because one bake per process lets
bench_peers stop a row early and keeps Blender's memory out of the other measurements.

What it does, in an empty scene (factory settings, no default cube):

* imports the OBJ with Blender's own importer, axes untouched (forward Y, up Z), so the
  vertex coordinates are the file's (the caller maps them back to its own vertex order);
* shades every face smooth, so each face corner is baked with the vertex normal (Blender's
  own, angle-weighted) rather than its face's normal;
* adds a float colour attribute on the CORNER domain and makes it the active one;
* bakes Cycles' AO pass into it (``bake(type='AO', target='VERTEX_COLORS')``) on the CPU with
  ``render.threads_mode='FIXED'`` and ``render.threads``, ``cycles.samples = N``, no
  denoising, no adaptive sampling, and the world's AO distance
  (``world.light_settings.distance``, 10 units by default) set to 1e10: infinite for any
  mesh here;
* averages the corners of each vertex (by vertex index) into a per-vertex value.

Cycles bakes one value per face corner, each at the vertex position with N samples of its
own, so a vertex with k corners gets k * N AO rays: the caller counts corners x samples.

OUT.npz: ``co`` (v, 3) float32 Blender's vertex coordinates, ``ao`` (v,) float64 corner
average (1 = open, NaN for a vertex with no corner), ``corners`` (v,) int32, and scalars
``samples``, ``bake_s`` (the bake operator call), ``import_s`` (the OBJ import),
``bpy_import_s`` (``import bpy``), ``version``.
"""

from __future__ import annotations

import argparse
import sys
import time

#: the world's AO distance used: effectively infinite for any mesh in the benchmark
AO_DISTANCE = 1e10


def bake(mesh: str, samples: int, threads: int) -> dict:
    start = time.perf_counter()
    import bpy
    import numpy as np

    bpy_import_s = time.perf_counter() - start
    from _blender_scene import import_one_mesh

    obj, import_s = import_one_mesh(mesh)
    me = obj.data
    me.shade_smooth()
    attr = me.color_attributes.new("AO", "FLOAT_COLOR", "CORNER")
    me.color_attributes.active_color = attr

    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.render.threads_mode = "FIXED"
    scene.render.threads = threads
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
    scene.world.light_settings.distance = AO_DISTANCE
    scene.render.bake.target = "VERTEX_COLORS"

    start = time.perf_counter()
    result = bpy.ops.object.bake(type="AO", target="VERTEX_COLORS")
    bake_s = time.perf_counter() - start
    if "FINISHED" not in result:
        raise SystemExit(f"{mesh}: Blender's bake returned {result}")

    n_loops, n_verts = len(me.loops), len(me.vertices)
    color = np.empty(n_loops * 4, dtype=np.float32)
    attr.data.foreach_get("color", color)  # FLOAT_COLOR: linear values, as baked
    loop_vertex = np.empty(n_loops, dtype=np.int32)
    me.loops.foreach_get("vertex_index", loop_vertex)
    co = np.empty(n_verts * 3, dtype=np.float32)
    me.vertices.foreach_get("co", co)
    corners = np.bincount(loop_vertex, minlength=n_verts)
    total = np.bincount(loop_vertex, weights=color.reshape(-1, 4)[:, 0].astype(np.float64),
                        minlength=n_verts)
    with np.errstate(invalid="ignore", divide="ignore"):
        ao = np.where(corners > 0, total / np.maximum(corners, 1), np.nan)
    return {"co": co.reshape(-1, 3), "ao": ao, "corners": corners.astype(np.int32),
            "samples": samples, "bake_s": bake_s, "import_s": import_s,
            "bpy_import_s": bpy_import_s, "version": bpy.app.version_string}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("mesh", nargs="?")
    parser.add_argument("--samples", type=int)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out")
    parser.add_argument("--version", action="store_true", help="print bpy's version and exit")
    args = parser.parse_args(argv)
    if args.version:
        import bpy

        print(bpy.app.version_string)
        return
    if not (args.mesh and args.samples and args.out):
        parser.error("MESH, --samples and --out are required")
    import numpy as np

    out = bake(args.mesh, args.samples, args.threads)
    np.savez(args.out, **out)


if __name__ == "__main__":
    sys.exit(main())
