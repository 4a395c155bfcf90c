"""Speed to the same error: aobake against libigl's Embree AO on the bunny.

    python benchmarks/bench_peers.py [--mesh PATH] [--threads 2] [--subset 2000]

libigl (``pip install libigl``, not a dependency of aobake) reports the occluded
fraction of uniformly sampled hemisphere directions, i.e. 1 minus aobake's
``--weighting uniform`` AO.  Both are baked over every vertex of the mesh and
timed.  Their error is measured on a random subset of vertices against a
reference: aobake at 16,384 rays (``sobol``), whose own reported stderr is printed
so it can be seen to be far below the errors measured.  Rows: libigl at 256 rays
(the brief's peer figure), aobake ``sobol`` and ``random`` at several ray counts.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import aobake  # noqa: E402
from aobake.scene import load_scene  # noqa: E402

DEFAULT_MESH = Path(__file__).resolve().parents[2] / "shared" / "meshes" / "stanford-bunny.obj"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", type=Path, default=DEFAULT_MESH)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--subset", type=int, default=2000)
    args = parser.parse_args()
    try:
        import igl.embree
    except ImportError:
        sys.exit("bench_peers needs libigl: pip install libigl")
    if not args.mesh.is_file():
        sys.exit(f"{args.mesh}: not found (benchmarks use ../shared/meshes)")

    scene = load_scene(args.mesh)
    V, F, N = scene.vertices, scene.faces, scene.vertex_normals
    rng = np.random.default_rng(0)
    # Vertices with a normal (the bunny has unreferenced ones, baked as "no information").
    candidates = np.flatnonzero(np.linalg.norm(N, axis=1) > 0.5)
    subset = rng.choice(candidates, size=min(args.subset, len(candidates)), replace=False)
    # Another seed than the bakes below: with the same seed the reference would share
    # their random shifts, and their errors would look smaller than they are.
    ref = aobake.bake_points(scene, V[subset], N[subset], rays=16384, sampler="sobol",
                             weighting="uniform", seed=987654321, threads=args.threads)
    truth = ref.ao

    rows = []
    start = time.perf_counter()
    occluded = igl.embree.ambient_occlusion(V, F.astype(np.int64), V, N, 256)
    wall = time.perf_counter() - start
    rows.append(("libigl embree", "libigl's", 256, wall, 1.0 - occluded[subset], None))
    for sampler in ("sobol", "random"):
        for rays in (32, 64, 128, 256):
            start = time.perf_counter()
            res = aobake.bake(scene, rays=rays, sampler=sampler, weighting="uniform",
                              threads=args.threads)
            wall = time.perf_counter() - start
            rows.append(("aobake", sampler, rays, wall, res.ao[subset], res.ao_stderr[subset]))

    print(f"mesh: {scene.source}  vertices: {len(V)}  triangles: {len(F)}  threads: {args.threads}")
    print(f"convention: uniform-weighted AO (1/2pi) int V dw; reference: aobake sobol 16384 rays on "
          f"{len(subset)} vertices, its mean reported stderr {ref.ao_stderr.mean():.5f}\n")
    print("| tool | sampler | rays | time s (all vertices) | RMS error | mean reported stderr | "
          "mean error (bias) |")
    print("|---|---|---|---|---|---|---|")
    for tool, sampler, rays, wall, ao, se in rows:
        err = ao - truth
        rms = float(np.sqrt(np.mean(err**2)))
        print(f"| {tool} | {sampler} | {rays} | {wall:.2f} | {rms:.4f} | "
              f"{'-' if se is None else f'{se.mean():.4f}'} | {err.mean():+.4f} |")


if __name__ == "__main__":
    main()
