"""``--method hemicube`` measured: error against resolution against time per point, on the
bundled still life (``assets/still_life.obj``, 37,064 triangles), against a many-ray truth.

    python benchmarks/bench_hemicube.py [--points 300] [--resolutions 8,16,32,64,128,256]
                                        [--truth-rays 16384] [--threads 1]
                                        [--weighting cosine] [--json PATH]

Points: ``--points`` points drawn by area on the still life's triangles with a fixed seed,
at their triangles' normals and sizes (``query_points`` says why not vertices), through
``aobake.bake_points`` (the same ray offset for both methods).  Truth: the
ray-traced bake of the same points with ``--truth-rays`` rays (sobol, cached in /tmp); its
own noise (mean stderr^2) is subtracted from the hemicube's mean squared error, and printed.
Time: the whole ``bake_points`` call (scene load, the scene's BVH, the GL child's start
~0.4 s, drawing) per point, and for the hemicube the drawing alone per point (the call minus
the same call on one point).  The ray-traced baker with few rays is timed on the same points
for comparison (its whole call: at these counts mostly the scene's load).  Numbers from a
shared, loaded machine are slower than a quiet one; the errors are deterministic.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import aobake  # noqa: E402
from aobake.methods.hemicube import HemicubeMethod, HemicubeOptions  # noqa: E402
from aobake.scene import load_scene  # noqa: E402
from aobake.vectors import defined  # noqa: E402

ASSET = ROOT / "assets" / "still_life.obj"


def query_points(n: int, seed: int = 1):
    """n points drawn uniformly by area on the still life's triangles (seeded), with their
    triangles' normals and sizes (sqrt of twice the area).  Surface points, not vertices:
    the asset's slabs are separate patches, so a vertex on a patch's rim lies exactly in its
    neighbour's plane (and the objects' rims in the floor's), where the ray tracer's origin
    sits on that plane (hits at t = 0: AO 0) and the rasteriser sees the plane edge-on (it
    blocks nothing): AO is not defined there, and the two disagree by up to 1."""
    scene = load_scene(str(ASSET))
    areas = scene.areas()
    rng = np.random.default_rng(seed)
    face = rng.choice(len(areas), size=n, p=areas / areas.sum())
    u = rng.random((n, 2))
    flip = u.sum(axis=1) > 1
    u[flip] = 1 - u[flip]
    corners = scene.vertices[scene.faces[face]]
    points = corners[:, 0] + u[:, :1] * (corners[:, 1] - corners[:, 0]) \
        + u[:, 1:] * (corners[:, 2] - corners[:, 0])
    normals = scene.face_normals[face]
    keep = defined(normals)
    return points[keep], normals[keep], np.sqrt(2 * areas[face])[keep]


def truth(points, normals, sizes, rays: int, weighting: str, threads: int):
    """(ao, ao_stderr) of the ray-traced bake, cached in /tmp by its settings."""
    key = f"{len(points)}-{rays}-{weighting}-{hash(points.tobytes()) & 0xFFFFFFFF:08x}"
    cache = Path("/tmp") / f"aobake-bench-hemicube-truth-{key}.npz"
    if cache.exists():
        with np.load(cache) as data:
            return data["ao"], data["ao_stderr"]
    result = aobake.bake_points(str(ASSET), points, normals, point_sizes=sizes, rays=rays,
                                weighting=weighting, seed=12345, threads=threads)
    np.savez(cache, ao=result.ao, ao_stderr=result.ao_stderr)
    return result.ao, result.ao_stderr


def timed(function):
    clock = time.perf_counter()
    value = function()
    return value, time.perf_counter() - clock


def score(ao, exact, noise2) -> dict:
    error = ao - exact
    mse = max(float(np.mean(error ** 2)) - noise2, 0.0)
    return {"rmse": mse ** 0.5, "bias": float(error.mean()),
            "max_abs": float(np.abs(error).max())}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--points", type=int, default=300)
    parser.add_argument("--resolutions", default="8,16,32,64,128,256")
    parser.add_argument("--truth-rays", type=int, default=16384)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--weighting", default="cosine", choices=("cosine", "uniform"))
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)

    points, normals, sizes = query_points(args.points)
    n = len(points)
    exact, stderr = truth(points, normals, sizes, args.truth_rays, args.weighting,
                          args.threads)
    noise2 = float(np.mean(stderr ** 2))
    print(f"{ASSET.name}: {n} points, truth {args.truth_rays} rays (noise rms "
          f"{noise2 ** 0.5:.5f}), weighting {args.weighting}, threads {args.threads}")
    print(f"{'method':>16} {'rmse':>8} {'bias':>9} {'max|err|':>9} {'call s':>7} "
          f"{'ms/point':>9} {'draw ms/pt':>10}")
    rows = []
    for r in (int(x) for x in args.resolutions.split(",")):
        HemicubeMethod.options = HemicubeOptions(hemicube_resolution=r)

        def bake(k):
            return aobake.bake_points(str(ASSET), points[:k], normals[:k],
                                      point_sizes=sizes[:k], method="hemicube",
                                      weighting=args.weighting, threads=args.threads)
        _, fixed = timed(lambda: bake(1))
        result, seconds = timed(lambda: bake(n))
        row = {"method": "hemicube", "resolution": r, **score(result.ao, exact, noise2),
               "seconds": seconds, "ms_per_point": 1000 * seconds / n,
               "draw_ms_per_point": 1000 * (seconds - fixed) / max(n - 1, 1)}
        rows.append(row)
        print(f"{'hemicube R=' + str(r):>16} {row['rmse']:8.5f} {row['bias']:+9.5f} "
              f"{row['max_abs']:9.5f} {seconds:7.2f} {row['ms_per_point']:9.2f} "
              f"{row['draw_ms_per_point']:10.2f}")
    for rays in (16, 64, 256):
        def trace(k):
            return aobake.bake_points(str(ASSET), points[:k], normals[:k],
                                      point_sizes=sizes[:k], rays=rays,
                                      weighting=args.weighting, threads=args.threads)
        result, seconds = timed(lambda: trace(n))
        row = {"method": "rays", "rays": rays, **score(result.ao, exact, noise2),
               "seconds": seconds, "ms_per_point": 1000 * seconds / n}
        rows.append(row)
        print(f"{'rays ' + str(rays):>16} {row['rmse']:8.5f} {row['bias']:+9.5f} "
              f"{row['max_abs']:9.5f} {seconds:7.2f} {row['ms_per_point']:9.2f}")
    if args.json:
        args.json.write_text(json.dumps({"asset": ASSET.name, "points": n,
                                         "truth_rays": args.truth_rays,
                                         "truth_noise_rms": noise2 ** 0.5,
                                         "weighting": args.weighting,
                                         "threads": args.threads, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
