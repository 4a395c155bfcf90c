"""``--method hemicube``: the culled draw against the whole draw, cost per point, side by side
in one run (issue 33 point 3).

    python benchmarks/bench_hemicube_batched.py [--points 48] [--small-points 300]
        [--resolution 64] [--reps 2] [--threads 1] [--cluster 32] [--json PATH]

Meshes: the Stanford bunny (69,451 triangles) and spot (5,856) from /work/shared/meshes when
there, the bundled still life (37,064), and two small test meshes built here: a torus over a
floor (624 triangles) and an icosphere (80).  Points: drawn by area on each mesh's triangles
(seeded), at their triangles' normals, with the method's own eyes and near planes
(``HemicubeMethod.eyes``: the ray origins).

Each way is a ``hemicube_gl.Rasteriser`` in this process (its own EGL context, made current
around its draws): ``cull=False`` draws every triangle five times per point (the draw before
issue 33), ``cull=True`` the runs of clusters the cull keeps.  ``draw`` is timed whole
(drawing, read-back, the per-point sums) on the same points, the two ways alternated
``--reps`` times and the fastest of each kept, so both see the same machine load; the ratio
is whole / culled from the same run.  Every run's values are compared bit for bit (ao and
blocked pixels per point: the tiles are the same).  "drawn" is the share of the 5 x triangles
per point the culled draw hands to the GL.  The machine is shared: absolute times move with
its load, the ratios much less.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aobake.methods import hemicube_cells, hemicube_gl  # noqa: E402
from aobake.methods.hemicube import HemicubeMethod, HemicubeOptions  # noqa: E402
from aobake.scene import load_scene  # noqa: E402
from aobake.settings import BakeConfig  # noqa: E402
from aobake.vectors import defined  # noqa: E402
from aobake.warp import frames  # noqa: E402

SHARED = Path("/work/shared/meshes")


def meshes() -> list:
    """(name, mesh or path, large): the meshes there are."""
    out = []
    if (SHARED / "stanford-bunny.obj").exists():
        out.append(("bunny", str(SHARED / "stanford-bunny.obj"), True))
    out.append(("still life", str(ROOT / "assets" / "still_life.obj"), True))
    if (SHARED / "spot.obj").exists():
        out.append(("spot", str(SHARED / "spot.obj"), False))
    floor = trimesh.Trimesh([[-2.5, -2.5, -0.45], [2.5, -2.5, -0.45], [2.5, 2.5, -0.45],
                             [-2.5, 2.5, -0.45]], [[0, 1, 2], [0, 2, 3]], process=False)
    torus = trimesh.creation.torus(1.0, 0.4, major_sections=26, minor_sections=12)
    out.append(("torus + floor", trimesh.util.concatenate([torus, floor]), False))
    out.append(("icosphere", trimesh.creation.icosphere(1), False))
    return out


def case(source, n: int, resolution: int, seed: int = 1) -> dict:
    """What the method hands its GL child for n surface points of the mesh."""
    scene = load_scene(source)
    method = HemicubeMethod.prepare(scene, BakeConfig(), None, 0,
                                    options=HemicubeOptions(resolution))
    method.close()  # its GL child started ahead: not used here
    areas = scene.areas()
    rng = np.random.default_rng(seed)
    face = rng.choice(len(areas), size=n, p=areas / areas.sum())
    u = rng.random((n, 2))
    u[u.sum(axis=1) > 1] = 1 - u[u.sum(axis=1) > 1]
    corners = scene.vertices[scene.faces[face]]
    points = corners[:, 0] + u[:, :1] * (corners[:, 1] - corners[:, 0]) \
        + u[:, 1:] * (corners[:, 2] - corners[:, 0])
    normals = scene.face_normals[face]
    keep = defined(normals)
    points, normals = points[keep], normals[keep]
    eyes, near = method.eyes(points, normals, np.sqrt(2 * areas[face][keep]))
    t, b = frames(normals)
    return dict(vertices=method.vertices, faces=method.faces, eyes=eyes.astype(np.float32),
                frames=np.stack([t, b, normals], axis=1).astype(np.float32),
                near=near.astype(np.float32), max_distance=method.max_distance * method.scale)


def measure(name: str, source, n: int, args) -> dict:
    c = case(source, n, args.resolution)
    weight = hemicube_cells.weights(args.resolution, "cosine")
    ways = {cull: hemicube_gl.Rasteriser(c["vertices"], c["faces"], args.resolution,
                                         c["max_distance"], cull=cull)
            for cull in (False, True)}
    seconds = {False: [], True: []}
    values = {}
    for _ in range(args.reps):
        for cull, raster in ways.items():
            with raster.ctx:
                raster.draw(c["eyes"][:2], c["frames"][:2], c["near"][:2], weight)  # compile
                clock = time.perf_counter()
                out = raster.draw(c["eyes"], c["frames"], c["near"], weight)
                seconds[cull].append(time.perf_counter() - clock)
            got = (out["ao"], out["blocked_pixels"])
            values.setdefault(cull, got)
            assert all(np.array_equal(a, b) for a, b in zip(values[cull], got))
    identical = all(np.array_equal(a, b) for a, b in zip(values[False], values[True]))
    culled = ways[True]
    commands, _, _ = hemicube_gl.cull_commands(
        culled.clusters, c["eyes"].astype(np.float64), c["frames"].astype(np.float64),
        c["near"].astype(np.float64))
    n_points, triangles = len(c["eyes"]), len(c["faces"])
    for raster in ways.values():
        raster.release()
    whole_ms, culled_ms = (1e3 * min(seconds[k]) / n_points for k in (False, True))
    return {"mesh": name, "triangles": triangles, "points": n_points,
            "resolution": args.resolution, "whole_ms_per_point": whole_ms,
            "culled_ms_per_point": culled_ms, "ratio": whole_ms / culled_ms,
            "drawn_fraction": float(commands[:, 0].sum() / 3 / (5 * triangles * n_points)),
            "identical": bool(identical)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--points", type=int, default=48, help="points on the large meshes")
    parser.add_argument("--small-points", type=int, default=300,
                        help="points on the small meshes")
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--reps", type=int, default=2)
    parser.add_argument("--threads", type=int, default=1, help="llvmpipe's raster threads")
    parser.add_argument("--cluster", type=int, default=hemicube_gl.CLUSTER_TRIANGLES)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    os.environ["LP_NUM_THREADS"] = str(args.threads)  # read when a context is made
    hemicube_gl.CLUSTER_TRIANGLES = args.cluster
    rows = []
    print(f"R = {args.resolution}, clusters of {args.cluster}, LP_NUM_THREADS={args.threads}, "
          f"load {os.getloadavg()[0]:.1f}", flush=True)
    print(f"{'mesh':<14} {'triangles':>9} {'points':>6} {'whole ms/pt':>11} "
          f"{'culled ms/pt':>12} {'ratio':>6} {'drawn':>6}  same bits", flush=True)
    for name, source, large in meshes():
        row = measure(name, source, args.points if large else args.small_points, args)
        rows.append(row)
        print(f"{row['mesh']:<14} {row['triangles']:>9} {row['points']:>6} "
              f"{row['whole_ms_per_point']:>11.2f} {row['culled_ms_per_point']:>12.2f} "
              f"{row['ratio']:>5.1f}x {100 * row['drawn_fraction']:>5.1f}%  "
              f"{row['identical']}", flush=True)
    if args.json:
        args.json.write_text(json.dumps({"load": os.getloadavg()[0], "rows": rows}, indent=1))
    return 0 if all(r["identical"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
