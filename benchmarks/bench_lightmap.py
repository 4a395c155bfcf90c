"""Lightmap throughput: texels/s, rays/s, ratio to a bare embreex loop on the same rays,
and where the time goes (unwrap, rasterise, trace, write).

    python benchmarks/bench_lightmap.py [--resolution 1024] [--rays 256] [--threads 2] [--padding P]
                                        [--phases-only]

First table (in-process bakes against the bare loop): ../shared/meshes/spot.obj (baked into
the UVs it ships) and ../shared/meshes/stanford-bunny.obj (no UVs: a new atlas).  Also
printed: the share of the image the surface covers, the charts and the spread of their texel
densities (p95 / p5) from the report; benchmarks/bench_atlas.py compares atlases in more
detail.

Second table (``--phases-only``: this one alone): the ``aobake`` command as a user runs it
(its own process, EXR and report written, the atlas mesh beside it when it is new) on spot,
the bunny and the ogre, one after the other, and its phases from the report: load, unwrap
(+ the own-UV check), rasterise, trace, seams, splat (gutters, intervals, the rest of
splat+dilate), write, and import/other (the process's wall time outside the bake and the
write: interpreter start, imports, the CLI), with the share of the wall time that is not
tracing.  Nothing of the bake runs beside the tracing (the seam system is made after it,
beside the splatting), so the trace phase is tracing alone and the share counts every
second of the rest.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_throughput import bare_loop  # noqa: E402

from aobake.api import bake_texels  # noqa: E402
from aobake.settings import DEFAULTS, BakeConfig  # noqa: E402
from aobake.outputs.texture import write_texture  # noqa: E402
from aobake.scene import load_scene  # noqa: E402
from aobake.targets.texels.raster import rasterize  # noqa: E402
from aobake.targets.texels.surface import surface_points  # noqa: E402
from aobake.occluders import build as build_occluders  # noqa: E402
from aobake.trace import DEFAULT_CHUNK_RAYS, Tracer  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "meshes"


def case(path: Path, unwrap: str, args):
    config = BakeConfig(rays=args.rays)
    start = time.perf_counter()
    result = bake_texels(path, config, resolution=args.resolution, padding=args.padding,
                         texel_samples=args.texel_samples, threads=args.threads, unwrap=unwrap)
    bake_wall = time.perf_counter() - start
    with tempfile.TemporaryDirectory() as tmp:
        clock = time.perf_counter()
        write_texture(Path(tmp, "ao.exr"), result, {"bench": True})
        write_s = time.perf_counter() - clock
    t = result.report["timings"]
    rays = result.report["rays_cast"]
    # The same rays through a bare embreex loop: rebuild the same sample points.
    scene = load_scene(path)
    k = args.texel_samples
    tracer = Tracer(scene, config, build_occluders(scene, config), rays=-(-config.rays // k))
    atlas = result.atlas
    # Atlas UVs per face corner (the atlas faces follow the scene's face order).
    samples = rasterize(atlas.uv, atlas.faces, args.resolution, args.resolution, k, config.seed)
    points, normals, _ = surface_points(scene.vertices, scene.vertex_normals, scene.faces, samples)
    # Tracing is compared with the bare loop's tracing alone: the bake builds its
    # embreex scene before this phase (counted in "load", as the bare loop's build is).
    n_bare, _, t_bare = bare_loop(tracer, points, normals, np.arange(len(points)), args.threads,
                                  DEFAULT_CHUNK_RAYS)
    total = bake_wall + write_s
    return {
        "mesh": path.name,
        "atlas": result.report["texture"]["atlas"],
        "texels": result.report["texture"]["texels_covered"],
        "texels_per_s": result.report["texture"]["texels_covered"] / total,
        "trace_mrays": rays / t["trace_s"] / 1e6,
        "bare_mrays": n_bare / t_bare / 1e6,
        "unwrap_s": t["unwrap_s"],
        "check_s": t["uv_check_s"],
        "load_s": t["load_s"],
        "raster_s": t["rasterize_s"],
        "trace_s": t["trace_s"],
        "post_s": t["splat_dilate_s"],
        "write_s": write_s,
        "total_s": total,
        "stderr_p95": result.report["texture"].get("ao_stderr", {}).get("p95", float("nan")),
        "covered": result.report["texture"]["covered_fraction"],
        "charts": result.report["texture"]["chart_density"]["islands"],
        "spread": result.report["texture"]["chart_density"]["spread"],
    }


#: the phases of the CLI table: (column, report keys summed)
PHASES = [("load", ("load_s",)), ("unwrap", ("unwrap_s", "uv_check_s")),
          ("rasterize", ("rasterize_s",)), ("trace", ("trace_s",)), ("seams", ("seams_s",))]


def cli_phases(path: Path, args) -> dict:
    """One run of the ``aobake`` command on ``path`` (EXR + report in a temporary folder):
    phase name -> seconds, from its report and its wall time."""
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp, "report.json")
        command = [sys.executable, "-m", "aobake", str(path), "--out", str(Path(tmp, "ao.exr")),
                   "--report", str(report), "--quiet", "--resolution", str(args.resolution),
                   "--rays", str(args.rays), "--texel-samples", str(args.texel_samples),
                   "--threads", str(args.threads), "--padding", str(args.padding)]
        # As a user's Python runs it: with bytecode caching (a sandbox may set
        # PYTHONDONTWRITEBYTECODE, which recompiles every aobake module at each start).
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        clock = time.perf_counter()
        subprocess.run(command, check=True, cwd=Path(__file__).resolve().parents[1], env=env)
        wall = time.perf_counter() - clock
        data = json.loads(report.read_text())
    t = data["timings"]
    row = {name: sum(t.get(key, 0.0) for key in keys) for name, keys in PHASES}
    row["splat"] = t["splat_dilate_s"] - t.get("seams_s", 0.0)
    row["write"] = t["write_s"]
    row["import/other"] = wall - t["total_s"] - t["write_s"]
    row["total"] = wall
    row["atlas"] = data["texture"]["atlas"]
    return row


def print_phases(args) -> None:
    """The CLI phase table for spot (own UVs), the bunny and the ogre (new atlases)."""
    meshes = [SHARED / name for name in ("spot.obj", "stanford-bunny.obj", "ogre.obj")]
    # untimed: the first run of a session compiles the bytecode and reads the meshes from disk
    warm = argparse.Namespace(**{**vars(args), "rays": 4, "resolution": 64})
    for m in meshes:
        if m.is_file():
            m.read_bytes()
    if meshes[0].is_file():
        cli_phases(meshes[0], warm)
    rows = [(m.name, cli_phases(m, args)) for m in meshes if m.is_file()]
    names = [name for name, _ in PHASES] + ["splat", "write", "import/other", "total"]
    print(f"aobake CLI, resolution {args.resolution}^2, padding {args.padding}, {args.rays} rays "
          f"per texel over {args.texel_samples} samples, {args.threads} threads (seconds)\n")
    print("| mesh | atlas | " + " | ".join(names) + " | non-trace share |")
    print("|" + "---|" * (len(names) + 3))
    for mesh, r in rows:
        share = 1.0 - r["trace"] / r["total"]
        print(f"| {mesh} | {r['atlas']} | " + " | ".join(f"{r[n]:.2f}" for n in names)
              + f" | {share:.1%} |")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolution", type=int, default=1024)
    parser.add_argument("--rays", type=int, default=256)
    parser.add_argument("--texel-samples", type=int, default=4)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--padding", type=int, default=DEFAULTS["padding"])
    parser.add_argument("--phases-only", action="store_true",
                        help="only the CLI phase table (spot, bunny, ogre)")
    args = parser.parse_args()
    if args.phases_only:
        print_phases(args)
        return
    # spot's own UVs (10 faces reach slightly outside [0, 1], so "auto" would
    # re-unwrap; "never" bakes them as shipped), the bunny through xatlas.
    cases = [(SHARED / "spot.obj", "never"), (SHARED / "stanford-bunny.obj", "auto")]
    if not all(m.is_file() for m, _ in cases):
        sys.exit("benchmarks need ../shared/meshes (spot.obj, stanford-bunny.obj)")
    rows = [case(m, unwrap, args) for m, unwrap in cases]
    print(f"resolution {args.resolution}^2, padding {args.padding}, {args.rays} rays per texel over "
          f"{args.texel_samples} samples, {args.threads} threads\n")
    print("| mesh | atlas | charts | covered | density p95/p5 | texels | texels/s | trace Mrays/s | "
          "bare Mrays/s | trace/bare | load+BVH s | UV check s | unwrap s | rasterise s | trace s | "
          "splat+dilate s | write s | total s | non-trace share | p95 stderr |")
    print("|" + "---|" * 20)
    for r in rows:
        # Everything that is not loading the mesh / building the BVH or tracing.
        other = r["check_s"] + r["unwrap_s"] + r["raster_s"] + r["post_s"] + r["write_s"]
        print(f"| {r['mesh']} | {r['atlas']} | {r['charts']} | {r['covered']:.1%} | "
              f"{r['spread']:.3f} | {r['texels']} | {r['texels_per_s']:.0f} | "
              f"{r['trace_mrays']:.2f} | {r['bare_mrays']:.2f} | {r['trace_mrays'] / r['bare_mrays']:.2f} | "
              f"{r['load_s']:.2f} | {r['check_s']:.2f} | {r['unwrap_s']:.2f} | {r['raster_s']:.2f} | {r['trace_s']:.2f} | {r['post_s']:.2f} | "
              f"{r['write_s']:.2f} | {r['total_s']:.2f} | {other / r['total_s']:.0%} | "
              f"{r['stderr_p95']:.4f} |")
    print()
    print_phases(args)


if __name__ == "__main__":
    main()
