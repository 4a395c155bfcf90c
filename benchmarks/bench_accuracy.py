"""Speed/accuracy trade: error against a closed form, per sampler and ray count.

    python benchmarks/bench_accuracy.py [--points 2000] [--threads 2]

Scene: floor points under a tessellated disc (exact AO from Lambert's polygon form
factor).  For each sampler and --rays it prints the RMS error against the exact
value and the RMS reported standard error (honest when the two agree), so
you can pick the cheapest setting that reaches an error target.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import aobake  # noqa: E402
from analytic import polygon, polygon_form_factor  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=500)
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    disc = polygon([0, 0, 0.7], 1.3, 48)
    rng = np.random.default_rng(0)
    pts = np.zeros((args.points, 3))
    pts[:, :2] = rng.uniform(-2.5, 2.5, size=(args.points, 2))
    nrm = np.tile([0, 0, 1.0], (args.points, 1))
    exact = np.array([1 - polygon_form_factor(p, [0, 0, 1], disc.vertices[1:]) for p in pts])
    print(f"{args.points} floor points under a 48-gon disc (exact AO mean {exact.mean():.3f})\n")
    # Points of one bake share their base set and elevation shifts (correlated
    # errors), so the RMS is pooled over several seeds to be representative.
    print(f"RMS over {args.points} points x {args.seeds} seeds\n")
    print("| sampler | rays | RMS error | RMS reported stderr | error x sqrt(rays) |")
    print("|---|---|---|---|---|")
    for sampler in ("random", "stratified", "sobol"):
        for rays in (16, 64, 256, 1024):
            err, se = [], []
            for seed in range(args.seeds):
                res = aobake.bake_points(disc, pts, nrm, rays=rays, sampler=sampler, seed=seed,
                                         threads=args.threads)
                err.append(res.ao - exact)
                se.append(res.ao_stderr)
            rms = np.sqrt(np.mean(np.square(err)))
            rse = np.sqrt(np.mean(np.square(se)))
            print(f"| {sampler} | {rays} | {rms:.5f} | {rse:.5f} | {rms * np.sqrt(rays):.3f} |")


if __name__ == "__main__":
    main()
