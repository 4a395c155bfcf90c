"""Throughput: aobake end to end vs a bare embreex loop on the same rays.

    python benchmarks/bench_throughput.py [--mesh PATH] [--rays 256] [--threads 2] [--repeat 3]

Uses ../shared/meshes/stanford-bunny.obj when present (a generated torus knot
otherwise).  In one run it times

* aobake.bake (AO, occlusion queries): scene build, ray generation, tracing,
  estimation, report -- everything except reading the file;
* the bare loop: the shortest program that traces the same rays -- build an
  embreex scene from the same float32 vertices and int32 faces (``build``), then
  the same rays (generated beforehand, NOT timed), chunked the same way, through
  ``EmbreeScene.run(query="OCCLUDED")`` on the same threads (``trace``);

and prints rays/s for both, two ratios and the peak resident memory:

* ``ratio``: aobake vs the whole bare program (build + trace): like for like,
  both start from arrays in memory and end with per-ray results in hand (the bare
  loop is still spared generating its rays);
* ``vs trace only``: aobake vs the bare loop's tracing alone, the stricter bound
  (aobake pays the same ~0.1 s embreex scene build as any embreex program).
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import aobake  # noqa: E402
from aobake.targets.vertices import vertex_sizes  # noqa: E402
from aobake.occluders import build as build_occluders  # noqa: E402
from aobake.trace import DEFAULT_CHUNK_RAYS, Tracer, morton_order, point_offsets  # noqa: E402
from aobake.settings import BakeConfig  # noqa: E402
from aobake.scene import load_scene, make_scene  # noqa: E402

DEFAULT_MESH = Path(__file__).resolve().parents[2] / "shared" / "meshes" / "stanford-bunny.obj"


def fallback_scene():
    import trimesh

    knot = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3, major_sections=256,
                                  minor_sections=128)
    return make_scene(knot.vertices, knot.faces, source="<generated torus>")


def bare_loop(tracer, points, normals, ids, threads, chunk_rays, sizes=None):
    """Pre-generate every chunk's rays (not timed), then time building an embreex scene of
    the tracer's mesh and tracing the rays through it.  Returns (rays, build s, trace s)."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    per_chunk = max(1, chunk_rays // tracer.samples.rays)
    order = morton_order(points)
    chunks = []
    for start in range(0, len(order), per_chunk):
        sel = order[start:start + per_chunk]
        rebased = points[sel] - tracer.center
        offsets = point_offsets(rebased, None if sizes is None else sizes[sel],
                                tracer.config.ray_offset)
        origins = rebased + offsets[:, None] * normals[sel]
        rays = tracer.generator.rays(origins, normals[sel], ids[sel])
        chunks.append((rays.origins, rays.directions.reshape(-1, 3).copy()))
    total = sum(len(o) for o, _ in chunks)
    vertices = (tracer.scene.vertices - tracer.center).astype(np.float32)
    faces = tracer.scene.faces.astype(np.int32)
    tmax = np.float32(1e37)

    start = time.perf_counter()
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, vertices, faces)
    scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32), query="OCCLUDED")  # commit
    built = time.perf_counter()

    def run(chunk):
        o, d = chunk
        return scene.run(o, d, dists=np.full(len(o), tmax, np.float32), query="OCCLUDED")

    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(run, chunks))
    return total, built - start, time.perf_counter() - built


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mesh", type=Path, default=DEFAULT_MESH)
    parser.add_argument("--rays", type=int, default=256)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--sampler", default="sobol")
    args = parser.parse_args()

    scene = load_scene(args.mesh) if args.mesh.is_file() else fallback_scene()
    config = BakeConfig(rays=args.rays, sampler=args.sampler)
    rows = []
    for _ in range(args.repeat):
        start = time.perf_counter()
        result = aobake.bake(scene, config, threads=args.threads)
        wall = time.perf_counter() - start
        cast = result.report["rays_cast"]
        tracer = Tracer(scene, config, build_occluders(scene, config))
        keys = np.concatenate([scene.vertices, scene.vertex_normals], axis=1)
        _, first = np.unique(keys, axis=0, return_index=True)
        valid = first[np.linalg.norm(scene.vertex_normals[first], axis=1) > 0.5]
        n_bare, t_build, t_trace = bare_loop(tracer, scene.vertices[valid], scene.vertex_normals[valid],
                                             valid.astype(np.int64), args.threads, DEFAULT_CHUNK_RAYS,
                                             vertex_sizes(scene)[valid])
        assert n_bare == cast, (n_bare, cast)
        rows.append((wall, t_build, t_trace))
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"mesh: {scene.source}  vertices: {len(scene.vertices)}  triangles: {len(scene.faces)}")
    print(f"rays/point: {config.rays}  sampler: {args.sampler}  threads: {args.threads}  "
          f"chunk: {DEFAULT_CHUNK_RAYS} rays  rays: {cast}  ray kernel: {result.report['parameters']['kernels']['ray_generation']}  "
          f"mean AO stderr: {result.report['error']['ao']['stderr_mean']:.4f}")
    print()
    print("| run | aobake s | bare build s | bare trace s | aobake Mrays/s | bare Mrays/s "
          "| ratio | vs trace only |")
    print("|---|---|---|---|---|---|---|---|")
    for i, (wall, t_build, t_trace) in enumerate(rows):
        print(f"| {i + 1} | {wall:.3f} | {t_build:.3f} | {t_trace:.3f} | {cast / wall / 1e6:.2f} "
              f"| {cast / (t_build + t_trace) / 1e6:.2f} | {(t_build + t_trace) / wall:.2f} "
              f"| {t_trace / wall:.2f} |")
    ratio = float(np.median([(b + t) / w for w, b, t in rows]))
    strict = float(np.median([t / w for w, _, t in rows]))
    wall, t_build, t_trace = np.median(np.array(rows), axis=0)
    print(f"| median | {wall:.3f} | {t_build:.3f} | {t_trace:.3f} | {cast / wall / 1e6:.2f} "
          f"| {cast / (t_build + t_trace) / 1e6:.2f} | {ratio:.2f} | {strict:.2f} |")
    print("\n(median row: median of each column; the ratios are medians of the per-run ratios)")
    print(f"\npeak resident memory: {peak_mb:.0f} MiB")


if __name__ == "__main__":
    main()
