"""xatlas's charting: the xatlas package against aobake._xatlas (third_party/xatlas, built
with two speed-only patches), on the same meshes and parts, in one run.

    python benchmarks/bench_charting.py [--meshes spot,stanford-bunny,ogre] [--repeat 3]

For each mesh (../shared/meshes), ``unwrap._xatlas_charts`` (the parts, xatlas's charting
and its cheap pack, the charts rescaled to their surface area) runs with each library in
turn, ``--repeat`` times, alternating; the table gives the fastest run of each, their ratio
and whether the two gave the same charts (vertices, faces and UVs, bit for bit).  Wall
seconds on all cores (xatlas charts each part on its own thread).
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "meshes"
sys.path.insert(0, str(ROOT))

from aobake.scene import load_scene  # noqa: E402
from aobake.targets.texels import unwrap  # noqa: E402


def _charts(vertices, faces, library):
    real = unwrap.xatlas_charts
    unwrap.xatlas_charts = lambda meshes, area, tpu, library_=None: real(meshes, area, tpu,
                                                                          library)
    try:
        start = time.perf_counter()
        result = unwrap._xatlas_charts(vertices, faces, unwrap.CHART_FACES)
        seconds = time.perf_counter() - start
    finally:
        unwrap.xatlas_charts = real
    digest = hashlib.sha256(b"".join(np.ascontiguousarray(a).tobytes() for a in result[:4]))
    return seconds, digest.hexdigest(), int(result[3].max()) + 1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--meshes", default="spot,stanford-bunny,ogre")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    if unwrap.charting_library() != "aobake._xatlas":
        sys.exit("aobake._xatlas was not built: nothing to compare")
    libraries = ("xatlas", "aobake._xatlas")
    print("| mesh | triangles | charts | xatlas package s | aobake._xatlas s | speed-up | "
          "same charts |")
    print("|---|---|---|---|---|---|---|")
    for name in args.meshes.split(","):
        scene = load_scene(SHARED / f"{name}.obj")
        best = {lib: float("inf") for lib in libraries}
        digests = {lib: set() for lib in libraries}
        charts = 0
        for _ in range(args.repeat):
            for lib in libraries:
                seconds, digest, charts = _charts(scene.vertices, scene.faces, lib)
                best[lib] = min(best[lib], seconds)
                digests[lib].add(digest)
        same = len(digests["xatlas"] | digests["aobake._xatlas"]) == 1
        print(f"| {name}.obj | {len(scene.faces)} | {charts} | {best['xatlas']:.2f} | "
              f"{best['aobake._xatlas']:.2f} | {best['xatlas'] / best['aobake._xatlas']:.2f}x | "
              f"{'yes' if same else 'NO'} |", flush=True)


if __name__ == "__main__":
    main()
