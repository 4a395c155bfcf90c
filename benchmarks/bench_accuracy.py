"""Speed/accuracy trade: error against a closed form, per sampler and ray count.

    python benchmarks/bench_accuracy.py [--points 2000] [--threads 2]

Scene: floor points under a tessellated disc (exact AO from Lambert's polygon form
factor).  For each sampler and --rays it prints the RMS error against the exact
value, the RMS reported standard error (honest when the two agree), and
Mrays/s; so you can pick the cheapest setting that reaches an error target.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import aobake  # noqa: E402
from analytic import polygon, polygon_form_factor  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=2000)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    disc = polygon([0, 0, 0.7], 1.3, 48)
    rng = np.random.default_rng(0)
    pts = np.zeros((args.points, 3))
    pts[:, :2] = rng.uniform(-2.5, 2.5, size=(args.points, 2))
    nrm = np.tile([0, 0, 1.0], (args.points, 1))
    exact = np.array([1 - polygon_form_factor(p, [0, 0, 1], disc.vertices[1:]) for p in pts])
    print(f"{args.points} floor points under a 48-gon disc (exact AO mean {exact.mean():.3f})\n")
    print("| sampler | rays | RMS error | RMS reported stderr | Mrays/s |")
    print("|---|---|---|---|---|")
    for sampler in ("random", "stratified", "sobol"):
        for rays in (16, 64, 256, 1024):
            start = time.perf_counter()
            res = aobake.bake_points(disc, pts, nrm, rays=rays, sampler=sampler,
                                     threads=args.threads)
            wall = time.perf_counter() - start
            rms = np.sqrt(np.mean((res.ao - exact) ** 2))
            rse = np.sqrt(np.mean(res.ao_stderr**2))
            print(f"| {sampler} | {rays} | {rms:.5f} | {rse:.5f} | "
                  f"{res.rays.sum() / wall / 1e6:.2f} |")


if __name__ == "__main__":
    main()
