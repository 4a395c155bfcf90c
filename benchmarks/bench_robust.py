"""Embree's robust traversal against its fast one (``--embree-mode robust | fast``): speed,
and how far any estimate moves.

    python benchmarks/bench_robust.py [--rays 256] [--repeats 3] [--threads 2]
                                      [--meshes still_life torus_uv bunny ogre]

Per mesh (the project's own closed-form scenes, assets/still_life.obj with its 0.002 gap
between two plates and spheres touching the floor, assets/torus_uv.obj, and the bunny and
ogre from ../shared/meshes), per-vertex AO with ``--rays`` rays, the same seed in both
modes, so both trace the very same rays and differ only where Embree's answer differs:

- hits: the rays whose answer differs, sum over vertices of |ao_fast - ao_robust| x rays
  (a lower bound: two flips in opposite directions at one vertex cancel);
- moved: the vertices whose estimate differs at all, and the largest |difference| /
  stderr (the robust bake's ``ao_stderr``; a difference where the stderr is 0 is "inf");
- speed: trace seconds (the report's ``trace_s``), the median of ``--repeats`` bakes of each
  mode, alternated, and the ratio fast / robust.

The rule (issue 21): the fast mode becomes the default only if no estimate moves by more
than 0.1 of its stderr anywhere measured.  Timings mean something only on a quiet machine.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import aobake  # noqa: E402

SHARED = ROOT.parent / "shared" / "meshes"
MESHES = {"still_life": ROOT / "assets" / "still_life.obj",
          "torus_uv": ROOT / "assets" / "torus_uv.obj",
          "bunny": SHARED / "stanford-bunny.obj", "ogre": SHARED / "ogre.obj"}


def bake(mesh, mode, rays, threads):
    result = aobake.bake(mesh, rays=rays, threads=threads, embree_mode=mode)
    return result, result.report["timings"]["trace_s"], result.report["rays_cast"]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rays", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--meshes", nargs="+", default=list(MESHES))
    args = parser.parse_args(argv)
    print(f"rays per vertex {args.rays}, threads {args.threads}, median of {args.repeats}")
    print("| mesh | vertices | rays cast | robust trace s | fast trace s | fast / robust | "
          "rays that differ | vertices moved | max |diff| | max |diff| / stderr |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in args.meshes:
        mesh = MESHES[name]
        if not mesh.exists():
            print(f"| {name} | (missing: {mesh}) |")
            continue
        times = {"robust": [], "fast": []}
        results = {}
        for _ in range(args.repeats):
            for mode in ("robust", "fast"):
                result, seconds, cast = bake(mesh, mode, args.rays, args.threads)
                times[mode].append(seconds)
                results[mode] = result
        robust, fast = results["robust"], results["fast"]
        diff = np.abs(fast.ao.astype(np.float64) - robust.ao.astype(np.float64))
        rays = robust.rays.astype(np.float64)
        flips = int(np.rint(np.sum(diff * rays)))
        moved = int(np.count_nonzero(diff))
        se = robust.ao_stderr.astype(np.float64)
        ratio = np.where(diff > 0, np.divide(diff, se, out=np.full_like(diff, np.inf),
                                             where=se > 0), 0.0)
        t_r, t_f = statistics.median(times["robust"]), statistics.median(times["fast"])
        print(f"| {name} | {len(diff)} | {cast} | {t_r:.3f} | {t_f:.3f} | {t_f / t_r:.3f} | "
              f"{flips} | {moved} | {diff.max():.3g} | {ratio.max():.3g} |")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
