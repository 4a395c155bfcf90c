"""Peak memory of a per-vertex bake of a ~1.3M-triangle mesh at 256 rays.

    python benchmarks/bench_memory.py [--subdivisions 8] [--rays 256] [--threads 2]

The mesh is generated (a bumpy icosphere: 10 * 4^s * 2 triangles), so this runs
anywhere.  Prints the wall time, rays/s and peak resident memory: chunking keeps
ray memory bounded (a few chunks of 128k rays in flight), so the peak is the
mesh, its Embree BVH and the per-vertex results.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import aobake  # noqa: E402
from aobake.scene import make_scene  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subdivisions", type=int, default=8)
    parser.add_argument("--rays", type=int, default=256)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=args.subdivisions)
    v = sphere.vertices * (1 + 0.05 * np.sin(12 * sphere.vertices[:, [0]]) * np.cos(9 * sphere.vertices[:, [1]]))
    scene = make_scene(v, sphere.faces, source=f"<icosphere {args.subdivisions}>")
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    start = time.perf_counter()
    res = aobake.bake(scene, rays=args.rays, threads=args.threads)
    wall = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print("| triangles | vertices | rays | wall s | Mrays/s | peak RSS MiB (before bake) |")
    print("|---|---|---|---|---|---|")
    print(f"| {len(scene.faces)} | {len(scene.vertices)} | {int(res.rays.sum())} | {wall:.1f} | "
          f"{res.rays.sum() / wall / 1e6:.2f} | {peak:.0f} ({before:.0f}) |")


if __name__ == "__main__":
    main()
