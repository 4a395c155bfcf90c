"""xatlas's charting: the xatlas package against aobake._xatlas (third_party/xatlas, built
with speed patches), on the same meshes and parts, in one run.

    python benchmarks/bench_charting.py [--meshes spot,stanford-bunny,ogre] [--repeat 3]

For each mesh (../shared/meshes), ``charts.chart_mesh`` (the parts, xatlas's charting
and its cheap pack, the charts rescaled to their surface area) runs ``--repeat`` times, in
turn: with the package, with aobake._xatlas placing the charts as the package does, and
with aobake._xatlas leaving them unplaced (what aobake uses: ``charts.xatlas_charts``).  The
table gives the fastest run of each, the package's over the unplaced run, and whether the
charts are the same: placed, the vertices, faces, UVs and charts of the package bit for
bit; unplaced, the same vertices, faces and charts (its UVs differ by each chart's
placement: tests/test_xatlas_build.py checks that).  Wall seconds on all cores (xatlas
charts each part on its own thread).
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
from aobake.targets.texels import charts as charting  # noqa: E402


def _charts(vertices, faces, library, placed):
    real = charting.xatlas_charts
    charting.xatlas_charts = lambda meshes, area, tpu, library_=None, placed_=False: real(
        meshes, area, tpu, library, placed)
    try:
        start = time.perf_counter()
        result = charting.chart_mesh(vertices, faces, charting.CHART_FACES)
        seconds = time.perf_counter() - start
    finally:
        charting.xatlas_charts = real

    def digest(arrays):
        return hashlib.sha256(b"".join(np.ascontiguousarray(a).tobytes() for a in arrays)
                              ).hexdigest()

    # (vertices, faces, uv, face_chart): the charts with and without their UVs
    return seconds, digest(result[:4]), digest(result[:2] + result[3:4]), int(result[3].max()) + 1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--meshes", default="spot,stanford-bunny,ogre")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    if charting.charting_library() != "aobake._xatlas":
        sys.exit("aobake._xatlas was not built: nothing to compare")
    runs = {"package": ("xatlas", True), "placed": ("aobake._xatlas", True),
            "unplaced": ("aobake._xatlas", False)}
    print("| mesh | triangles | charts | xatlas package s | aobake._xatlas placed s | "
          "aobake._xatlas unplaced s | speed-up | same charts |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.meshes.split(","):
        scene = load_scene(SHARED / f"{name}.obj")
        best = {run: float("inf") for run in runs}
        full = {run: set() for run in runs}
        shape = {run: set() for run in runs}
        charts = 0
        for _ in range(args.repeat):
            for run, (library, placed) in runs.items():
                seconds, with_uv, without_uv, charts = _charts(scene.vertices, scene.faces,
                                                               library, placed)
                best[run] = min(best[run], seconds)
                full[run].add(with_uv)
                shape[run].add(without_uv)
        same = (len(full["package"] | full["placed"]) == 1
                and len(shape["package"] | shape["unplaced"]) == 1)
        print(f"| {name}.obj | {len(scene.faces)} | {charts} | {best['package']:.2f} | "
              f"{best['placed']:.2f} | {best['unplaced']:.2f} | "
              f"{best['package'] / best['unplaced']:.2f}x | {'yes' if same else 'NO'} |",
              flush=True)


if __name__ == "__main__":
    main()
