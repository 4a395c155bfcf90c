"""Seam erasure (--seams erase|off): how far bilinear lookups from the two sides of every
UV seam disagree, split into a systematic part and a random part, before and after.

    python benchmarks/bench_seams.py [--resolution 1024] [--rays 256] [--seeds 4]
                                     [--threads 2] [--mesh NAME ...] [--meshes DIR]
                                     [--kappa K] [--worst N]

Cases (``--meshes``, default ../shared/meshes): stanford-bunny.obj and ogre.obj (no UVs: a
new xatlas atlas) and spot.obj (baked into the UVs it ships).

Each seed is baked twice, --seams off and erase (the same rays: the seed decides them).
At the seam points (3-point Gauss-Legendre per piece of every seam edge, so weighted sums
are exact integrals along the seams: ``aobake.targets.texels.seams.seam_points``) d is the
difference of the two sides' bilinear AO lookups.  Over S seeds:

- systematic = rms over the seam (weighted by length) of the mean of d over seeds, with
  the part the seeds' noise adds to that mean (random^2 / S) taken out;
- random = rms over the seam of the per-seed deviation from that mean (S - 1 dof);
- the systematic part again without the 1% of seam points whose mean difference is largest
  (``--worst N`` prints what N of them read: texels, coverage, baked and erased values);
- texel noise = rms of the texels' own stderr (``ao_stderr``) at the seam lookups
  (bilinear), and the noise the baked stderrs predict for d (sqrt(sum G^2 se^2));
- lookup noise = rms over the seam of the seeds' spread of the side-A lookup itself, which
  the erasure must not raise above the texel noise;
- shift = rms of the change the erasure makes to the mean (over seeds) of the two sides'
  lookups, i.e. what it adds to the value at the seam beyond the noise.
Timings are minimums over the seeds (the machine is shared): seams_s (the erasure, part of
splat_dilate_s) against the bake's wall time.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from aobake.api import bake_texels  # noqa: E402
from aobake.targets.texels import seams  # noqa: E402
from aobake.targets.texels.seams import (SeamMesh, bilinear, bilinear_stencil,  # noqa: E402
                                         seam_points)

SHARED = Path(__file__).resolve().parents[2] / "shared" / "meshes"
CASES = {"stanford-bunny.obj": "always", "spot.obj": "never", "ogre.obj": "always"}


def seam_mesh(result) -> SeamMesh:
    atlas = result.atlas
    return SeamMesh(atlas.positions, atlas.normals, atlas.faces, atlas.uv, atlas.faces,
                    atlas.wrap)


def predicted_sd(stderr, points, wrap):
    """sd of d from the texels' own independent errors: sqrt(sum_t G_pt^2 se_t^2)."""
    height, width = stderr.shape
    ta, wa = bilinear_stencil(points.uv_a, width, height, wrap)
    tb, wb = bilinear_stencil(points.uv_b, width, height, wrap)
    flat = stderr.reshape(-1).astype(np.float64)
    # both sides' stencils are disjoint except where a texel is read twice (rare): ignore
    return np.sqrt(np.sum((wa * flat[ta]) ** 2, axis=1) + np.sum((wb * flat[tb]) ** 2, axis=1))


def wrms(values, weight):
    return float(np.sqrt(np.sum(weight * values ** 2) / np.sum(weight)))


def worst_points(mean, which, points, runs, mesh) -> list:
    """What the worst seam points read: for each, its edge, mean difference, and per side
    its UV in texel-centre units and the 2 x 2 texels' (row, col), coverage and mean baked
    (off) and erased values -- the dump that found issue 21's classes (sides on a
    zero-area face's collapsed UVs, reading no covered texel; texels held at 0 or 1)."""
    covered = runs["off"][0].covered
    height, width = covered.shape
    off = np.mean([r.channels["ao"] for r in runs["off"]], axis=0, dtype=np.float64)
    erased = np.mean([r.channels["ao"] for r in runs["erase"]], axis=0, dtype=np.float64)
    rows = []
    for i in which:
        row = {"point": int(i), "edge": int(points.edge[i]), "d": float(mean[i])}
        for side, uv in (("a", points.uv_a), ("b", points.uv_b)):
            texel, w = bilinear_stencil(uv[i:i + 1], width, height, mesh.wrap)
            r, c = np.divmod(texel[0], width)
            row[side] = {"xy": (float(uv[i, 0] * width - 0.5),
                                float((1 - uv[i, 1]) * height - 0.5)),
                         "texels": list(zip(r.tolist(), c.tolist())),
                         "weights": w[0].round(3).tolist(),
                         "covered": covered[r, c].astype(int).tolist(),
                         "off": off[r, c].round(3).tolist(),
                         "erase": erased[r, c].round(3).tolist()}
        rows.append(row)
    return rows


def case(path: Path, unwrap: str, args) -> dict:
    runs = {"off": [], "erase": []}
    times = {"off": [], "erase": [], "seams_s": []}
    for seed in range(args.seeds):
        for mode in ("off", "erase"):
            clock = time.perf_counter()
            result = bake_texels(path, resolution=args.resolution, rays=args.rays, seed=seed,
                                 texel_samples=4, padding=8, unwrap=unwrap, seams=mode,
                                 threads=args.threads)
            times[mode].append(time.perf_counter() - clock)
            if mode == "erase":
                times["seams_s"].append(result.report["timings"]["seams_s"])
            runs[mode].append(result)
    mesh = seam_mesh(runs["off"][0])
    points = seam_points(mesh, args.resolution, args.resolution)
    weight = points.weight
    out = {"mesh": path.name, "atlas": runs["off"][0].report["texture"]["atlas"],
           "seam_edges": points.n_edges, "seam_points": len(weight),
           "seam_texels": float(weight.sum())}
    mean_lookup = {}
    for mode, results in runs.items():
        ao = [r.channels["ao"] for r in results]
        la = np.array([bilinear(a, points.uv_a, mesh.wrap) for a in ao])
        lb = np.array([bilinear(a, points.uv_b, mesh.wrap) for a in ao])
        d = la - lb
        s = len(d)
        mean = d.mean(axis=0)
        random = wrms(np.sqrt(np.sum((d - mean) ** 2, axis=0) / (s - 1)), weight)
        raw = wrms(mean, weight)
        se = [r.channels["ao_stderr"] for r in results]
        texel_noise = wrms(np.mean([bilinear(e, points.uv_a, mesh.wrap) for e in se], axis=0),
                           weight)
        # the same without the 1% of seam points whose mean difference is largest (issue
        # 21: a few seams that escape the erasure dominate the rms)
        worst = np.argsort(-np.abs(mean), kind="stable")[:len(mean) // 100]
        rest = np.ones(len(mean), dtype=bool)
        rest[worst] = False
        raw_rest = wrms(mean[rest], weight[rest])
        random_rest = wrms(np.sqrt(np.sum((d[:, rest] - mean[rest]) ** 2, axis=0) / (s - 1)),
                           weight[rest])
        out[mode] = {
            "systematic": float(np.sqrt(max(raw ** 2 - random ** 2 / s, 0.0))),
            "systematic_raw": raw,
            "systematic_without_worst": float(np.sqrt(max(raw_rest ** 2 - random_rest ** 2 / s,
                                                          0.0))),
            "random": random,
            "max_abs_d": float(np.abs(d).max()),
            "texel_noise": texel_noise,
            "predicted_d_noise": wrms(predicted_sd(se[0], points, mesh.wrap), weight),
            "lookup_noise": wrms(la.std(axis=0, ddof=1), weight),
        }
        mean_lookup[mode] = 0.5 * (la + lb).mean(axis=0)
        if mode == "erase" and args.worst:
            out["worst"] = worst_points(mean, worst[:args.worst], points, runs, mesh)
    erased = runs["erase"][0].report["texture"]["seams"]
    out["solve"] = {key: erased.get(key) for key in ("points_dropped", "bound_texels", "kappa",
                                                      "iterations", "converged")}
    out["erase"]["shift"] = wrms(mean_lookup["erase"] - mean_lookup["off"], weight)
    out["bake_s"] = {"off": min(times["off"]), "erase": min(times["erase"])}
    out["seams_s"] = min(times["seams_s"])
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolution", type=int, default=1024)
    parser.add_argument("--rays", type=int, default=256)
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--mesh", nargs="*", default=list(CASES))
    parser.add_argument("--meshes", type=Path, default=SHARED,
                        help="the folder of the meshes (default ../shared/meshes)")
    parser.add_argument("--worst", type=int, default=0,
                        help="print what the N worst seam points (mean erased difference) read")
    parser.add_argument("--kappa", type=float, default=None,
                        help="study: the seam weight (default seams.KAPPA)")
    args = parser.parse_args()
    if args.kappa is not None:
        seams.KAPPA = args.kappa
    for name in args.mesh:
        row = case(args.meshes / name, CASES.get(name, "auto"), args)
        print(f"{row['mesh']} ({row['atlas']}, {args.resolution}^2, {args.rays} rays, "
              f"{args.seeds} seeds): {row['seam_edges']} seam edges, "
              f"{row['seam_texels']:.0f} texels of seam, {row['seam_points']} points")
        for mode in ("off", "erase"):
            r = row[mode]
            print(f"  {mode:5s} systematic {r['systematic']:.5f} (raw {r['systematic_raw']:.5f},"
                  f" without the worst 1% {r['systematic_without_worst']:.5f})"
                  f"  random {r['random']:.5f}  max|d| {r['max_abs_d']:.4f}"
                  f"  | texel stderr {r['texel_noise']:.5f}  predicted sd(d) "
                  f"{r['predicted_d_noise']:.5f}  lookup noise {r['lookup_noise']:.5f}")
        print(f"  erase shifts the seam's mean lookup by {row['erase']['shift']:.5f} rms;"
              f" solve: {row['solve']}")
        for w in row.get("worst", []):
            print(f"    worst point {w['point']} edge {w['edge']} d {w['d']:+.4f}")
            for side in ("a", "b"):
                x = w[side]
                print(f"      {side}: at ({x['xy'][0]:.2f}, {x['xy'][1]:.2f}) texels "
                      f"{x['texels']} weights {x['weights']} covered {x['covered']} "
                      f"off {x['off']} erase {x['erase']}")
        print(f"  time (min over seeds): bake off {row['bake_s']['off']:.2f} s, erase "
              f"{row['bake_s']['erase']:.2f} s, of which seams_s {row['seams_s']:.3f} s")


if __name__ == "__main__":
    main()
