"""A set dressed with N copies of one asset, one copy baked (issue 34): peak memory and time
traced as Embree instances against flattened, as N grows.

    python benchmarks/bench_instances.py [--mesh ../shared/meshes/ogre.obj]
        [--instanced 1 100 1000] [--flattened 1 10 50] [--rays 256] [--threads 2]
        [--atlas 9 100 1000 --atlas-baked 9 --resolution 1024 --atlas-rays 16]

Each row writes a GLB holding the mesh once and N nodes on a square grid (spacing 1.05x the
mesh's footprint, a seeded turn about the up axis each: neighbours close enough to shade
each other), then bakes in a fresh process ``aobake SET.glb --bake NODE`` the node nearest
the middle, through the library (``load_scene(path, bake=...)`` then ``aobake.api.run``),
with ``--instances trace`` (Embree instances: one child scene of the mesh) or ``flatten``
(every copy's triangles in one Embree scene, the flattened scene's bake).  Printed per
row: the triangles placed, the peak RSS of the process (VmHWM) and its RSS once loaded,
load / occluders / trace / wall seconds, and the other work on the machine while it ran
(``_machine.Load``: rows above 0.3 cores are marked).

``--atlas N ...``: a lightmap of the set instead (``aobake SET.glb --bake ... --out
set.exr``: one region per baked instance, ``aobake.targets.texels.instanced``), the
``--atlas-baked`` nodes nearest the middle baked into one ``--resolution`` image at
``--atlas-rays`` rays per texel, traced as Embree instances: the mesh's one new atlas
(unwrap), the set's rasterising, tracing and the peak RSS, as the copies grow.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))

CHILD = textwrap.dedent("""
    import json, sys, time
    from aobake import api
    from aobake.scene import load_scene
    from aobake.settings import BakeConfig
    from aobake.targets import TARGETS

    def status(key):
        with open("/proc/self/status") as lines:
            return next(int(line.split()[1]) for line in lines if line.startswith(key))

    path, node, mode, rays, threads = sys.argv[1:6]
    clock = time.perf_counter()
    scene = load_scene(path, bake=(node,))
    loaded = time.perf_counter() - clock
    rss_loaded = status("VmRSS:")
    config = BakeConfig(rays=int(rays), bake=(node,), instances=mode)
    result = api.run(config, scene, TARGETS["vertices"](), threads=int(threads))
    wall = time.perf_counter() - clock
    timings = result.report["timings"]
    print(json.dumps({"load_s": loaded, "occluders_s": timings["occluders_s"],
                      "trace_s": timings["trace_s"], "wall_s": wall,
                      "rss_loaded_mib": rss_loaded / 1024, "peak_mib": status("VmHWM:") / 1024,
                      "vertices": len(result.positions), "ao_mean": float(result.ao.mean()),
                      "traced_as": result.report["parameters"]["instances"]["traced_as"]}))
""")


ATLAS_CHILD = textwrap.dedent("""
    import json, sys, time
    from aobake import api
    from aobake.settings import BakeConfig
    from aobake.targets import TARGETS

    def status(key):
        with open("/proc/self/status") as lines:
            return next(int(line.split()[1]) for line in lines if line.startswith(key))

    path, nodes, rays, threads, resolution = sys.argv[1:6]
    nodes = tuple(nodes.split(","))
    clock = time.perf_counter()
    config = BakeConfig(rays=int(rays), bake=nodes, resolution=int(resolution))
    result = api.run(config, path, TARGETS["texels"](), threads=int(threads))
    wall = time.perf_counter() - clock
    timings, texture = result.report["timings"], result.report["texture"]
    print(json.dumps({"unwrap_s": timings["unwrap_s"], "raster_s": timings["rasterize_s"],
                      "trace_s": timings["trace_s"], "wall_s": wall,
                      "peak_mib": status("VmHWM:") / 1024,
                      "regions": len(texture["instances"]["placed"]),
                      "density": texture["instances"]["texels_per_unit"],
                      "covered": texture["texels_covered"]}))
""")


def nearest(n, k, spacing=1.0) -> list:
    """The names of the ``k`` nodes of ``write_set``'s grid of ``n`` nearest its middle."""
    side = math.ceil(math.sqrt(n))
    where = [((k_ // side - (side - 1) / 2) ** 2 + (k_ % side - (side - 1) / 2) ** 2, k_)
             for k_ in range(n)]
    return [f"ogre_{k_:04d}" for _, k_ in sorted(where)[:k]]


def write_set(path, vertices, faces, n, seed=0) -> str:
    """A GLB of the mesh once and ``n`` nodes ogre_0000.. on a grid; the name of the node
    nearest the middle."""
    from gltf_scenes import write_instanced

    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    spacing = 1.05 * float(max(hi[0] - lo[0], hi[2] - lo[2]))
    side = math.ceil(math.sqrt(n))
    rng = np.random.default_rng(seed)
    nodes, middle, best = [], None, math.inf
    for k in range(n):
        row, col = divmod(k, side)
        x, z = (col - (side - 1) / 2) * spacing, (row - (side - 1) / 2) * spacing
        yaw = rng.uniform(0, 2 * math.pi)
        nodes.append({"name": f"ogre_{k:04d}", "mesh": 0, "translation": [x, 0.0, z],
                      "rotation": [0.0, math.sin(yaw / 2), 0.0, math.cos(yaw / 2)]})
        if x * x + z * z < best:
            middle, best = f"ogre_{k:04d}", x * x + z * z
    write_instanced(path, [{"name": "ogre", "vertices": vertices, "faces": faces}], nodes)
    return middle


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mesh", default=str(ROOT.parent / "shared" / "meshes" / "ogre.obj"))
    parser.add_argument("--instanced", type=int, nargs="*", default=[1, 100, 1000])
    parser.add_argument("--flattened", type=int, nargs="*", default=[1, 10, 50])
    parser.add_argument("--rays", type=int, default=256)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--atlas", type=int, nargs="*", default=[])
    parser.add_argument("--atlas-baked", type=int, default=9)
    parser.add_argument("--atlas-rays", type=int, default=16)
    parser.add_argument("--resolution", type=int, default=1024)
    args = parser.parse_args()
    if args.atlas:
        return atlas_rows(args)
    from _machine import LOAD_THRESHOLD, Load, cpu

    from aobake.scene import load_scene

    mesh = load_scene(args.mesh)
    print(f"{args.mesh}: {len(mesh.faces)} triangles, {len(mesh.vertices)} vertices; "
          f"{args.rays} rays, {args.threads} threads; {cpu()}")
    print("| traced as | copies | triangles placed | peak RSS MiB | RSS loaded MiB | load s "
          "| occluders s | trace s | wall s | other work (cores) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    rows = [("trace", n) for n in args.instanced] + [("flatten", n) for n in args.flattened]
    written = {}
    with tempfile.TemporaryDirectory() as folder:
        for mode, n in rows:
            path = Path(folder) / f"set_{n}.glb"
            if n not in written:  # one file per count, for both ways of tracing it
                written[n] = write_set(path, mesh.vertices, mesh.faces, n)
            node = written[n]
            with Load() as load:
                out = subprocess.run([sys.executable, "-c", CHILD, str(path), node, mode,
                                      str(args.rays), str(args.threads)],
                                     capture_output=True, text=True)
            if out.returncode:
                print(f"| {mode} | {n} | failed: {out.stderr.strip().splitlines()[-1]} |")
                continue
            row = json.loads(out.stdout.strip().splitlines()[-1])
            busy = f"{load.others:.2f}" + (" (not comparable)" if load.others > LOAD_THRESHOLD
                                           else "")
            print(f"| {'Embree instances' if mode == 'trace' else 'flattened'} | {n} | "
                  f"{n * len(mesh.faces):,} | {row['peak_mib']:.0f} | {row['rss_loaded_mib']:.0f} | "
                  f"{row['load_s']:.2f} | {row['occluders_s']:.2f} | {row['trace_s']:.2f} | "
                  f"{row['wall_s']:.2f} | {busy} |", flush=True)


def atlas_rows(args) -> None:
    from _machine import LOAD_THRESHOLD, Load, cpu

    from aobake.scene import load_scene

    mesh = load_scene(args.mesh)
    print(f"{args.mesh}: {len(mesh.faces)} triangles; lightmap {args.resolution}^2 of the "
          f"{args.atlas_baked} copies nearest the middle, {args.atlas_rays} rays per texel, "
          f"{args.threads} threads; {cpu()}")
    print("| copies | baked | unwrap s | raster s | trace s | wall s | peak RSS MiB | "
          "texels per unit | texels covered | other work (cores) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        for n in args.atlas:
            path = Path(folder) / f"set_{n}.glb"
            write_set(path, mesh.vertices, mesh.faces, n)
            nodes = nearest(n, min(n, args.atlas_baked))
            with Load() as load:
                out = subprocess.run([sys.executable, "-c", ATLAS_CHILD, str(path),
                                      ",".join(nodes), str(args.atlas_rays), str(args.threads),
                                      str(args.resolution)], capture_output=True, text=True)
            if out.returncode:
                print(f"| {n} | failed: {out.stderr.strip().splitlines()[-1]} |")
                continue
            row = json.loads(out.stdout.strip().splitlines()[-1])
            busy = f"{load.others:.2f}" + (" (not comparable)" if load.others > LOAD_THRESHOLD
                                           else "")
            print(f"| {n} | {row['regions']} | {row['unwrap_s']:.2f} | {row['raster_s']:.2f} | "
                  f"{row['trace_s']:.2f} | {row['wall_s']:.2f} | {row['peak_mib']:.0f} | "
                  f"{row['density']:.4g} | {row['covered']:,} | {busy} |", flush=True)


if __name__ == "__main__":
    main()
