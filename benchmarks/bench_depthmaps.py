"""``--method depthmaps`` measured: its error against the ray-traced truth, split into its
sources (the directions K, the map resolution N, the bias b), against time, and how its
error is shared between points (issue 33 point 1).

    python benchmarks/bench_depthmaps.py [--mesh bunny] [--points 0] [--truth-rays 2048]
        [--threads 2] [--directions 16,64,256,1024] [--traced-directions 4096]
        [--resolutions 256,512,1024,2048] [--biases 0.25,0.5,0.71,1,2,4] [--seeds 8]
        [--rays 16,32,64,128,256,512,1024] [--work /tmp/aobake_depthmaps] [--json PATH]
        [--plot docs/img/depthmaps_error.png] [--views docs/img/depthmaps_views.png]
        [--parts rays,k,n,b,seeds,views]

Points: as ``bench_approximations`` (as many as the mesh has vertices, drawn by area with a
fixed seed, at their triangles' normals and sizes).  Truth: ``aobake.bake_points`` with
``--truth-rays`` sobol rays, seed 1001 (cached in ``--work``); every error below is
``aobake.compare.metrics`` against it: RMSE, bias (candidate - truth), max, and the RMSE
with the truth's own noise taken out (``rmse_without_reference_noise``, "excess").

The error sources, apart:
- ``traced`` (no GL): the same K directions with exact visibility, each point's K rays
  traced by Embree from the ray tracer's origins (``depthmaps.traced``): the directions'
  error alone, what the method tends to as N grows and b falls;
- ``maps``: the GL values minus ``traced`` at the same K and seed: the maps' error alone
  (resolution and bias);
- sweeps: K at the default N and b; N at the default K and b; b at the default K and N.

Shared error: every point uses the same K directions, so the error is correlated between
points.  ``seeds``: over ``--seeds`` seeds (rotations of the lattice), the spread of the
mean error over all points against what independent errors of the same rms would give
(rms / sqrt(points)), beside the ray tracer's at a ray count of similar rms; and the
correlation of two points' errors against their distance (pairs within distance bins).
``views``: a camera view of the truth, rays and depthmaps at similar rms, and their error
maps (the depth maps' bands against the rays' noise).

Time: wall-clock seconds of a whole estimate (the GL child's start, K maps, the point
passes) on ``--threads`` (llvmpipe's threads); rays: the whole ``bake_points``.  The machine
is shared (2 cores, other jobs running): times are pessimistic; errors are deterministic.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import aobake  # noqa: E402
from aobake.compare import metrics  # noqa: E402
from aobake.methods.depthmaps import DepthmapsMethod, directions, traced  # noqa: E402
from aobake.occluders import build  # noqa: E402
from aobake.records import SamplePoints  # noqa: E402
from aobake.scene import load_scene  # noqa: E402
from aobake.settings import BakeConfig  # noqa: E402
from aobake.settings.depthmaps import (DEFAULT_BIAS, DEFAULT_DIRECTIONS,  # noqa: E402
                                       DEFAULT_RESOLUTION, DepthmapsOptions)
from bench_approximations import MESHES, query_points  # noqa: E402

#: distance bins of the correlogram, in units of the bounding-box diagonal
BINS = (0.0, 0.0025, 0.005, 0.01, 0.02, 0.04, 0.08, 0.16, 0.32)
#: the point pairs drawn per distance bin
PAIRS = 20000


def _ints(text):
    return [int(x) for x in text.split(",") if x]


def _floats(text):
    return [float(x) for x in text.split(",") if x]


class Bench:
    def __init__(self, args):
        self.args = args
        self.work = Path(args.work) / args.mesh
        self.work.mkdir(parents=True, exist_ok=True)
        self.scene = load_scene(str(MESHES[args.mesh]))
        n = args.points or len(self.scene.vertices)
        self.points, self.normals, self.sizes = query_points(self.scene, n)
        self.occluders = build(self.scene, BakeConfig())
        self.rows, self.correlation = [], {}
        self.truth, self.truth_se = self._truth()
        self._traced = {}

    def _truth(self):
        path = self.work / f"truth_{len(self.points)}_{self.args.truth_rays}.npz"
        if path.is_file():
            with np.load(path) as data:
                return data["ao"], data["ao_stderr"]
        clock = time.perf_counter()
        result = aobake.bake_points(self.scene, self.points, self.normals,
                                    point_sizes=self.sizes, threads=self.args.threads,
                                    rays=self.args.truth_rays, seed=1001)
        print(f"truth: {self.args.truth_rays} rays, {time.perf_counter() - clock:.1f} s, rms "
              f"stderr {np.sqrt(np.mean(result.ao_stderr ** 2)):.4f}", flush=True)
        np.savez(path, ao=result.ao, ao_stderr=result.ao_stderr)
        return result.ao, result.ao_stderr

    def score(self, values) -> dict:
        m = metrics(self.truth, values, self.truth_se)
        return {"rmse": m["rmse"], "bias": m["bias"], "max_error": m["max_error"],
                "excess_rmse": m["rmse_without_reference_noise"]}

    def depthmaps(self, k, n, b, seed=0):
        """(values (points,), seconds) of the GL method on all the points."""
        clock = time.perf_counter()
        method = DepthmapsMethod.prepare(self.scene, BakeConfig(seed=seed), self.occluders, 0,
                                         options=DepthmapsOptions(k, n, b))
        est = method.estimate(SamplePoints(self.points, self.normals,
                                           np.arange(len(self.points), dtype=np.int64),
                                           sizes=self.sizes), self.args.threads, 0)
        return est.fields["ao"], time.perf_counter() - clock

    def traced(self, k, seed=0):
        """(values, seconds): the same K directions with exact visibility (Embree)."""
        key = (k, seed)
        if key not in self._traced:
            clock = time.perf_counter()
            values = traced(self.occluders, self.points, self.normals, directions(k, seed),
                            sizes=self.sizes)
            self._traced[key] = values, time.perf_counter() - clock
        return self._traced[key]

    def row(self, part, k, n, b, seed, values, seconds, note=""):
        exact_k, _ = self.traced(k, seed)
        maps = values - exact_k
        r = {"part": part, "family": "depthmaps", "k": k, "n": n, "b": b, "seed": seed,
             "seconds": seconds, **self.score(values),
             "maps_rmse": float(np.sqrt(np.mean(maps ** 2))), "maps_bias": float(maps.mean()),
             "directions_excess_rmse": self.score(exact_k)["excess_rmse"], "note": note}
        self.rows.append(r)
        print(f"{part}: K {k} N {n} b {b:g} seed {seed}: {seconds:.1f} s, rmse {r['rmse']:.4f} "
              f"(excess {r['excess_rmse']:.4f}), bias {r['bias']:+.4f}; directions alone "
              f"{r['directions_excess_rmse']:.4f}; maps alone {r['maps_rmse']:.4f} "
              f"({r['maps_bias']:+.4f})", flush=True)
        return r

    def run_rays(self):
        for rays in _ints(self.args.rays):
            clock = time.perf_counter()
            result = aobake.bake_points(self.scene, self.points, self.normals,
                                        point_sizes=self.sizes, threads=self.args.threads,
                                        rays=rays, seed=1)
            seconds = time.perf_counter() - clock
            self.rows.append({"part": "rays", "family": "rays", "rays": rays,
                              "seconds": seconds, **self.score(result.ao)})
            print(f"rays {rays}: {seconds:.2f} s, excess rmse "
                  f"{self.rows[-1]['excess_rmse']:.4f}", flush=True)

    def run_k(self):
        for k in _ints(self.args.directions):
            values, seconds = self.depthmaps(k, DEFAULT_RESOLUTION, DEFAULT_BIAS)
            self.row("k", k, DEFAULT_RESOLUTION, DEFAULT_BIAS, 0, values, seconds)
        for k in _ints(self.args.traced_directions):  # the directions alone, further out
            values, seconds = self.traced(k)
            self.rows.append({"part": "traced", "family": "traced", "k": k, "seed": 0,
                              "seconds": seconds, **self.score(values)})
            print(f"traced K {k}: {seconds:.1f} s, excess "
                  f"{self.rows[-1]['excess_rmse']:.4f}", flush=True)

    def run_n(self):
        for n in _ints(self.args.resolutions):
            values, seconds = self.depthmaps(DEFAULT_DIRECTIONS, n, DEFAULT_BIAS)
            self.row("n", DEFAULT_DIRECTIONS, n, DEFAULT_BIAS, 0, values, seconds)

    def run_b(self):
        for b in _floats(self.args.biases):
            values, seconds = self.depthmaps(DEFAULT_DIRECTIONS, DEFAULT_RESOLUTION, b)
            self.row("b", DEFAULT_DIRECTIONS, DEFAULT_RESOLUTION, b, 0, values, seconds)

    def run_seeds(self):
        """The mean error over the points per seed: its spread against independent errors',
        for depthmaps (K = 64, 256) and rays (64, 256 rays); and the correlogram."""
        n_points = len(self.points)
        cases = [("depthmaps", k) for k in (64, DEFAULT_DIRECTIONS)] + \
                [("rays", r) for r in (64, 256)]
        errors_of = {}
        for family, count in cases:
            means, squares, errors = [], [], None
            for seed in range(self.args.seeds):
                if family == "depthmaps":
                    values, seconds = self.depthmaps(count, DEFAULT_RESOLUTION, DEFAULT_BIAS,
                                                     seed)
                    if count == DEFAULT_DIRECTIONS and seed == 0:
                        self.row("seed", count, DEFAULT_RESOLUTION, DEFAULT_BIAS, seed,
                                 values, seconds)
                else:
                    values = aobake.bake_points(
                        self.scene, self.points, self.normals, point_sizes=self.sizes,
                        threads=self.args.threads, rays=count, seed=100 + seed).ao
                error = values - self.truth
                means.append(float(error.mean()))
                squares.append(float(np.mean(error ** 2)))
                if errors is None:
                    errors = error
            spread = float(np.std(means, ddof=1))
            independent = float(np.sqrt(np.mean(squares) / n_points))
            key = f"{family} {count}"
            self.correlation[key] = {"seed_means": means, "spread_of_mean": spread,
                                     "independent_prediction": independent,
                                     "ratio": spread / independent,
                                     "rms": float(np.sqrt(np.mean(squares)))}
            errors_of[key] = errors
            print(f"{key}: mean error over seeds {np.mean(means):+.5f} +- {spread:.5f} "
                  f"(independent errors: {independent:.5f}; ratio {spread / independent:.1f})",
                  flush=True)
        self.correlation["correlogram"] = self.correlogram(errors_of)

    def correlogram(self, errors_of) -> dict:
        """Correlation of two points' errors (their product's mean over the error variance,
        the errors taken about their mean) in distance bins (units of the diagonal)."""
        from scipy.spatial import cKDTree

        diagonal = self.scene.diagonal
        tree = cKDTree(self.points)
        rng = np.random.default_rng(3)
        out = {"bins": list(BINS)}
        pairs = {}
        for lo, hi in zip(BINS[:-1], BINS[1:]):
            found = tree.query_pairs(hi * diagonal, output_type="ndarray") if hi <= 0.02 \
                else None
            if found is None:  # far bins: sample pairs at random, keep those in the bin
                i = rng.integers(0, len(self.points), 40 * PAIRS)
                j = rng.integers(0, len(self.points), 40 * PAIRS)
                found = np.stack([i, j], axis=1)
            d = np.linalg.norm(self.points[found[:, 0]] - self.points[found[:, 1]], axis=1)
            keep = found[(d >= lo * diagonal) & (d < hi * diagonal) & (found[:, 0] != found[:, 1])]
            if len(keep) > PAIRS:
                keep = keep[rng.choice(len(keep), PAIRS, replace=False)]
            pairs[(lo, hi)] = keep
        for key, error in errors_of.items():
            e = error - error.mean()
            var = float(np.mean(e ** 2))
            out[key] = [float(np.mean(e[p[:, 0]] * e[p[:, 1]]) / var) if len(p) else None
                        for p in pairs.values()]
        out["pairs"] = [int(len(p)) for p in pairs.values()]
        print("correlogram (bins of the diagonal " + ", ".join(f"{b:g}" for b in BINS) + "):",
              flush=True)
        for key in errors_of:
            print(f"  {key}: " + ", ".join("-" if c is None else f"{c:+.2f}" for c in out[key]))
        return out


def views(args, path):
    """Truth (1024 rays), rays and depthmaps at about the same rms, and their error maps."""
    from PIL import Image, ImageDraw

    mesh = str(MESHES[args.mesh])
    size = (320, 320)
    common = dict(size=size, threads=args.threads)
    clock = time.perf_counter()
    truth = aobake.bake_view(mesh, rays=1024, seed=11, **common)
    print(f"view truth: {time.perf_counter() - clock:.1f} s", flush=True)
    covered = truth.covered
    candidates = {"rays (32)": dict(rays=32, seed=12),
                  "depthmaps K 64": dict(method="depthmaps", depthmaps_directions=64),
                  "depthmaps K 256": dict(method="depthmaps", depthmaps_directions=256)}
    images = {}
    for label, options in candidates.items():
        clock = time.perf_counter()
        images[label] = aobake.bake_view(mesh, **common, **options).channels["ao"]
        error = images[label][covered] - truth.channels["ao"][covered]
        print(f"view {label}: {time.perf_counter() - clock:.1f} s, rms error "
              f"{np.sqrt(np.mean(error ** 2)):.4f}", flush=True)
    scale = 0.1

    def grey(values):
        v = (np.clip(np.where(covered, values, 0.0), 0, 1) * 255).round().astype(np.uint8)
        rgb = np.stack([v] * 3, axis=-1)
        rgb[~covered] = (40, 40, 60)
        return Image.fromarray(rgb)

    def diverging(values):
        e = np.clip(np.where(covered, values - truth.channels["ao"], 0.0) / scale, -1, 1)
        rgb = (np.stack([np.where(e > 0, 1.0, 1.0 + e), 1.0 - np.abs(e),
                         np.where(e < 0, 1.0, 1.0 - e)], axis=-1) * 255).round()
        rgb = rgb.astype(np.uint8)
        rgb[~covered] = (40, 40, 60)
        return Image.fromarray(rgb)

    rows = [[("truth (1024 rays)", grey(truth.channels["ao"]))]
            + [(label, grey(values)) for label, values in images.items()],
            [("", None)] + [(f"{label} - truth", diverging(values))
                            for label, values in images.items()]]
    w, h = size
    label_h = 16
    sheet = Image.new("RGB", (4 * w, 2 * (h + label_h) + 20), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for i, row in enumerate(rows):
        for j, (label, image) in enumerate(row):
            x, y = j * w, i * (h + label_h)
            if image is not None:
                sheet.paste(image, (x, y + label_h))
            draw.text((x + 4, y + 2), label, fill=(0, 0, 0))
    draw.text((4, 2 * (h + label_h) + 4), f"error maps: blue = darker than the truth, red = "
              f"lighter, full colour at +-{scale:g}", fill=(0, 0, 0))
    sheet.save(path)
    print(f"wrote {path}")


def plot(data, path):
    """Six panels: error against time (rays, depthmaps per K); the error sources against K, N
    and b; the seeds' mean errors; the correlogram."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows, corr = data["rows"], data.get("correlation", {})
    fig, axes = plt.subplots(2, 3, figsize=(15, 8.5))
    ax = axes[0][0]
    rays = [r for r in rows if r["part"] == "rays"]
    ax.plot([r["seconds"] for r in rays], [r["excess_rmse"] for r in rays], "o-",
            color="tab:blue", label="rays")
    for r in rays:
        ax.annotate(str(r["rays"]), (r["seconds"], r["excess_rmse"]), fontsize=7,
                    xytext=(3, 3), textcoords="offset points", color="tab:blue")
    pts = [r for r in rows if r["part"] == "k"]
    ax.plot([r["seconds"] for r in pts], [r["excess_rmse"] for r in pts], "D-",
            color="tab:purple", label="depthmaps, K (N 1024, b 1)")
    for r in pts:
        ax.annotate(f"K {r['k']}", (r["seconds"], r["excess_rmse"]), fontsize=7,
                    xytext=(3, -9), textcoords="offset points", color="tab:purple")
    ax.set(xscale="log", yscale="log", xlabel="seconds for all the points (2 shared cores)",
           ylabel="RMSE against the truth (its noise removed)", title="error against time")
    ax.legend(fontsize=8)
    ax = axes[0][1]
    pts = [r for r in rows if r["part"] == "k"]
    ks = [r["k"] for r in pts]
    ax.plot(ks, [r["excess_rmse"] for r in pts], "D-", color="tab:purple", label="depthmaps")
    tr = sorted([(r["k"], r["excess_rmse"]) for r in rows if r["part"] == "traced"]
                + [(r["k"], r["directions_excess_rmse"]) for r in pts])
    ax.plot([t[0] for t in tr], [t[1] for t in tr], "o--", color="tab:green",
            label="directions alone (exact visibility)")
    ax.plot(ks, [r["maps_rmse"] for r in pts], "s:", color="tab:red",
            label="maps alone (depthmaps - exact, N 1024)")
    ref = tr[0][1] * (np.array([t[0] for t in tr]) / tr[0][0]) ** -0.75
    ax.plot([t[0] for t in tr], ref, color="grey", lw=0.8, label="K^-3/4")
    ax.set(xscale="log", yscale="log", xlabel="K directions", ylabel="RMSE",
           title="the directions' error")
    ax.legend(fontsize=8)
    ax = axes[0][2]
    pts = [r for r in rows if r["part"] == "n"]
    ax.plot([r["n"] for r in pts], [r["excess_rmse"] for r in pts], "v-", color="tab:purple",
            label="depthmaps (K 256)")
    ax.plot([r["n"] for r in pts], [r["maps_rmse"] for r in pts], "s:", color="tab:red",
            label="maps alone")
    ax.plot([r["n"] for r in pts], [abs(r["maps_bias"]) for r in pts], "x:", color="k",
            label="|maps' mean error|")
    ax.set(xscale="log", yscale="log", xlabel="N texels across", ylabel="RMSE",
           title="the maps' resolution (b = 1)")
    ax.set_xticks([r["n"] for r in pts], [str(r["n"]) for r in pts])
    ax.minorticks_off()
    ax.legend(fontsize=8)
    ax = axes[1][0]
    pts = [r for r in rows if r["part"] == "b"]
    ax.plot([r["b"] for r in pts], [r["excess_rmse"] for r in pts], "o-", color="tab:purple",
            label="depthmaps RMSE (K 256, N 1024)")
    ax.plot([r["b"] for r in pts], [r["maps_rmse"] for r in pts], "s:", color="tab:red",
            label="maps alone RMSE")
    ax.plot([r["b"] for r in pts], [r["maps_bias"] for r in pts], "x-", color="k",
            label="maps' mean error (+ = too light)")
    ax.axvline(1 / np.sqrt(2), color="grey", lw=0.8)
    ax.axhline(0, color="grey", lw=0.5)
    ax.set(xscale="log", xlabel="bias b (texels)", ylabel="error",
           title="the bias: acne below 0.71, light leaks above", ylim=(-0.012, 0.012))
    ax.set_xticks([r["b"] for r in pts], [f"{r['b']:g}" for r in pts])
    ax.minorticks_off()
    for r in pts:  # off the axis: say so
        if abs(r["maps_bias"]) > 0.012:
            ax.annotate(f"b {r['b']:g}: RMSE {r['excess_rmse']:.3f}, mean {r['maps_bias']:+.3f}",
                        (r["b"], -0.0115), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
    ax.legend(fontsize=8, loc="upper right")
    ax = axes[1][1]
    keys = [k for k in corr if k != "correlogram"]
    for i, key in enumerate(keys):
        c = corr[key]
        ax.plot(np.full(len(c["seed_means"]), i), c["seed_means"], "o", alpha=0.7,
                color="tab:purple" if key.startswith("depthmaps") else "tab:blue")
        ax.errorbar(i + 0.25, 0, yerr=2 * c["independent_prediction"], color="k", capsize=3)
    ax.axhline(0, color="grey", lw=0.5)
    ax.set_xticks(range(len(keys)))
    ax.set_xticklabels([f"{k}\n(rms {corr[k]['rms']:.3f})" for k in keys], fontsize=8)
    ax.set(ylabel="mean error over all the points, per seed",
           title="mean error per seed; bars: +-2 x rms/sqrt(n)")
    ax = axes[1][2]
    if "correlogram" in corr:
        g = corr["correlogram"]
        mids = [(a + b) / 2 for a, b in zip(g["bins"][:-1], g["bins"][1:])]
        for key in keys:
            ax.plot(mids, g[key], "o-", label=key)
        ax.axhline(0, color="grey", lw=0.5)
        ax.set(xscale="log", xlabel="distance between two points (x diagonal)",
               ylabel="correlation of their errors", title="shared error against distance")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    print(f"wrote {path}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mesh", default="bunny", choices=sorted(MESHES))
    parser.add_argument("--points", type=int, default=0)
    parser.add_argument("--truth-rays", type=int, default=2048)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--directions", default="16,64,256,1024")
    parser.add_argument("--traced-directions", default="4096")
    parser.add_argument("--resolutions", default="256,512,1024,2048")
    parser.add_argument("--biases", default="0.25,0.5,0.71,1,2,4")
    parser.add_argument("--rays", default="16,32,64,128,256,512,1024")
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--parts", default="rays,k,n,b,seeds")
    parser.add_argument("--work", default="/tmp/aobake_depthmaps")
    parser.add_argument("--json")
    parser.add_argument("--plot")
    parser.add_argument("--views")
    parser.add_argument("--replot", metavar="JSON", help="no bake: --plot from a saved run")
    args = parser.parse_args(argv)
    if args.replot:
        plot(json.loads(Path(args.replot).read_text()), args.plot)
        return
    load = os.getloadavg()
    print(f"load average at start: {load[0]:.2f} ({os.cpu_count()} cores)", flush=True)
    parts = args.parts.split(",")
    data = {"args": vars(args), "rows": [], "correlation": {}}
    if set(parts) - {"views"}:
        bench = Bench(args)
        print(f"{args.mesh}: {len(bench.points)} points, {len(bench.scene.faces)} triangles",
              flush=True)
        for part, run in (("rays", bench.run_rays), ("k", bench.run_k), ("n", bench.run_n),
                          ("b", bench.run_b), ("seeds", bench.run_seeds)):
            if part in parts:
                run()
                data["rows"], data["correlation"] = bench.rows, bench.correlation
                if args.json:  # after each part: a long run keeps what it measured
                    Path(args.json).write_text(json.dumps(data, indent=1))
    load = os.getloadavg()
    print(f"load average at end: {load[0]:.2f}", flush=True)
    if args.plot:
        plot(data, args.plot)
    if args.views:
        views(args, args.views)


if __name__ == "__main__":
    main()
