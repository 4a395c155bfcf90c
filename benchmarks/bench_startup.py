"""The command's start-up, side by side: ``aobake --version`` and a 12-triangle bake, each in a
fresh process, for this checkout and another one (an older commit's worktree), alternated
so that load from other work falls on both alike.

    git worktree add /tmp/before <commit> && (cd /tmp/before && python setup.py build_ext --inplace)
    python benchmarks/bench_startup.py --before /tmp/before [--runs 15]

Each tree runs ``python -m aobake`` from its own root (so it imports its own package).
Prints medians and the after/before ratio, and the load average before and after.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", type=Path, required=True,
                        help="root of the other checkout (built in place)")
    parser.add_argument("--runs", type=int, default=15)
    args = parser.parse_args(argv)
    import trimesh

    work = Path(tempfile.mkdtemp(prefix="aobake-startup-"))
    mesh = work / "box12.ply"
    trimesh.creation.box().export(mesh)
    trees = {"before": args.before.resolve(), "after": ROOT}
    cases = {"--version": ["--version"],
             "12-triangle bake": [str(mesh), "--out", str(work / "out.npz"), "--rays", "64",
                                  "--quiet"]}
    times = {(t, c): [] for t in trees for c in cases}
    load = os.getloadavg()
    for i in range(args.runs):
        order = list(trees.items()) if i % 2 == 0 else list(trees.items())[::-1]
        for case, extra in cases.items():
            for tree, root in order:
                start = time.perf_counter()
                done = subprocess.run([sys.executable, "-m", "aobake", *extra], cwd=root,
                                      capture_output=True, text=True)
                times[(tree, case)].append(time.perf_counter() - start)
                if done.returncode != 0:
                    raise SystemExit(f"{tree}: {done.stderr}")
    print(f"{'case':18s} {'before':>10s} {'after':>10s} {'after/before':>13s}")
    for case in cases:
        b = statistics.median(times[("before", case)])
        a = statistics.median(times[("after", case)])
        print(f"{case:18s} {b * 1e3:8.1f}ms {a * 1e3:8.1f}ms {a / b:13.3f}")
    print(f"load average before {load[0]:.2f}, after {os.getloadavg()[0]:.2f} "
          f"({os.cpu_count()} cores; rows under load compare only as ratios)")


if __name__ == "__main__":
    main()
