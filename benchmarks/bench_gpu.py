"""GPGPU ray casting: ``--backend warp`` on a CUDA device (and on its CPU device) against
Embree on the same machine.

    python benchmarks/bench_gpu.py [--meshes bunny ogre] [--tracers embree warp-cuda warp-cpu]
                                   [--rays 64] [--repeats 3] [--threads N] [--target 0.01]
                                   [--ref-rays 4096] [--max-rays 4096]
                                   [--cache /tmp/aobake_bench_gpu] [--skip-rmse]

Needs the warp extra (``pip install -e '.[warp]'``); ``warp-cuda`` is left out with a note
where Warp sees no CUDA device.  Prints markdown tables (docs/gpu.md keeps them):

1. Throughput, per mesh (../shared/meshes) and tracer:
   * query Mrays/s: the backend's occlusion query alone (``backend.occluded``) on rays
     from every face's centre (lifted by 1e-5 local units) in cosine-distributed
     directions, --rays per face, in chunks of 131072 rays on --threads threads (one
     CUDA device takes one chunk at a time), median of --repeats: what a GPU speeds up;
   * bake Mrays/s: a per-vertex AO bake at --rays (``aobake.bake``), rays cast / the
     report's ``trace_s`` (ray generation, queries and estimation: numpy and the compiled
     kernels on the CPU whatever the tracer), median of --repeats, and the bake's total.
2. Time to RMSE --target (per-vertex AO against a --ref-rays Embree reference of another
   seed, cached under --cache, its own noise removed: RMSE = sqrt(max(0, MSE - mean(ref
   stderr^2))), over the vertices that cast rays): bakes at 16, 32, 64, ... rays until RMSE <= target; the rays needed and
   the seconds of that bake (trace and total).  The estimators are the same on every
   tracer, so the rays needed are too; the seconds are the tracer's.

The first Warp bake of a process compiles its kernels (cached in ~/.cache/warp): a warm-up
bake runs first and is not timed.  Timings mean something only on a quiet machine (the
load average is printed).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import aobake  # noqa: E402
from aobake.backends import BACKENDS, unavailable  # noqa: E402
from aobake.backends.warp import WarpBackend  # noqa: E402
from aobake.trace import DEFAULT_CHUNK_RAYS, default_threads  # noqa: E402

SHARED = ROOT.parent / "shared" / "meshes"
MESHES = {"bunny": SHARED / "stanford-bunny.obj", "ogre": SHARED / "ogre.obj",
          "spot": SHARED / "spot.obj"}
TRACERS = ("embree", "warp-cuda", "warp-cpu")
REF_SEED = 12345


@contextlib.contextmanager
def tracer(name: str):
    """(backend name for the bake) with ``warp`` pinned to the tracer's device."""
    if not name.startswith("warp"):
        yield name
        return
    device = {"warp-cuda": "cuda:0", "warp-cpu": "cpu"}[name]
    saved = BACKENDS["warp"]
    BACKENDS["warp"] = partial(WarpBackend, device=device)
    try:
        yield "warp"
    finally:
        BACKENDS["warp"] = saved


def available_tracers(wanted) -> list:
    out = []
    for name in wanted:
        if name.startswith("warp"):
            if unavailable("warp"):
                print(f"note: {name} left out: {unavailable('warp')}")
                continue
            if name == "warp-cuda":
                from aobake.backends.warp import _warp

                wp, _ = _warp()
                if not wp.is_cuda_available():
                    print("note: warp-cuda left out: Warp sees no CUDA device here")
                    continue
                print(f"CUDA device: {wp.get_device('cuda:0').name}")
        out.append(name)
    return out


def bake(mesh: Path, name: str, rays: int, seed: int, threads: int):
    with tracer(name) as backend:
        return aobake.bake(str(mesh), rays=rays, seed=seed, threads=threads, backend=backend)


def local_scene(mesh: Path):
    """(vertices (v, 3) float64 local, faces (f, 3) int64, face normals (f, 3)) in the
    tracer's frame: rebased on the median, scaled by a power of two into [-1, 1]."""
    import math

    import trimesh

    from aobake.scene import face_normals

    m = trimesh.load(str(mesh), force="mesh", process=False)
    v = np.asarray(m.vertices, dtype=np.float64)
    v = v - np.median(v, axis=0)
    v = v * 2.0 ** -math.frexp(float(np.abs(v).max()))[1]
    f = np.asarray(m.faces, dtype=np.int64)
    return v, f, face_normals(v, f)


def surface_rays(v, f, fn, per_face: int, seed: int = 0):
    """(origins, directions) float32: ``per_face`` cosine-distributed rays from each face's
    centre lifted by 1e-5 along its normal (faces with area)."""
    rng = np.random.default_rng(seed)
    usable = np.flatnonzero(np.linalg.norm(fn, axis=1) > 0)  # zero-area faces have no normal
    n = len(usable) * per_face
    face = np.repeat(usable, per_face)
    normal = fn[face]
    origin = v[f].mean(axis=1)[face] + 1e-5 * normal
    u1, u2 = rng.random(n), rng.random(n)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    helper = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    tx = np.cross(normal, helper)
    tx /= np.linalg.norm(tx, axis=1)[:, None]
    ty = np.cross(normal, tx)
    d = (tx * (r * np.cos(phi))[:, None] + ty * (r * np.sin(phi))[:, None]
         + normal * np.sqrt(np.maximum(0.0, 1 - u1))[:, None])
    return origin.astype(np.float32), d.astype(np.float32)


def query_rate(backend, origins, directions, threads: int) -> float:
    """Seconds of ``backend.occluded`` over all rays in DEFAULT_CHUNK_RAYS chunks."""
    chunks = [slice(i, i + DEFAULT_CHUNK_RAYS) for i in range(0, len(origins), DEFAULT_CHUNK_RAYS)]
    start = time.perf_counter()
    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(lambda s: backend.occluded(origins[s], directions[s], np.float32(np.inf)),
                      chunks))
    return time.perf_counter() - start


def make_backend(name, v, f, fn):
    from aobake.backends.embree import EmbreeBackend

    if name == "embree":
        return EmbreeBackend(v, f, fn, 1e-5)
    return WarpBackend(v, f, fn, 1e-5, device={"warp-cuda": "cuda:0", "warp-cpu": "cpu"}[name])


def throughput(meshes, tracers, rays, repeats, threads):
    print(f"\n### Throughput: {rays} rays per face (query) / per vertex (bake), {threads} "
          f"threads, median of {repeats}\n")
    print("| mesh | tracer | query Mrays/s | bake Mrays/s (trace_s) | bake total s | build s |")
    print("|---|---|---|---|---|---|")
    for mesh in meshes:
        v, f, fn = local_scene(MESHES[mesh])
        origins, directions = surface_rays(v, f, fn, rays)
        for name in tracers:
            start = time.perf_counter()
            backend = make_backend(name, v, f, fn)
            build = time.perf_counter() - start
            query_rate(backend, origins[:1000], directions[:1000], 1)  # warm up
            query = statistics.median(query_rate(backend, origins, directions, threads)
                                      for _ in range(repeats))
            bake(MESHES[mesh], name, 8, 0, threads)  # warm up (kernels compiled, caches)
            runs = [bake(MESHES[mesh], name, rays, 0, threads) for _ in range(repeats)]
            trace = statistics.median(r.report["timings"]["trace_s"] for r in runs)
            total = statistics.median(r.report["timings"]["total_s"] for r in runs)
            cast = int(runs[0].report["rays_cast"])
            print(f"| {mesh} | {name} | {len(origins) / query / 1e6:.2f} | "
                  f"{cast / trace / 1e6:.2f} ({trace:.2f} s) | {total:.2f} | {build:.2f} |",
                  flush=True)


def reference(mesh: str, ref_rays: int, threads: int, cache: Path):
    """(ao, ao_stderr, rays) of the Embree reference bake (cached)."""
    path = cache / f"{mesh}_ref{ref_rays}_seed{REF_SEED}.npz"
    if path.exists():
        data = np.load(path)
        return data["ao"], data["ao_stderr"], data["rays"]
    start = time.perf_counter()
    res = bake(MESHES[mesh], "embree", ref_rays, REF_SEED, threads)
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(path, ao=res.ao, ao_stderr=res.ao_stderr, rays=res.rays)
    print(f"(reference {mesh} at {ref_rays} rays: {time.perf_counter() - start:.0f} s, cached "
          f"in {path})", flush=True)
    return res.ao, res.ao_stderr, res.rays


def time_to_rmse(meshes, tracers, target, ref_rays, max_rays, threads, cache):
    print(f"\n### Time to RMSE {target} (per-vertex AO, against a {ref_rays}-ray Embree "
          f"reference, its noise removed; {threads} threads)\n")
    print("| mesh | tracer | rays needed | RMSE there | trace s | bake total s | "
          "RMSE at each ray count |")
    print("|---|---|---|---|---|---|---|")
    for mesh in meshes:
        ref, ref_se, ref_rays_cast = reference(mesh, ref_rays, threads, cache)
        # vertices that cast no ray (no normal: unreferenced or only on degenerate faces)
        # carry AO 0.5 +- 0.5 by convention: not an estimate, left out
        traced = ref_rays_cast > 0
        ref_var = float(np.mean(ref_se[traced] ** 2))
        for name in tracers:
            bake(MESHES[mesh], name, 8, 0, threads)  # warm up
            rays, seen, found = 16, [], None
            while rays <= max_rays:
                res = bake(MESHES[mesh], name, rays, 0, threads)
                mse = float(np.mean((res.ao[traced] - ref[traced]) ** 2))
                rmse = float(np.sqrt(max(0.0, mse - ref_var)))
                seen.append(f"{rays}: {rmse:.4f}")
                if rmse <= target:
                    found = (rays, rmse, res.report["timings"])
                    break
                rays *= 2
            if found is None:
                print(f"| {mesh} | {name} | > {max_rays} | | | | {', '.join(seen)} |", flush=True)
                continue
            rays, rmse, timings = found
            print(f"| {mesh} | {name} | {rays} | {rmse:.4f} | {timings['trace_s']:.2f} | "
                  f"{timings['total_s']:.2f} | {', '.join(seen)} |", flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--meshes", nargs="+", default=["bunny", "ogre"], choices=list(MESHES))
    parser.add_argument("--tracers", nargs="+", default=list(TRACERS), choices=TRACERS)
    parser.add_argument("--rays", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=default_threads())
    parser.add_argument("--target", type=float, default=0.01)
    parser.add_argument("--ref-rays", type=int, default=4096)
    parser.add_argument("--max-rays", type=int, default=4096)
    parser.add_argument("--cache", type=Path, default=Path("/tmp/aobake_bench_gpu"))
    parser.add_argument("--skip-rmse", action="store_true", help="throughput only")
    args = parser.parse_args(argv)
    missing = [m for m in args.meshes if not MESHES[m].exists()]
    if missing:
        sys.exit(f"missing meshes: {', '.join(str(MESHES[m]) for m in missing)}")
    tracers = available_tracers(args.tracers)
    print("load average %.2f %.2f %.2f" % os.getloadavg()
          + f", {os.cpu_count()} CPUs, threads {args.threads}")
    throughput(args.meshes, tracers, args.rays, args.repeats, args.threads)
    if not args.skip_rmse:
        time_to_rmse(args.meshes, tracers, args.target, args.ref_rays, args.max_rays,
                     args.threads, args.cache)
    print(f"\nload average after {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
