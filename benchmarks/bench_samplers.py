"""Samplers: accuracy and honesty of the error bars, new samplers against the old default.

    python benchmarks/bench_samplers.py [--quick] [--threads 2] [--old /tmp/orig]
                                        [--cache /tmp/aobake_bench_samplers]

Prints markdown tables for the samplers ``random``, ``stratified`` and ``sobol`` (this
tree: every point randomised on its own, 8 replicates for the randomised-QMC ones) and
``old sobol (CP)``: the previous release's default (Cranley-Patterson-rotated Sobol with
the elevation shift shared by all points), imported from a checkout of that release
(``--old``, e.g. commit 703c6a8 with its kernel built in place) in a subprocess, since
both packages are called ``aobake``.

1. Closed-form scene: floor points under a tilted 48-gon (a tessellated disc), exact AO
   = 1 - Lambert's polygon form factor; pooled over points x seeds: RMSE, RMS(error) /
   RMS(stderr), coverage of the 95% interval (new: ``ao_ci_low <= exact <= ao_ci_high``;
   old: ``|ao - exact| <= 1.96 ao_stderr``, what its users had) and the fraction of zero
   stderr.
2. Bunny and ogre (../shared/meshes): per-vertex AO against a high-ray reference of
   another seed (``sobol``, this tree, cached as .npy under --cache), with the reference's
   own noise accounted for (see ``mesh_rows``).
3. The headline: new default vs old default at 256 rays on the bunny, and the most
   accurate sampler whose error bars are honest.

``--quick``: a smoke run (fewer points and seeds, 64 and 256 rays, bunny only against a
1024-ray reference).  Wall times are informative only (another process may be running).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import aobake  # noqa: E402
from analytic import polygon, polygon_form_factor  # noqa: E402

SHARED = ROOT.parent / "shared" / "meshes"
NEW = ("random", "stratified", "sobol")
OLD = "old sobol (CP)"
Z95 = 1.959963984540054
REF_SEED = 12345
#: |old release - reference| above which a vertex counts as a leak of the old ray offset
LEAK = 0.1

# Run inside the old checkout (cwd and PYTHONPATH = --old): bakes the jobs of a JSON spec
# with the old release's API and saves ao, ao_stderr and the wall time of every job.
OLD_HELPER = r"""
import json, sys, time
import numpy as np
import aobake
assert aobake.__file__.startswith(sys.argv[3]), aobake.__file__
spec = json.load(open(sys.argv[1]))
out = {}
if spec.get("scene"):
    import trimesh
    data = np.load(spec["scene"])
    mesh = trimesh.Trimesh(data["vertices"], data["faces"], process=False)
    points, normals = data["points"], data["normals"]
for i, (rays, seed) in enumerate(spec["jobs"]):
    start = time.perf_counter()
    if spec.get("scene"):
        res = aobake.bake_points(mesh, points, normals, rays=rays, sampler="sobol", seed=seed,
                                 threads=spec["threads"])
    else:
        res = aobake.bake(spec["mesh"], rays=rays, sampler="sobol", seed=seed,
                          threads=spec["threads"])
    out[f"wall_{i}"] = np.array(time.perf_counter() - start)
    out[f"ao_{i}"] = res.ao
    out[f"se_{i}"] = res.ao_stderr
np.savez(sys.argv[2], **out)
"""


def old_bakes(old: Path, jobs, threads: int, mesh: Path | None = None, scene: dict | None = None):
    """[(ao, stderr, wall)] of the old release's default sampler for jobs [(rays, seed)]."""
    with tempfile.TemporaryDirectory() as tmp:
        spec = {"jobs": [list(j) for j in jobs], "threads": threads}
        if scene is not None:
            np.savez(Path(tmp, "scene.npz"), **scene)
            spec["scene"] = str(Path(tmp, "scene.npz"))
        else:
            spec["mesh"] = str(mesh)
        Path(tmp, "spec.json").write_text(json.dumps(spec))
        env = {**os.environ, "PYTHONPATH": str(old)}
        subprocess.run([sys.executable, "-c", OLD_HELPER, str(Path(tmp, "spec.json")),
                        str(Path(tmp, "out.npz")), str(old)], cwd=old, env=env, check=True)
        data = np.load(Path(tmp, "out.npz"))
        return [(data[f"ao_{i}"], data[f"se_{i}"], float(data[f"wall_{i}"]))
                for i in range(len(jobs))]


def fmt(x, digits=5):
    return f"{x:.{digits}f}"


# --------------------------------------------------------------------------- closed form
def closed_form(args, ray_counts):
    """Table 1: floor points under a tilted 48-gon, exact AO per point."""
    import trimesh

    disc = polygon([0, 0, 0], 1.3, 48)
    # Tilted 30 degrees about x, centre at (0.3, 0, 1): every corner stays above the floor
    # (z in [0.35, 1.65]), so the form factor of the whole polygon is the exact occlusion.
    tilt = trimesh.transformations.rotation_matrix(np.radians(30.0), [1, 0, 0])
    tilt[:3, 3] = [0.3, 0.0, 1.0]
    disc.apply_transform(tilt)
    rng = np.random.default_rng(0)
    pts = np.zeros((args.points, 3))
    pts[:, :2] = rng.uniform(-2.5, 2.5, size=(args.points, 2))
    nrm = np.tile([0.0, 0.0, 1.0], (args.points, 1))
    corners = disc.vertices[1:]
    exact = np.array([1.0 - polygon_form_factor(p, [0, 0, 1], corners) for p in pts])
    seeds = list(range(args.seeds))

    results = {}  # (sampler, rays) -> dict of (seeds, points) arrays
    for sampler in NEW:
        for rays in ray_counts:
            ao, se, lo, hi = [], [], [], []
            for seed in seeds:
                r = aobake.bake_points(disc, pts, nrm, rays=rays, sampler=sampler, seed=seed,
                                       threads=args.threads)
                for out, value in zip((ao, se, lo, hi),
                                      (r.ao, r.ao_stderr, r.ao_ci_low, r.ao_ci_high)):
                    out.append(value)
            results[sampler, rays] = dict(ao=np.array(ao), se=np.array(se), lo=np.array(lo),
                                          hi=np.array(hi))
    jobs = [(rays, seed) for rays in ray_counts for seed in seeds]
    old = old_bakes(args.old, jobs, args.threads,
                    scene=dict(vertices=disc.vertices, faces=disc.faces, points=pts, normals=nrm))
    for rays in ray_counts:
        mine = [o for (r, _), o in zip(jobs, old) if r == rays]
        ao, se = np.array([o[0] for o in mine]), np.array([o[1] for o in mine])
        results[OLD, rays] = dict(ao=ao, se=se, lo=ao - Z95 * se, hi=ao + Z95 * se)

    print(f"### 1. Closed form: {args.points} floor points under a tilted 48-gon x "
          f"{args.seeds} seeds\n")
    print(f"Exact AO = 1 - Lambert's polygon form factor (mean {exact.mean():.3f}, range "
          f"{exact.min():.3f}-{exact.max():.3f}). Pooled over points x seeds; \"per-seed RMSE\" "
          "is the range of the RMSE of one bake over the seeds. Coverage: new samplers "
          "`ao_ci_low <= exact <= ao_ci_high`, old `|ao - exact| <= 1.96 ao_stderr`.\n")
    print("| sampler | rays | RMSE | per-seed RMSE | RMS(err)/RMS(stderr) | 95% coverage | "
          "zero stderr |")
    print("|---|---|---|---|---|---|---|")
    rows = {}
    for sampler in (*NEW, OLD):
        for rays in ray_counts:
            d = results[sampler, rays]
            err = d["ao"] - exact[None, :]
            rmse = float(np.sqrt(np.mean(err**2)))
            per_seed = np.sqrt(np.mean(err**2, axis=1))
            ratio = rmse / float(np.sqrt(np.mean(d["se"] ** 2)))
            cover = float(np.mean((d["lo"] <= exact) & (exact <= d["hi"])))
            zero = float(np.mean(d["se"] == 0))
            rows[sampler, rays] = dict(rmse=rmse, ratio=ratio, cover=cover, zero=zero)
            print(f"| {sampler} | {rays} | {fmt(rmse)} | {fmt(per_seed.min())}-"
                  f"{fmt(per_seed.max())} | {ratio:.2f} | {cover:.3f} | {zero:.3f} |")
    print()
    return rows


# --------------------------------------------------------------------------- meshes
def reference(path: Path, rays: int, args):
    """(ao, stderr, ci_low, ci_high, rays) of the reference bake, cached under --cache."""
    args.cache.mkdir(parents=True, exist_ok=True)
    stem = args.cache / f"{path.stem}_sobol_{rays}_seed{REF_SEED}"
    names = ("ao", "se", "lo", "hi", "rays")
    files = [Path(f"{stem}_{n}.npy") for n in names]
    if all(f.is_file() for f in files):
        return [np.load(f) for f in files], None
    start = time.perf_counter()
    r = aobake.bake(path, rays=rays, sampler="sobol", seed=REF_SEED, threads=args.threads)
    wall = time.perf_counter() - start
    arrays = [r.ao, r.ao_stderr, r.ao_ci_low, r.ao_ci_high, r.rays]
    for f, a in zip(files, arrays):
        np.save(f, a)
    return arrays, wall


def mesh_rows(path: Path, ref_rays: int, ray_counts, seeds, args):
    """Table 2 for one mesh: every sampler's per-vertex AO against the reference.

    With e = ao - ref over the vertices that have a normal (unreferenced vertices are
    baked as "no information"), MSE = mean(e^2) and ref_se the reference's stderr:
    * RMSE (ref. noise removed) = sqrt(max(0, MSE - mean(ref_se^2))): the reference's own
      error adds mean(ref_se^2) to the MSE in expectation (independent seeds);
    * RMS(err)/RMS(se) = RMSE / sqrt(mean(se^2 + ref_se^2));
    * coverage: new samplers, ref in the 95% interval with each half-width widened in
      quadrature by the reference's own 95% half-width h_ref = max(ref_hi - ref, ref - ref_lo):
      [ao - sqrt((ao - lo)^2 + h_ref^2), ao + sqrt((hi - ao)^2 + h_ref^2)]; old sampler:
      |ao - ref| <= 1.96 sqrt(se^2 + ref_se^2);
    * "w/o leaks": the same, over the vertices where the old release's mean over seeds at
      the highest ray count is within LEAK of the reference.  The old release offsets ray
      origins by 1e-5 of the bounding-box diagonal, this tree by a fraction of the point's
      own triangles; on a mesh with thin creases the old offset puts some origins past the
      occluder (AO wrong by 0.18-0.84 on the ogre, whatever the rays), an error that is not the sampler's.
    """
    (ref, ref_se, ref_lo, ref_hi, ref_n), ref_wall = reference(path, ref_rays, args)
    mask = ref_n > 0
    ref, ref_se, ref_lo, ref_hi = ref[mask], ref_se[mask], ref_lo[mask], ref_hi[mask]
    h_ref = np.maximum(ref_hi - ref, ref - ref_lo)
    ref_var = float(np.mean(ref_se**2))

    runs = {}  # (sampler, rays) -> list over seeds of (ao, se, lo, hi, wall)
    for sampler in NEW:
        for rays in ray_counts:
            for seed in seeds:
                start = time.perf_counter()
                r = aobake.bake(path, rays=rays, sampler=sampler, seed=seed, threads=args.threads)
                wall = time.perf_counter() - start
                runs.setdefault((sampler, rays), []).append(
                    (r.ao[mask], r.ao_stderr[mask], r.ao_ci_low[mask], r.ao_ci_high[mask], wall))
    jobs = [(rays, seed) for rays in ray_counts for seed in seeds]
    for (rays, _), (ao, se, wall) in zip(jobs, old_bakes(args.old, jobs, args.threads, mesh=path)):
        runs.setdefault((OLD, rays), []).append((ao[mask], se[mask], None, None, wall))

    # "Leaks": vertices where the old release at its highest ray count is off the reference
    # by more than LEAK (its larger ray offset, 1e-5 of the diagonal, lets rays out of thin
    # creases; far beyond sampling noise at that ray count).  The same vertex set is left
    # out for every sampler in "w/o leaks", which isolates the samplers.
    old_top = np.mean([run[0] for run in runs[OLD, ray_counts[-1]]], axis=0)
    keep = np.abs(old_top - ref) <= LEAK
    ref_var_keep = float(np.mean(ref_se[keep] ** 2))

    rows = {}
    for sampler in (*NEW, OLD):
        for rays in ray_counts:
            sq, per_seed, se2, covered, zero, walls = [], [], [], [], [], []
            for ao, se, lo, hi, wall in runs[sampler, rays]:
                e = ao - ref
                sq.append(e**2)
                per_seed.append(np.sqrt(max(0.0, float(np.mean(e**2)) - ref_var)))
                se2.append(se**2)
                if lo is None:
                    covered.append(np.abs(e) <= Z95 * np.sqrt(se**2 + ref_se**2))
                else:
                    low = ao - np.sqrt((ao - lo) ** 2 + h_ref**2)
                    high = ao + np.sqrt((hi - ao) ** 2 + h_ref**2)
                    covered.append((low <= ref) & (ref <= high))
                zero.append(se == 0)
                walls.append(wall)
            mse = float(np.mean(sq))
            mse_keep = float(np.mean(np.array(sq)[:, keep]))
            rows[sampler, rays] = dict(
                raw=np.sqrt(mse), rmse=np.sqrt(max(0.0, mse - ref_var)),
                rmse_keep=np.sqrt(max(0.0, mse_keep - ref_var_keep)),
                per_seed=(min(per_seed), max(per_seed)),
                ratio=np.sqrt(mse) / np.sqrt(float(np.mean(se2)) + ref_var),
                cover=float(np.mean(covered)), zero=float(np.mean(zero)),
                wall=float(np.mean(walls)))
    for sampler in (*NEW, OLD):
        for rays in ray_counts:
            d = rows[sampler, rays]
            d["vs_old"] = d["rmse"] / rows[OLD, rays]["rmse"]
            d["vs_old_keep"] = d["rmse_keep"] / rows[OLD, rays]["rmse_keep"]

    took = "" if ref_wall is None else f", baked in {ref_wall:.1f} s"
    print(f"### 2. {path.name}: {int(mask.sum()):,} vertices with a normal (of {len(mask):,}) "
          f"x {len(seeds)} seed(s)\n")
    print(f"Reference: `sobol`, {ref_rays} rays, seed {REF_SEED} (this tree; cached under "
          f"{args.cache}{took}); its RMS stderr is {np.sqrt(ref_var):.5f}. \"RMSE\" has the "
          "reference's noise removed, \"raw\" is against the reference as it is; \"vs old\" is "
          "RMSE / the old default's RMSE at the same rays; \"per-seed RMSE\" the range over "
          "the seeds of one bake's RMSE; \"w/o leaks\" leaves out the "
          f"{int((~keep).sum())} vertices where the old release at {ray_counts[-1]} rays is off "
          f"the reference by more than {LEAK} (its larger ray offset; see the docstring of "
          "`mesh_rows`).\n")
    print("| sampler | rays | RMSE | raw RMSE | per-seed RMSE | vs old | RMSE w/o leaks | "
          "vs old w/o leaks | RMS(err)/RMS(stderr) | 95% coverage | zero stderr | wall s/bake |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for sampler in (*NEW, OLD):
        for rays in ray_counts:
            d = rows[sampler, rays]
            print(f"| {sampler} | {rays} | {fmt(d['rmse'])} | {fmt(d['raw'])} | "
                  f"{fmt(d['per_seed'][0])}-{fmt(d['per_seed'][1])} | {d['vs_old']:.2f} | "
                  f"{fmt(d['rmse_keep'])} | {d['vs_old_keep']:.2f} | "
                  f"{d['ratio']:.2f} | {d['cover']:.3f} | {d['zero']:.3f} | {d['wall']:.2f} |")
    print()
    return rows


# --------------------------------------------------------------------------- headline
def headline(tables, meshes, ray_counts):
    """tables: the closed-form rows and every mesh's; meshes: [(name, rows)]."""
    print("### 3. Headline\n")
    for name, rows in meshes:
        if (OLD, 256) not in rows:
            continue
        new, old = rows["sobol", 256]["rmse"], rows[OLD, 256]["rmse"]
        new_k, old_k = rows["sobol", 256]["rmse_keep"], rows[OLD, 256]["rmse_keep"]
        target = ""
        if name == "stanford-bunny":
            target = f" (target <= 0.80: {'met' if new <= 0.8 * old else 'NOT met'})"
        print(f"- {name}, 256 rays: new default `sobol` RMSE {new:.5f} vs old default "
              f"{old:.5f}: {new / old:.2f} x{target}; without the old release's leak "
              f"vertices {new_k:.5f} vs {old_k:.5f}: {new_k / old_k:.2f} x.")
    # Honest: in every table and at every ray count, 95% coverage >= 0.93 and
    # RMS(err)/RMS(stderr) <= 1.2 (the stderr is not too small on average).
    print("- Honest = 95% coverage >= 0.93 and RMS(err)/RMS(stderr) <= 1.2 in every table "
          "at every ray count.")
    honest, score = [], {}
    for sampler in (*NEW, OLD):
        cells = [t[sampler, r] for t in tables for r in ray_counts if (sampler, r) in t]
        ok = all(c["cover"] >= 0.93 and c["ratio"] <= 1.2 for c in cells)
        worst = min(c["cover"] for c in cells)
        # accuracy, the samplers' own (leak vertices left out): geometric mean over all
        # cells of RMSE / the best sampler's RMSE in that cell
        key = lambda c: c.get("rmse_keep", c["rmse"])  # noqa: E731
        rel = [key(t[sampler, r]) / min(key(t[s, r]) for s in (*NEW, OLD))
               for t in tables for r in ray_counts if (sampler, r) in t]
        score[sampler] = float(np.exp(np.mean(np.log(rel))))
        print(f"- `{sampler}`: worst coverage {worst:.3f}, max RMS(err)/RMS(stderr) "
              f"{max(c['ratio'] for c in cells):.2f}, RMSE {score[sampler]:.2f} x the best "
              f"sampler's (geometric mean over all tables and ray counts, leaks left out): "
              f"{'honest' if ok else 'NOT honest'}.")
        if ok:
            honest.append(sampler)
    if honest:
        best = min(honest, key=score.get)
        print(f"- Most accurate honest sampler: `{best}`.")
    else:
        print("- No sampler is honest in every case.")
    print()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="smoke run (~1 minute)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--old", type=Path, default=Path("/tmp/orig"),
                        help="checkout of the previous release (its kernel built in place)")
    parser.add_argument("--cache", type=Path,
                        default=Path(tempfile.gettempdir(), "aobake_bench_samplers"),
                        help="where the mesh references are cached (.npy)")
    parser.add_argument("--points", type=int, default=None)
    parser.add_argument("--seeds", type=int, default=None)
    parser.add_argument("--mesh-seeds", type=int, default=None)
    parser.add_argument("--ref-rays", default=None,
                        help="reference rays per mesh, e.g. 'stanford-bunny=8192,ogre=4096'")
    args = parser.parse_args()
    if not (args.old / "aobake" / "__init__.py").is_file():
        sys.exit(f"{args.old}: no old aobake checkout there (--old)")
    quick = args.quick
    args.points = args.points or (100 if quick else 500)
    args.seeds = args.seeds or (2 if quick else 8)
    mesh_seeds = list(range(args.mesh_seeds or (1 if quick else 3)))
    ray_counts = (64, 256) if quick else (64, 256, 1024)
    ref_rays = {"stanford-bunny": 1024} if quick else {"stanford-bunny": 8192, "ogre": 8192}
    if args.ref_rays:
        ref_rays.update({k: int(v) for k, v in (kv.split("=") for kv in args.ref_rays.split(","))})

    start = time.perf_counter()
    print(f"## bench_samplers ({'quick' if quick else 'full'}; {args.threads} threads; "
          f"old release from {args.old})\n")
    tables = [closed_form(args, ray_counts)]
    meshes = []
    for name, rays in ref_rays.items():
        path = SHARED / f"{name}.obj"
        if not path.is_file():
            print(f"({path}: not found, skipped)\n")
            continue
        rows = mesh_rows(path, rays, ray_counts, mesh_seeds, args)
        tables.append(rows)
        meshes.append((name, rows))
    headline(tables, meshes, ray_counts)
    print(f"(total {time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
