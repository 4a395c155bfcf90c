"""``--method discs`` measured: its cost against the element count (hierarchy and brute
force, with the log-log slope), and its error against ray-traced AO on the Stanford bunny
for kappa in {1, 2, 4, 8} and brute force, pass by pass.

    python benchmarks/bench_discs.py [--quick] [--max-n 1048576] [--max-brute-n 32768]
                                     [--threads 1] [--truth-rays 1024] [--json PATH]
                                     [--plot PATH]

Scaling: tori of n = m^2 vertices, n doubling from 4096 (a numpy grid, so building the
mesh costs nothing here); each row is one whole per-vertex bake with the default two
passes: prepare (the tree, the elements' pass 1) and the estimate at every element.  The slope is the
least-squares slope of log(seconds) on log(n) over the rows with n >= 16384 (below that,
fixed costs dominate): 1 for O(n), about 1.1 for O(n log n) over this range, 2 for O(n^2).

Accuracy: every vertex of ``../shared/meshes/stanford-bunny.obj`` against a ray-traced
bake (``aobake.bake``, ``--truth-rays`` cosine-weighted rays, cached in /tmp), and the
uniform-weighted one as well (the disc formula's on-axis factor is a solid angle).  The
truth's own noise (its mean stderr^2) is subtracted from the mean squared error; the
printed ``truth noise`` says how much that was.  Seconds are prepare + estimate, on
``--threads`` threads.  Numbers from a shared, loaded machine are slower than a quiet one.
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

import aobake  # noqa: E402
from aobake.settings import BakeConfig  # noqa: E402
from aobake.methods.discs import DiscsMethod, DiscsOptions, elements  # noqa: E402
from aobake.scene import load_scene  # noqa: E402
from aobake.records import SamplePoints  # noqa: E402
from aobake.targets.vertices import VertexTarget  # noqa: E402
from aobake.vectors import defined  # noqa: E402

SHARED = ROOT.parent / "shared" / "meshes"
BUNNY = SHARED / "stanford-bunny.obj"
KAPPAS = (1.0, 2.0, 4.0, 8.0)


class Grid:
    """A torus of m x m vertices (major radius 1, minor 0.4) with what ``elements`` reads:
    vertices, faces, face_normals, areas()."""

    def __init__(self, m: int):
        u, v = np.meshgrid(np.arange(m) * 2 * np.pi / m, np.arange(m) * 2 * np.pi / m,
                           indexing="ij")
        ring = 1.0 + 0.4 * np.cos(v)
        self.vertices = np.stack([ring * np.cos(u), ring * np.sin(u), 0.4 * np.sin(v)],
                                 axis=-1).reshape(-1, 3)
        i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
        a, b = i * m + j, ((i + 1) % m) * m + j
        c, d = ((i + 1) % m) * m + (j + 1) % m, i * m + (j + 1) % m
        self.faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                                     np.stack([a, c, d], -1).reshape(-1, 3)])
        tri = self.vertices[self.faces]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(cross, axis=1)
        self.face_normals = cross / length[:, None]
        self._areas = length / 2

    def areas(self):
        return self._areas


def whole_bake(position, normal, area, options: DiscsOptions, threads: int) -> tuple:
    """(seconds, prepare seconds, mean terms per point) of a per-vertex bake of the discs."""
    clock = time.perf_counter()
    method = DiscsMethod.from_elements(position, normal, area, options, threads=threads)
    prepared = time.perf_counter() - clock
    points = SamplePoints(position, normal, np.arange(len(position), dtype=np.int64))
    got = method.estimate(points, threads, 131072)
    return time.perf_counter() - clock, prepared, float(got.extras["discs_terms"].mean())


def slope(rows: list) -> float | None:
    big = [(n, s) for n, s in rows if n >= 16384]
    if len(big) < 2:
        return None
    x, y = np.log([n for n, _ in big]), np.log([s for _, s in big])
    return float(np.polyfit(x, y, 1)[0])


def scaling(max_n: int, max_brute_n: int, threads: int) -> dict:
    print("\n## Time against n (a whole two-pass per-vertex bake)\n")
    print("| n | hierarchy s | (prepare s) | terms/point | us/point | brute s | brute us/point |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    out = {"hierarchy": [], "brute": []}
    for m in (64, 90, 128, 181, 256, 362, 512, 724, 1024):  # n doubles: m grows by sqrt(2)
        if m * m > max_n:
            break
        position, normal, area = elements(Grid(m))
        n = len(position)
        seconds, prepared, terms = whole_bake(position, normal, area, DiscsOptions(), threads)
        out["hierarchy"].append((n, seconds))
        brute = ""
        if n <= max_brute_n:
            b, _, _ = whole_bake(position, normal, area, DiscsOptions(discs_traversal="brute"),
                                 threads)
            out["brute"].append((n, b))
            brute = f"{b:.2f} | {b / n * 1e6:.1f}"
        else:
            brute = "- | -"
        print(f"| {n} | {seconds:.2f} | {prepared:.2f} | {terms:.0f} | {seconds / n * 1e6:.1f} "
              f"| {brute} |", flush=True)
    out["slope_hierarchy"], out["slope_brute"] = slope(out["hierarchy"]), slope(out["brute"])
    fmt = (lambda s: "n/a (too few rows >= 16384)" if s is None else f"{s:.2f}")
    print(f"\nlog-log slope (n >= 16384): hierarchy {fmt(out['slope_hierarchy'])}, "
          f"brute force {fmt(out['slope_brute'])}")
    return out


def truth(rays: int, weighting: str, threads: int) -> dict:
    cache = Path(f"/tmp/aobake_discs_truth_{weighting}_{rays}.npz")
    if cache.exists():
        data = np.load(cache)
        return {"ao": data["ao"], "stderr": data["stderr"], "seconds": float(data["seconds"])}
    clock = time.perf_counter()
    result = aobake.bake(BUNNY, rays=rays, seed=1, weighting=weighting, threads=threads)
    seconds = time.perf_counter() - clock
    np.savez(cache, ao=result.ao, stderr=result.ao_stderr, seconds=seconds)
    return {"ao": result.ao, "stderr": result.ao_stderr, "seconds": seconds}


def accuracy(truth_rays: int, threads: int, kappas=KAPPAS, brute: bool = True) -> dict:
    scene = load_scene(BUNNY)
    config = BakeConfig()
    plan = VertexTarget().sample(scene, config, None, threads, {}, [])
    truths = {w: truth(truth_rays, w, threads) for w in ("cosine", "uniform")}
    sampled = defined(scene.vertex_normals)  # the others hold no-information values
    print(f"\n## Error against ray-traced AO: {BUNNY.name}, {int(sampled.sum())} vertices\n")
    for w, t in truths.items():
        noise = float(np.mean(t["stderr"][sampled] ** 2))
        print(f"truth ({w}): {truth_rays} rays, {t['seconds']:.1f} s, truth noise "
              f"(rms stderr) {math.sqrt(noise):.4f}")
    print("\n| setting | s | terms/point | RMSE cos (pass 1, 2, result) | bias cos (result) | "
          "max cos | RMSE uniform (result) | bias uniform |")
    print("|---|---:|---:|---|---:|---:|---:|---:|")
    settings = [(f"kappa {k:g}", DiscsOptions(discs_kappa=k)) for k in kappas]
    settings += [("kappa 4, k 3 (the CD's)", DiscsOptions(discs_k=3.0))]
    if brute:  # O(n^2): about a minute per pass on the bunny
        settings.append(("brute force", DiscsOptions(discs_traversal="brute")))
    out = {}
    for label, options in settings:
        clock = time.perf_counter()
        method = DiscsMethod.prepare(scene, config, None, 0, options=options)
        got = method.estimate(plan, threads, 131072)
        seconds = time.perf_counter() - clock
        ao = got.fields["ao"][plan.state][sampled]
        passes = got.extras["discs_passes"][plan.state][sampled]
        row = {"seconds": seconds, "terms": float(got.extras["discs_terms"].mean())}
        for w, t in truths.items():
            ref, noise = t["ao"][sampled], float(np.mean(t["stderr"][sampled] ** 2))

            def rmse(values):
                return math.sqrt(max(float(np.mean((values - ref) ** 2)) - noise, 0.0))

            row[w] = {"rmse": rmse(ao), "bias": float(np.mean(ao - ref)),
                      "max": float(np.abs(ao - ref).max()),
                      "rmse_passes": [rmse(passes[:, j]) for j in range(passes.shape[1])]}
        cos, uni = row["cosine"], row["uniform"]
        print(f"| {label} | {seconds:.2f} | {row['terms']:.0f} | "
              f"{', '.join(f'{r:.4f}' for r in cos['rmse_passes'])}, {cos['rmse']:.4f} | "
              f"{cos['bias']:+.4f} | {cos['max']:.3f} | {uni['rmse']:.4f} | "
              f"{uni['bias']:+.4f} |", flush=True)
        out[label] = row
    return out


def plot(path: Path, rows: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4))
    for name, marker in (("hierarchy", "o"), ("brute", "s")):
        if rows[name]:
            n, s = zip(*rows[name])
            ax.loglog(n, s, marker=marker, label=f"{name} (slope "
                      f"{rows['slope_' + name]:.2f})" if rows["slope_" + name] else name)
    ax.set_xlabel("elements n (= receivers)")
    ax.set_ylabel("seconds, whole two-pass bake")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="n up to 65536 (brute force 16384), truth 512 rays, no brute "
                        "force on the bunny")
    parser.add_argument("--max-n", type=int, default=1 << 20)
    parser.add_argument("--max-brute-n", type=int, default=1 << 15)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--truth-rays", type=int, default=1024)
    parser.add_argument("--json", type=Path)
    parser.add_argument("--plot", type=Path, help="write the log-log plot (needs matplotlib)")
    args = parser.parse_args(argv)
    if args.plot:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            parser.error("--plot needs matplotlib (pip install matplotlib)")
    if args.quick:
        args.max_n, args.max_brute_n = min(args.max_n, 1 << 16), min(args.max_brute_n, 1 << 14)
        args.truth_rays = min(args.truth_rays, 512)
    results = {"scaling": scaling(args.max_n, args.max_brute_n, args.threads)}
    results["accuracy"] = accuracy(args.truth_rays, args.threads, brute=not args.quick)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    if args.plot:
        plot(args.plot, results["scaling"])


if __name__ == "__main__":
    main()
