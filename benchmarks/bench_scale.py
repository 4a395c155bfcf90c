"""Past one process: an asset library and one large scene on threads, processes and Dask.

    python benchmarks/bench_scale.py [--assets 50] [--rays 128] [--large-copies 30]
        [--large-rays 16] [--cli-assets 10] [--json OUT.json] [--skip library,large,cli]

What it measures (docs/scale.md has the table and what it means):

* **library**: ``--assets`` generated meshes of mixed size (icospheres, tori, cylinders,
  capsules, subdivided boxes: 12 to ~33k vertices, plus ../shared/meshes when present),
  baked per vertex by ``aobake.batch`` in this process on threads (2), processes (2) and
  Dask with 1 and 2 workers (one LocalCluster per run, its start timed apart): seconds,
  rays/s, and how many assets reached the cluster (the cost model finishes an asset with
  less than MIN_ITEM_SECONDS of tracing in the parent); and ``dask-ship``: 2 workers with
  every asset sent to the cluster as one item (what that shortcut saves).
* **large**: the Stanford bunny tiled ``--large-copies`` times (30: 2.1M triangles, 1.08M
  vertices; a generated torus grid without the bunny), baked per vertex on 1 and 2 threads
  and on Dask with 1 and 2 workers (the same bits: checked): seconds, rays/s, the split,
  and where the Dask run's time went: the pilot here, the job's scatter (timed apart, the
  pickled scene's size), each worker's preparation (unpickling, the occluders, the
  method), the workers' tracing, and the rest (scheduling, result gathering, waiting) as
  a fraction of the work.
* **cli**: the first ``--cli-assets`` assets baked by one ``aobake`` process each against
  one ``python -m aobake.cli.batch`` process for all of them (what batch saves per asset:
  the interpreter's start and the imports).

The machine is shared (2 cores): the load average is printed before and after; compare
rows of one run, not runs.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import aobake  # noqa: E402
from aobake import batch  # noqa: E402
from aobake.executors import dask as dask_executor  # noqa: E402

SHARED = ROOT.parent / "shared" / "meshes"


def library(folder: Path, count: int) -> list:
    """``count`` meshes of mixed size written as PLY into ``folder``: [(path, vertices)]."""
    import trimesh

    makers = [
        lambda i: trimesh.creation.icosphere(1 + i % 5),
        lambda i: trimesh.creation.torus(1.0, 0.3 + 0.02 * (i % 5),
                                         major_sections=16 * (1 + i % 8),
                                         minor_sections=8 * (1 + i % 8)),
        lambda i: trimesh.creation.cylinder(0.5, 2.0, sections=16 * (1 + i % 6)),
        lambda i: trimesh.creation.capsule(1.5, 0.4, count=[8 * (1 + i % 6)] * 2),
        lambda i: trimesh.creation.box().subdivide_loop(i % 5),
    ]
    out = []
    extra = [p for p in sorted(SHARED.glob("*.obj")) if p.name != "ogre.obj"]
    for i in range(count):
        path = folder / f"asset_{i:03d}.ply"
        if i < len(extra):
            mesh = trimesh.load(extra[i], force="mesh", process=False)
        else:
            mesh = makers[i % len(makers)](i // len(makers))
        mesh.export(path)
        out.append((path, len(mesh.vertices)))
    return out


def large_scene(path: Path, copies: int):
    """The bunny (or a torus) tiled on a grid ``copies`` times, written as binary PLY."""
    import trimesh

    if (SHARED / "stanford-bunny.obj").is_file():
        base = trimesh.load(SHARED / "stanford-bunny.obj", force="mesh", process=False)
    else:
        base = trimesh.creation.torus(1.0, 0.3, major_sections=256, minor_sections=128)
    step = base.extents * 1.1
    side = int(np.ceil(np.sqrt(copies)))
    parts = []
    for k in range(copies):
        tile = base.copy()
        tile.apply_translation([step[0] * (k % side), 0.0, step[2] * (k // side)])
        parts.append(tile)
    mesh = trimesh.util.concatenate(parts)
    mesh.export(path)
    return len(mesh.vertices), len(mesh.faces)


def run_library(meshes, out_root: Path, rays: int) -> list:
    rows = []
    assets = batch.find_assets([p for p, _ in meshes], out_root / "unused", "npz")
    settings = {"rays": rays}
    cases = [("threads", 2, {"executor": "threads", "threads": 2}),
             ("processes", 2, {"executor": "processes", "workers": 2}),
             ("dask", 1, {"executor": "dask", "workers": 1}),
             ("dask", 2, {"executor": "dask", "workers": 2}),
             # every asset shipped whole to the cluster (one item each): what the cost
             # model's "finish small assets here" saves
             ("dask", 2, {"executor": "dask", "workers": 2, "chunk_points": 1 << 30})]
    for number, (name, workers, run) in enumerate(cases):
        out = out_root / f"{number}-{name}{workers}"
        start_s = 0.0
        if name == "dask":
            context = dask_executor.cluster(workers=workers)
        else:
            context = _Null()
        with context as session:
            if name == "dask":
                clock = time.perf_counter()
                session.client  # noqa: B018 - started here, timed apart
                start_s = time.perf_counter() - clock
            clock = time.perf_counter()
            records = batch.bake_assets(assets, out, settings, run=run, write={})
            seconds = time.perf_counter() - clock
            reached = len(session.stats) if name == "dask" else None
        failed = [r for r in records if r["status"] != "ok"]
        if failed:
            raise SystemExit(f"library {name}: {failed[0]['error']}")
        cast = sum(r["rays"] for r in records)
        if run.get("chunk_points"):
            name = "dask-ship"
        rows.append({"executor": name, "workers": workers, "assets": len(records),
                     "seconds": seconds, "cluster_start_s": start_s, "rays": cast,
                     "rays_per_s": cast / seconds, "assets_on_cluster": reached})
        print(f"library {name:9s} {workers}: {seconds:7.2f} s {cast / seconds / 1e6:6.2f} "
              f"Mrays/s (cluster start {start_s:.2f} s, assets on the cluster: {reached})",
              flush=True)
    return rows


class _Null:
    def __enter__(self):
        return None

    def __exit__(self, *exc):
        return False


def run_large(path: Path, rays: int) -> list:
    from aobake.settings import BakeConfig
    from aobake.executors.base import Job
    from aobake.scene import load_scene

    rows, reference = [], None
    for name, workers in (("threads", 1), ("threads", 2), ("dask", 1), ("dask", 2)):
        start_s, scatter_s, stats = 0.0, None, {}
        if name == "threads":
            clock = time.perf_counter()
            result = aobake.bake(str(path), rays=rays, threads=workers)
            wall = time.perf_counter() - clock
        else:
            with dask_executor.cluster(workers=workers) as session:
                clock = time.perf_counter()
                client = session.client
                start_s = time.perf_counter() - clock
                # the job's scatter alone (the bake scatters it once more, the same way)
                scene = load_scene(str(path))
                job = Job(scene, BakeConfig(rays=rays), "rays", rays, True, "bench-scatter")
                size = len(pickle.dumps(job, protocol=5))
                clock = time.perf_counter()
                future = client.scatter(job, broadcast=True, hash=False)
                scatter_s = time.perf_counter() - clock
                client.cancel([future])
                del scene, job
                clock = time.perf_counter()
                result = aobake.bake(str(path), rays=rays, executor="dask", threads=1)
                wall = time.perf_counter() - clock
                stats = dict(session.stats[-1]) if session.stats else {}
                stats["job_bytes"] = size
        if reference is None:
            reference = result
        else:
            for key, value in reference.values.items():
                if not np.array_equal(value, result.values[key]):
                    raise SystemExit(f"large {name} {workers}: {key} differs from threads 1")
        timings = result.report["timings"]
        cast = result.report["rays_cast"]
        row = {"executor": name, "workers": workers, "seconds": wall,
               "trace_s": timings["trace_s"], "load_s": timings["load_s"],
               "occluders_s": timings.get("occluders_s"), "rays": cast,
               "rays_per_s": cast / wall, "trace_rays_per_s": cast / timings["trace_s"],
               "cluster_start_s": start_s, "scatter_s": scatter_s, **stats}
        if stats.get("items"):
            # the workers' capacity while the items ran vs the tracing they did: the rest is
            # each worker's preparation (once) and, per item, scheduling, the job's
            # unpickling (once per worker), result transfer and waiting
            capacity = workers * max(timings["trace_s"] - stats["pilot_s"], 1e-9)
            row["overhead_fraction"] = 1.0 - stats["estimate_s"] / capacity
            row["other_per_item_s"] = (capacity - stats["estimate_s"] - stats["prepare_s"]) \
                / stats["items"]
            row["cpu_share"] = stats["estimate_cpu_s"] / max(stats["estimate_s"], 1e-9)
        rows.append(row)
        extra = ""
        if stats.get("items"):
            extra = (f"; {stats['items']} items of <= {stats['per_item']} points, pilot "
                     f"{stats['pilot_points']} points {stats['pilot_s']:.2f} s, scatter "
                     f"{scatter_s:.2f} s ({stats['job_bytes'] / 1e6:.0f} MB), prepare "
                     f"{stats['prepare_s']:.2f} s, tracing {stats['estimate_s']:.2f} s "
                     f"(CPU {stats['estimate_cpu_s']:.2f} s), "
                     f"overhead {row['overhead_fraction']:.1%} (beyond preparing: "
                     f"{row['other_per_item_s'] * 1e3:.0f} ms per item); the workers had "
                     f"{row['cpu_share']:.0%} of a core each while tracing")
        print(f"large {name:7s} {workers}: {wall:7.2f} s (load {timings['load_s']:.2f} s, "
              f"occluders {timings.get('occluders_s') or 0:.2f} s, trace "
              f"{timings['trace_s']:.2f} s) "
              f"{cast / wall / 1e6:6.2f} Mrays/s end to end, "
              f"{cast / timings['trace_s'] / 1e6:6.2f} while tracing{extra}", flush=True)
    return rows


def run_cli(meshes, out_root: Path, rays: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    (out_root / "single").mkdir(parents=True)
    clock = time.perf_counter()
    for path, _ in meshes:
        subprocess.run([sys.executable, "-m", "aobake", str(path), "--out",
                        str(out_root / "single" / (path.stem + ".npz")), "--rays", str(rays),
                        "--quiet", "--threads", "2"], check=True, env=env,
                       stdout=subprocess.DEVNULL)
    single = time.perf_counter() - clock
    clock = time.perf_counter()
    subprocess.run([sys.executable, "-m", "aobake.cli.batch", *[str(p) for p, _ in meshes],
                    "--out-dir", str(out_root / "batch"), "--format", "npz", "--rays",
                    str(rays), "--quiet", "--threads", "2"], check=True, env=env)
    together = time.perf_counter() - clock
    n = len(meshes)
    row = {"assets": n, "one_process_each_s": single, "batch_s": together,
           "saved_per_asset_s": (single - together) / n}
    print(f"cli: {n} assets, one process each {single:.2f} s, one batch {together:.2f} s: "
          f"{row['saved_per_asset_s']:.2f} s saved per asset", flush=True)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--assets", type=int, default=50)
    parser.add_argument("--rays", type=int, default=128)
    parser.add_argument("--large-copies", type=int, default=30)
    parser.add_argument("--large-rays", type=int, default=16)
    parser.add_argument("--cli-assets", type=int, default=10)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--skip", default="", help="comma-separated: library,large,cli")
    args = parser.parse_args()
    skip = set(filter(None, args.skip.split(",")))
    results = {"load_before": os.getloadavg(), "cores": os.cpu_count()}
    print(f"load average {results['load_before']}, {results['cores']} cores", flush=True)
    with tempfile.TemporaryDirectory(prefix="aobake-scale-") as tmp:
        tmp = Path(tmp)
        (tmp / "lib").mkdir()
        meshes = library(tmp / "lib", args.assets)
        sizes = [v for _, v in meshes]
        print(f"library: {len(meshes)} meshes, {min(sizes)}-{max(sizes)} vertices, "
              f"{sum(sizes)} in all", flush=True)
        if "library" not in skip:
            results["library"] = run_library(meshes, tmp / "out", args.rays)
        if "large" not in skip:
            path = tmp / "large.ply"
            vertices, faces = large_scene(path, args.large_copies)
            print(f"large: {vertices} vertices, {faces} triangles, {args.large_rays} rays",
                  flush=True)
            results["large_scene"] = {"vertices": vertices, "faces": faces}
            results["large"] = run_large(path, args.large_rays)
        if "cli" not in skip:
            results["cli"] = run_cli(meshes[:args.cli_assets], tmp / "cli", args.rays)
    results["load_after"] = os.getloadavg()
    print(f"load average {results['load_after']}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
