"""The speed/accuracy trade, measured and drawn: RMS error against rays and against seconds.

    python benchmarks/bench_accuracy.py [--quick] [--threads 2] [--out docs/img] [--json PATH]

For each sampler (and for ``--tolerance``), on

* a closed-form scene: floor points under a tilted 17-gon (exact AO from Lambert's
  polygon formula at each ray origin, ``tests/analytic.py``), 4000 independent points;
* the bunny and the ogre (``../shared/meshes``), every vertex, against a 16,384-ray
  reference of another seed (cached in /tmp); the reference's own noise (its mean
  stderr^2) is subtracted from the mean squared error, and printed.

Seconds are the whole library call (``aobake.bake(path)``: file read included, or
``bake_points``) on this machine.  Prints markdown tables, writes the PNG plots of
docs/accuracy.md and a table: for a target RMS error, the rays and the seconds per million
points (log-log interpolation between measured counts).  Needs matplotlib (``[peers]``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import aobake  # noqa: E402
from aobake.samplers import SAMPLERS  # noqa: E402
from analytic import polygon_form_factors  # noqa: E402

SHARED = ROOT.parent / "shared" / "meshes"
RAYS = (16, 32, 64, 128, 256, 512, 1024)
TOLERANCES = (0.04, 0.02, 0.01)
TARGETS = (0.02, 0.01, 0.005, 0.0025)
REFERENCE_RAYS = 16384


def disc_scene(points: int):
    """(mesh, points (n, 3), normals (n, 3)): floor points under a tilted 17-gon."""
    import trimesh

    sides, radius = 17, 1.0
    angle = np.linspace(0.0, 2.0 * np.pi, sides, endpoint=False)
    ring = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros(sides)], axis=1)
    turn = trimesh.transformations.rotation_matrix(math.radians(25.0), (1.0, 0.3, 0.0))[:3, :3]
    ring = ring @ turn.T + np.array([0.2, 0.1, 0.8])
    vertices = np.vstack([[0.2, 0.1, 0.8], ring])
    faces = np.array([[0, 1 + i, 1 + (i + 1) % sides] for i in range(sides)])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    rng = np.random.default_rng(7)
    pts = np.zeros((points, 3))
    pts[:, :2] = rng.uniform(-1.5, 1.5, (points, 2))
    return mesh, pts, np.tile([0.0, 0.0, 1.0], (points, 1))


def _exact(mesh, points, normals, report) -> np.ndarray:
    """Exact AO at the ray origins (the points lifted by the documented offset)."""
    from aobake.trace import point_offsets

    params = report["parameters"]
    scale = params["trace_scale"]
    local = (points - np.asarray(params["rebase_center"])) * scale
    size = np.sqrt(2.0 * np.median(mesh.area_faces)) * scale
    offsets = point_offsets(local, np.full(len(points), size), report["config"]["ray_offset"])
    origins = points + (offsets / scale)[:, None] * normals
    return 1.0 - polygon_form_factors(origins, normals, mesh.vertices[1:])


def closed_form(args) -> dict:
    mesh, points, normals = disc_scene(args.points)
    exact = None
    rows = {}
    for sampler in SAMPLERS:
        rows[sampler] = []
        for rays in args.rays:
            start = time.perf_counter()
            res = aobake.bake_points(mesh, points, normals, rays=rays, sampler=sampler,
                                     threads=args.threads, seed=1)
            wall = time.perf_counter() - start
            if exact is None:
                exact = _exact(mesh, points, normals, res.report)
            rows[sampler].append(_row(res, exact, None, wall, len(points)))
    rows["tolerance"] = []
    for tolerance in args.tolerances:
        start = time.perf_counter()
        res = aobake.bake_points(mesh, points, normals, tolerance=tolerance, threads=args.threads,
                                 seed=1, rays=64)
        wall = time.perf_counter() - start
        rows["tolerance"].append(_row(res, exact, None, wall, len(points), tolerance))
    return rows


def _row(res, truth, ref_se, wall, points, tolerance=None) -> dict:
    """One measurement; ref_se (n,) the reference's stderr (its noise is subtracted) or None."""
    keep = res.rays > 0
    err2 = float(np.mean(np.square(res.ao[keep] - truth[keep])))
    if ref_se is not None:
        err2 = max(err2 - float(np.mean(np.square(ref_se[keep]))), 0.0)
    return {"rays": float(res.rays[keep].mean()), "seconds": wall, "points": points,
            "rmse": math.sqrt(err2), "rms_stderr": float(np.sqrt(np.mean(
                np.square(res.ao_stderr[keep])))), "tolerance": tolerance}


def reference(path: Path, threads: int):
    cache = Path("/tmp") / f"aobake_accuracy_ref_{path.stem}_{REFERENCE_RAYS}.npz"
    # The same reference (sobol, 16384 rays, seed 987654321) as bench_peers.py's, if cached.
    shared = sorted(Path("/tmp").glob(f"aobake_peers_ref_{path.stem}_cosine_{REFERENCE_RAYS}_"
                                      "987654321_*.npz"))
    if shared and not cache.exists():
        with np.load(shared[-1]) as data:
            return data["ao"], data["ao_stderr"]
    if cache.exists():
        with np.load(cache) as data:
            return data["ao"], data["stderr"]
    res = aobake.bake(path, rays=REFERENCE_RAYS, seed=987654321, threads=threads)
    np.savez(cache, ao=res.ao, stderr=res.ao_stderr)
    return res.ao, res.ao_stderr


def mesh_rows(path: Path, args) -> dict:
    truth, ref_se = reference(path, args.threads)
    traced = ref_se < 0.5  # vertices without a normal carry the no-information 1/2
    rows = {"reference_rms_stderr": math.sqrt(float(np.mean(np.square(ref_se[traced]))))}
    for sampler in SAMPLERS:
        rows[sampler] = []
        for rays in args.rays:
            start = time.perf_counter()
            res = aobake.bake(path, rays=rays, sampler=sampler, threads=args.threads, seed=1)
            wall = time.perf_counter() - start
            rows[sampler].append(_row(res, truth, ref_se, wall, len(res.positions)))
    rows["tolerance"] = []
    for tolerance in args.tolerances:
        start = time.perf_counter()
        res = aobake.bake(path, tolerance=tolerance, threads=args.threads, seed=1)
        wall = time.perf_counter() - start
        rows["tolerance"].append(_row(res, truth, ref_se, wall, len(res.positions), tolerance))
    return rows


def interpolate(rows: list, target: float, key: str) -> float | None:
    """``key`` (rays or seconds) at which the RMSE reaches ``target`` (log-log)."""
    ordered = sorted(rows, key=lambda r: r[key])
    for a, b in zip(ordered, ordered[1:]):
        if a["rmse"] >= target >= b["rmse"] > 0:
            t = (math.log(target) - math.log(a["rmse"])) / (math.log(b["rmse"]) - math.log(a["rmse"]))
            return math.exp(math.log(a[key]) + t * (math.log(b[key]) - math.log(a[key])))
    return None


def table(name: str, rows: dict) -> str:
    lines = [f"### {name}", ""]
    if "reference_rms_stderr" in rows:
        lines += [f"reference: {REFERENCE_RAYS} rays (sobol, another seed), rms stderr "
                  f"{rows['reference_rms_stderr']:.5f} (its mean stderr^2 is subtracted)", ""]
    lines += ["| method | rays/point | seconds | RMSE | rms stderr |", "|---|---|---|---|---|"]
    for method, entries in rows.items():
        if not isinstance(entries, list):
            continue
        for r in entries:
            label = method if r["tolerance"] is None else f"tolerance {r['tolerance']:g}"
            lines.append(f"| {label} | {r['rays']:.0f} | {r['seconds']:.2f} | {r['rmse']:.5f} | "
                         f"{r['rms_stderr']:.5f} |")
    lines += ["", "| target RMSE | " + " | ".join(
        f"{m} rays / s per M points" for m in rows if isinstance(rows[m], list)) + " |",
        "|---|" + "---|" * sum(isinstance(v, list) for v in rows.values())]
    for target in TARGETS:
        cells = []
        for method, entries in rows.items():
            if not isinstance(entries, list):
                continue
            rays = interpolate(entries, target, "rays")
            secs = interpolate([dict(r, seconds=r["seconds"] / r["points"] * 1e6)
                                for r in entries], target, "seconds")
            cells.append("—" if rays is None else f"{rays:.0f} / {secs:.0f} s")
        lines.append(f"| {target:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(results: dict, out: Path) -> list:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, rows in results.items():
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
        for method, entries in rows.items():
            if not isinstance(entries, list) or not entries:
                continue
            style = "o--" if method == "tolerance" else "o-"
            label = "--tolerance" if method == "tolerance" else method
            for ax, key in zip(axes, ("rays", "seconds")):
                xs = [r[key] if key == "rays" else r[key] / r["points"] * 1e6 for r in entries]
                ax.loglog(xs, [max(r["rmse"], 1e-6) for r in entries], style, label=label)
        axes[0].set_xlabel("rays per point (mean)")
        axes[1].set_xlabel("seconds per million points (2 threads)")
        for ax in axes:
            ax.set_ylabel("RMS error of AO")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend()
        fig.suptitle(name)
        fig.tight_layout()
        path = out / f"accuracy_{name.split()[0].lower()}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="smoke run: few points and rays")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--points", type=int, default=4000)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "img")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--meshes", nargs="*", default=["stanford-bunny", "ogre"])
    args = parser.parse_args()
    args.rays, args.tolerances = RAYS, TOLERANCES
    if args.quick:
        args.points, args.rays, args.tolerances, args.meshes = 300, (16, 64), (0.05,), []
    results = {"closed-form (disc)": closed_form(args)}
    for name in args.meshes:
        path = SHARED / f"{name}.obj"
        if not path.exists():
            print(f"{path}: not found, skipped", file=sys.stderr)
            continue
        results[f"{name} (every vertex)"] = mesh_rows(path, args)
    for name, rows in results.items():
        print(table(name, rows), end="\n\n")
    for path in plot(results, args.out):
        print(f"wrote {path}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
