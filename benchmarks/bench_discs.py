"""``--method discs`` measured, both models (``--discs-model chapter`` and ``robust``): the
cost against the element count (hierarchy and brute force, with the log-log slope), the
error against ray-traced AO on the Stanford bunny for kappa in {1, 2, 4, 8} and brute
force, pass by pass, and the two models side by side on the bundled still life (an open
floor with objects on it) and the bunny, per object on the still life.

    python benchmarks/bench_discs.py [--quick] [--max-n 1048576] [--max-brute-n 32768]
                                     [--threads 1] [--truth-rays 1024] [--repeat 2]
                                     [--sections scaling,bunny,models] [--json PATH]
                                     [--plot PATH]

Scaling: tori of n = m^2 vertices, n doubling from 4096 (a numpy grid, so building the
mesh costs nothing here); each row is one whole per-vertex bake with the default two
passes: prepare (the tree, the elements' pass 1; the robust model also finds which
elements lie on closed surfaces, a torus: all) and the estimate at every element.  The
slope is the least-squares slope of log(seconds) on log(n) over the rows with n >= 16384
(below that, fixed costs dominate): 1 for O(n), about 1.1 for O(n log n) over this
range, 2 for O(n^2).

Accuracy: every vertex of ``../shared/meshes/stanford-bunny.obj`` (and of
``assets/still_life.obj``) against a ray-traced bake (``aobake.bake``, ``--truth-rays``
cosine-weighted rays, seed 1, cached in /tmp); the bunny also against the uniform-weighted
one (the chapter's on-axis factor is a solid angle; the robust model computes the cosine
measure only).  The truth's own noise (its mean stderr^2) is subtracted from the mean
squared error; the printed ``truth noise`` says how much that was.  Seconds are prepare +
estimate, on ``--threads`` threads, the least of ``--repeat`` runs.  Numbers from a
shared, loaded machine are slower than a quiet one.

``--sections approximations`` runs bench_approximations.py's ``discs`` part (its points,
its 2048-ray truth, on at least two threads as it runs) once per model: the discs rows of
docs/approximations.md, both models under the same load.
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
from aobake.methods.discs import DiscsMethod, DiscsOptions  # noqa: E402
from aobake.scene import load_scene  # noqa: E402
from aobake.records import SamplePoints  # noqa: E402
from aobake.targets.vertices import VertexTarget  # noqa: E402
from aobake.vectors import defined  # noqa: E402

SHARED = ROOT.parent / "shared" / "meshes"
BUNNY = SHARED / "stanford-bunny.obj"
STILL_LIFE = ROOT / "assets" / "still_life.obj"
KAPPAS = (1.0, 2.0, 4.0, 8.0)
MODELS = ("chapter", "robust")


class Grid:
    """A torus of m x m vertices (major radius 1, minor 0.4) with what ``DiscsMethod.prepare``
    reads of a scene: vertices, faces, face_normals, areas(), diagonal, source."""

    source = "<torus grid>"

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
        self.diagonal = float(np.linalg.norm(self.vertices.max(0) - self.vertices.min(0)))

    def areas(self):
        return self._areas


def whole_bake(grid: Grid, options: DiscsOptions, threads: int) -> tuple:
    """(seconds, prepare seconds, mean terms per point) of a per-vertex bake of the discs."""
    clock = time.perf_counter()
    method = _prepare(grid, options, threads)
    prepared = time.perf_counter() - clock
    position = method.position / method.scale + method.center
    points = SamplePoints(position, method.normal, np.arange(len(position), dtype=np.int64))
    got = method.estimate(points, threads, 131072)
    return time.perf_counter() - clock, prepared, float(got.extras["discs_terms"].mean())


def _prepare(scene, options: DiscsOptions, threads: int) -> DiscsMethod:
    """``DiscsMethod.prepare`` on ``threads`` threads (prepare itself uses the default)."""
    from aobake.methods import discs

    default = discs._default_threads
    discs._default_threads = lambda: threads
    try:
        return DiscsMethod.prepare(scene, BakeConfig(), None, 0, options=options)
    finally:
        discs._default_threads = default


def slope(rows: list) -> float | None:
    big = [(n, s) for n, s in rows if n >= 16384]
    if len(big) < 2:
        return None
    x, y = np.log([n for n, _ in big]), np.log([s for _, s in big])
    return float(np.polyfit(x, y, 1)[0])


def scaling(max_n: int, max_brute_n: int, threads: int) -> dict:
    print("\n## Time against n (a whole two-pass per-vertex bake)\n")
    print("| n | chapter s | (prepare s) | terms/point | us/point | robust s | (prepare s) | "
          "terms/point | us/point | robust / chapter | chapter brute s | robust brute s |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    out = {f"{model}_{kind}": [] for model in MODELS for kind in ("hierarchy", "brute")}
    for m in (64, 90, 128, 181, 256, 362, 512, 724, 1024):  # n doubles: m grows by sqrt(2)
        if m * m > max_n:
            break
        grid = Grid(m)
        n = m * m
        cells, times = [], {}
        for model in MODELS:
            seconds, prepared, terms = whole_bake(grid, DiscsOptions(discs_model=model), threads)
            out[f"{model}_hierarchy"].append((n, seconds))
            times[model] = seconds
            cells.append(f"{seconds:.2f} | {prepared:.2f} | {terms:.0f} | "
                         f"{seconds / n * 1e6:.1f}")
        cells.append(f"{times['robust'] / times['chapter']:.1f}")
        for model in MODELS:
            if n <= max_brute_n:
                b, _, _ = whole_bake(grid, DiscsOptions(discs_model=model,
                                                        discs_traversal="brute"), threads)
                out[f"{model}_brute"].append((n, b))
                cells.append(f"{b:.2f}")
            else:
                cells.append("")
        print(f"| {n} | " + " | ".join(cells) + " |", flush=True)
    for key in list(out):
        out["slope_" + key] = slope(out[key])
    fmt = (lambda s: "n/a (too few rows >= 16384)" if s is None else f"{s:.2f}")
    print("\nlog-log slope (n >= 16384): " + ", ".join(
        f"{key} {fmt(out['slope_' + key])}" for key in
        ("chapter_hierarchy", "robust_hierarchy", "chapter_brute", "robust_brute")))
    return out


def truth(mesh: Path, rays: int, weighting: str, threads: int) -> dict:
    cache = Path(f"/tmp/aobake_discs_truth_{mesh.stem}_{weighting}_{rays}.npz")
    if cache.exists():
        data = np.load(cache)
        return {"ao": data["ao"], "stderr": data["stderr"], "seconds": float(data["seconds"])}
    clock = time.perf_counter()
    result = aobake.bake(mesh, rays=rays, seed=1, weighting=weighting, threads=threads)
    seconds = time.perf_counter() - clock
    np.savez(cache, ao=result.ao, stderr=result.ao_stderr, seconds=seconds)
    return {"ao": result.ao, "stderr": result.ao_stderr, "seconds": seconds}


def _timed(scene, plan, options: DiscsOptions, threads: int, repeat: int):
    """(estimates, least seconds of ``repeat`` runs of prepare + estimate)."""
    best = math.inf
    for _ in range(max(1, repeat)):
        clock = time.perf_counter()
        method = _prepare(scene, options, threads)
        got = method.estimate(plan, threads, 131072)
        best = min(best, time.perf_counter() - clock)
    return got, best


def _errors(values, ref, noise) -> dict:
    e = values - ref
    return {"rmse": math.sqrt(max(float(np.mean(e * e)) - noise, 0.0)),
            "raw_rmse": math.sqrt(float(np.mean(e * e))), "bias": float(np.mean(e)),
            "max": float(np.abs(e).max())}


def accuracy(truth_rays: int, threads: int, kappas=KAPPAS, brute: bool = True,
             repeat: int = 1) -> dict:
    scene = load_scene(BUNNY)
    plan = VertexTarget().sample(scene, BakeConfig(), None, threads, {}, [])
    truths = {w: truth(BUNNY, truth_rays, w, threads) for w in ("cosine", "uniform")}
    sampled = defined(scene.vertex_normals)  # the others hold no-information values
    print(f"\n## Error against ray-traced AO: {BUNNY.name}, {int(sampled.sum())} vertices\n")
    for w, t in truths.items():
        noise = float(np.mean(t["stderr"][sampled] ** 2))
        print(f"truth ({w}): {truth_rays} rays, {t['seconds']:.1f} s, truth noise "
              f"(rms stderr) {math.sqrt(noise):.4f}")
    print("\n| model | setting | s | terms/point | RMSE cos (pass 1, 2, result) | "
          "bias cos (result) | max cos | RMSE uniform (result) | bias uniform |")
    print("|---|---|---:|---:|---|---:|---:|---:|---:|")
    settings = []
    for model in MODELS:
        settings += [(model, f"kappa {k:g}", DiscsOptions(discs_model=model, discs_kappa=k))
                     for k in kappas]
        if model == "chapter":
            settings.append((model, "kappa 4, k 3 (the CD's)",
                             DiscsOptions(discs_model=model, discs_k=3.0)))
        if brute:  # O(n^2): about a minute per pass on the bunny (the robust model: more)
            settings.append((model, "brute force",
                             DiscsOptions(discs_model=model, discs_traversal="brute")))
    out = {}
    for model, label, options in settings:
        got, seconds = _timed(scene, plan, options, threads, repeat)
        ao = got.fields["ao"][plan.state][sampled]
        passes = got.extras["discs_passes"][plan.state][sampled]
        row = {"seconds": seconds, "terms": float(got.extras["discs_terms"].mean())}
        for w, t in truths.items():
            if model == "robust" and w == "uniform":
                continue  # it computes the cosine measure
            ref, noise = t["ao"][sampled], float(np.mean(t["stderr"][sampled] ** 2))
            row[w] = _errors(ao, ref, noise)
            row[w]["rmse_passes"] = [_errors(passes[:, j], ref, noise)["rmse"]
                                     for j in range(passes.shape[1])]
        cos, uni = row["cosine"], row.get("uniform")
        uniform = (f"{uni['rmse']:.4f} | {uni['bias']:+.4f}" if uni else "- | -")
        print(f"| {model} | {label} | {seconds:.2f} | {row['terms']:.0f} | "
              f"{', '.join(f'{r:.4f}' for r in cos['rmse_passes'])}, {cos['rmse']:.4f} | "
              f"{cos['bias']:+.4f} | {cos['max']:.3f} | {uniform} |", flush=True)
        out[f"{model} {label}"] = row
    return out


def models(truth_rays: int, threads: int, repeat: int, meshes=(STILL_LIFE, BUNNY)) -> dict:
    """The two models at their defaults on each mesh: error against the ray-traced truth
    (cosine), time, and on a mesh whose OBJ names objects, the error per object."""
    print("\n## The two models against the ray-traced truth, per vertex\n")
    out = {}
    for mesh in meshes:
        if not mesh.exists():
            print(f"({mesh} is missing: skipped)")
            continue
        scene = load_scene(mesh)
        plan = VertexTarget().sample(scene, BakeConfig(), None, threads, {}, [])
        t = truth(mesh, truth_rays, "cosine", threads)
        sampled = defined(scene.vertex_normals)
        ref = t["ao"][sampled]
        noise = float(np.mean(t["stderr"][sampled] ** 2))
        print(f"{mesh.name}: {int(sampled.sum())} vertices, truth {truth_rays} rays "
              f"({t['seconds']:.1f} s on {threads} threads), mean {ref.mean():.3f}, rms "
              f"stderr {math.sqrt(noise):.4f}\n")
        print("| model | s | terms/point | RMSE | bias | max | RMSE pass 1, pass 2 |")
        print("|---|---:|---:|---:|---:|---:|---|")
        per_model, values = {}, {}
        for model in MODELS:
            got, seconds = _timed(scene, plan, DiscsOptions(discs_model=model), threads,
                                  repeat)
            ao = got.fields["ao"][plan.state]
            passes = got.extras["discs_passes"][plan.state][sampled]
            row = _errors(ao[sampled], ref, noise)
            row.update(seconds=seconds, terms=float(got.extras["discs_terms"].mean()),
                       rmse_passes=[_errors(passes[:, j], ref, noise)["rmse"]
                                    for j in range(passes.shape[1])])
            per_model[model], values[model] = row, ao
            print(f"| {model} | {seconds:.2f} | {row['terms']:.0f} | {row['rmse']:.4f} | "
                  f"{row['bias']:+.4f} | {row['max']:.3f} | "
                  f"{', '.join(f'{r:.4f}' for r in row['rmse_passes'])} |", flush=True)
        names = (scene.names or {}).get("object")
        if names is not None:
            print("\n| object | vertices | truth mean | " + " | ".join(
                f"{m} mean, RMSE, bias" for m in MODELS) + " |")
            print("|---|---:|---:|" + "---|" * len(MODELS))
            labels, face_object = names
            vertex_object = np.full(len(scene.vertices), -1)
            vertex_object[np.asarray(scene.faces).ravel()] = np.repeat(face_object, 3)
            per_model["objects"] = {}
            for k, name in enumerate(labels):
                here = (vertex_object == k) & sampled
                if not here.any():
                    continue
                cells = []
                for model in MODELS:
                    e = values[model][here] - t["ao"][here]
                    cells.append(f"{values[model][here].mean():.3f}, "
                                 f"{math.sqrt(float(np.mean(e * e))):.3f}, {e.mean():+.3f}")
                print(f"| {name} | {int(here.sum())} | {t['ao'][here].mean():.3f} | "
                      + " | ".join(cells) + " |")
                per_model["objects"][name] = cells
        out[mesh.stem] = per_model
        print()
    return out


def approximations(meshes: str, threads: int, work: Path, extra=()) -> dict:
    """bench_approximations.py's ``discs`` part (its points, its 2048-ray truth, its
    kappas and passes, scored by ``aobake compare``) once per model, the rows' family
    named ``discs chapter`` / ``discs robust``: the discs rows of docs/approximations.md."""
    from functools import partial

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_approximations as approx

    out = {}
    brute_elements = approx.BRUTE_ELEMENTS
    for model in MODELS:
        approx.DiscsOptions = partial(DiscsOptions, discs_model=model)
        # the robust model's brute force walks every node of the tree: an oracle for the
        # tests, minutes here; its rows are left out
        approx.BRUTE_ELEMENTS = brute_elements if model == "chapter" else 0
        path = work / f"approximations_{model}.json"
        print(f"\n## {model}: bench_approximations --parts discs --meshes {meshes}\n",
              flush=True)
        approx.main(["--parts", "discs", "--meshes", meshes, "--threads", str(threads),
                     "--work", str(work / "approx"), "--json", str(path), *extra])
        rows = json.loads(path.read_text())["rows"]
        for row in rows:
            row["family"] = f"discs {model}"
        out[model] = rows
    print("\n## Both models, as docs/approximations.md prints them\n")
    rows = out["chapter"] + out["robust"]
    for mesh in dict.fromkeys(r["mesh"] for r in rows):
        for quantity in ("ao", "indirect"):
            mine = [r for r in rows if r["mesh"] == mesh and r["quantity"] == quantity]
            print(f"\n{mesh}, {quantity}\n\n{approx.table(mine, compact=True)}", flush=True)
    return out


def plot(path: Path, rows: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4))
    for key, marker in (("chapter_hierarchy", "o"), ("robust_hierarchy", "^"),
                        ("chapter_brute", "s"), ("robust_brute", "D")):
        if rows[key]:
            n, s = zip(*rows[key])
            slope_ = rows["slope_" + key]
            label = key.replace("_", ", ")
            ax.loglog(n, s, marker=marker,
                      label=f"{label} (slope {slope_:.2f})" if slope_ else label)
    ax.set_xlabel("elements n (= receivers)")
    ax.set_ylabel("seconds, whole two-pass bake")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="n up to 65536 (brute force 16384), truth 512 rays, no brute "
                        "force on the bunny")
    parser.add_argument("--max-n", type=int, default=1 << 20)
    parser.add_argument("--max-brute-n", type=int, default=1 << 15)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--truth-rays", type=int, default=1024)
    parser.add_argument("--repeat", type=int, default=1,
                        help="time each accuracy row as the least of this many runs")
    parser.add_argument("--sections", default="scaling,bunny,models",
                        help="which to run, comma-separated: scaling, bunny, models, "
                        "approximations (bench_approximations' discs part per model)")
    parser.add_argument("--meshes", default="still_life,bunny",
                        help="models: still_life, bunny, ogre; approximations: "
                        "bench_approximations' --meshes")
    parser.add_argument("--work", type=Path, default=Path("/tmp/aobake_discs_bench"),
                        help="approximations: where its candidates and runs go")
    parser.add_argument("--approximations-args", default="",
                        help="approximations: more arguments for bench_approximations "
                        "(a smoke run: '--points 300 --truth-rays 64')")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--plot", type=Path, help="write the log-log plot (needs matplotlib)")
    args = parser.parse_args(argv)
    sections = {s.strip() for s in args.sections.split(",") if s.strip()}
    known = {"scaling", "bunny", "models", "approximations"}
    if not sections <= known:
        parser.error(f"--sections: unknown {sorted(sections - known)}")
    if args.plot:
        if "scaling" not in sections:
            parser.error("--plot draws the scaling section: add it to --sections")
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            parser.error("--plot needs matplotlib (pip install matplotlib)")
    if args.quick:
        args.max_n, args.max_brute_n = min(args.max_n, 1 << 16), min(args.max_brute_n, 1 << 14)
        args.truth_rays = min(args.truth_rays, 512)
    results = {}
    if "scaling" in sections:
        results["scaling"] = scaling(args.max_n, args.max_brute_n, args.threads)
    if "bunny" in sections:
        results["accuracy"] = accuracy(args.truth_rays, args.threads, brute=not args.quick,
                                       repeat=args.repeat)
    if "models" in sections:
        meshes = {"still_life": STILL_LIFE, "bunny": BUNNY, "ogre": SHARED / "ogre.obj"}
        chosen = [m for m in args.meshes.split(",") if m]
        if not set(chosen) <= set(meshes):
            parser.error(f"--meshes: models knows {', '.join(meshes)}")
        results["models"] = models(args.truth_rays, args.threads, args.repeat,
                                   [meshes[m] for m in chosen])
    if "approximations" in sections:
        args.work.mkdir(parents=True, exist_ok=True)
        results["approximations"] = approximations(args.meshes, max(args.threads, 2),
                                                   args.work, args.approximations_args.split())
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    if args.plot:
        plot(args.plot, results["scaling"])


if __name__ == "__main__":
    main()
