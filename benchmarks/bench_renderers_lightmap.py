"""Time to a per-texel error: an aobake lightmap against Blender Cycles' AO bake into an
image, the same atlas, the same texels (issue 32 point 6, the lightmap half).  A benchmark
that prints a table, not a test.

    AOBAKE_BLENDER_PYTHON=/path/to/bpy/bin/python python benchmarks/bench_renderers_lightmap.py
    python benchmarks/bench_renderers_lightmap.py --quick            # smoke run, ~2 minutes
    python benchmarks/bench_renderers_lightmap.py --mesh M.obj --resolution 512 \\
        --budgets 16 64 256 --cycles-budgets 16 64 256 --json out.json

**The atlas.** The Stanford bunny (../shared/meshes/stanford-bunny.obj; without ../shared,
the project's generated still life, assets/still_life.obj) has no UVs: aobake makes one
atlas for it (``aobake MESH --resolution R --mesh-out atlas.obj``, untimed, cached in the
temporary directory) and both tools bake that same OBJ into an R x R image, so their
texels correspond one to one (a mesh with valid UVs of its own keeps them).

**The conventions, matched.** AO as aobake defines it (docs/conventions.md):
cosine-weighted, 1 = open, unbounded (aobake's default ``--max-distance inf``; Cycles' AO
distance, the world's ``light_settings.distance``, 1e10).  Normal: aobake's texel samples
take the interpolated vertex normal (the OBJ's ``vn``, which the atlas carries); Cycles' AO
pass samples about the shading normal, so the object is shaded smooth and Blender's
importer keeps the ``vn`` as custom normals: the same normal at every point.  Cycles' lift
of a grazing ray's origin off a smooth-shaded triangle (the object's
``shadow_terminator_geometry_offset``, 0.1 by default) is set to 0: aobake traces from the
flat triangle (at 0.1 Cycles read the bunny lighter by +0.0016 on average).  Texels: both
put texel (row r, column c) at u = (c + 0.5) / W, v = 1 - (r + 0.5) / H (Blender counts
rows from the bottom: flipped on reading).  A Cycles texel is baked where its centre lies
on a triangle; sample 0 is that centre, later samples are jittered over a box half a texel
wide around it (Blender's bake differentials are half a texel's) and kept inside the same
triangle: the mean AO over the central quarter of the texel within one triangle.  An aobake
texel is the mean over ``--texel-samples`` (4) stratified positions on the covered part of
the whole texel, every triangle.  The two agree where AO varies linearly across a texel;
the rest is a difference of definitions, largest at chart edges, shrinking with the texel:
the limit check measures it.  Texels scored: those both tools bake (every Cycles texel is
also an aobake texel; ``--texels interior`` keeps those inside a chart).  No gutters are
scored (Cycles bakes with margin 0).  aobake bakes with ``seams='off'``: seam erasure
changes texels along UV seams so that bilinear lookups agree across them, a step Cycles
does not have.

**The limit check** (before any timing): Cycles with ``--limit-samples`` (default 1024)
samples, twice with two seeds, against the reference, over the scored texels: the mean
difference with its standard error, and the RMSE with the noise of both taken out,
sqrt(max(0, mean(d^2) - mean(se_ref^2) - mean((c1 - c2)^2) / 4)) for d = (c1 + c2) / 2 - ref
(the "floor": what no number of samples would remove).  Also by kind of texel: interior
(every reference position on the surface) and chart edge.  Printed as agreeing when the
mean difference is within 4 standard errors (or 5e-4) and the floor is at most 0.3 x the
smallest target: then Cycles can reach every target.

**The reference**: aobake with ``--ref-rays`` (4096) rays per texel over 16 positions, another
seed than the runs, cached in the temporary directory (keyed by the atlas file, the
settings and aobake's version).  Each row's error is the per-texel RMSE against it over
the scored texels with the reference's own noise taken out,
sqrt(max(0, mean(e^2) - mean(se_ref^2))), as benchmarks/bench_renderers.py does per pixel.

**Budgets** are rays per texel: aobake's ``--rays`` (split over 4 positions; sobol's
budgets are R 2^k, so one with another odd factor runs as that many ``--replicates``: 384 =
3 x 128; an interpolated budget is not one aobake casts, so its first budget run that
reaches each target is printed too, as run), Cycles'
samples (one AO ray each).  A series stops at the first budget whose RMSE is below the
smallest target (``--all-budgets`` runs them all).  Time to each target (``--targets``,
0.01 and 0.005): between the two budgets whose errors bracket it, log RMSE against log
budget (no slope assumed: quasi-Monte Carlo samplers fall faster than 1/sqrt(rays)),
seconds linear in the budget between them; at or below the first budget "<=" its time;
past the last budget extrapolated as RMSE ~ 1/sqrt(budget) ("~", an estimate only).

**Times are each tool's own**, every row in a process of its own (so no row inherits
another's state), each tool's imports and the mesh file's reading left out, one untimed
warm-up bake first in the same process (one-time set-up: loading Embree, Cycles' first
session):
* aobake: the library call ``aobake.bake_texels(scene, ...)`` on the mesh read beforehand
  (benchmarks/_aobake_lightmap.py): UV check, rasterising the texel samples, Embree's
  BVH, tracing, the texel means and error bars, and the gutter fill (padding 2 and
  push-pull), on ``--threads`` threads.
* Cycles: Blender's bake operator ``bpy.ops.object.bake(type='AO')`` after the OBJ import
  (benchmarks/_cycles_bake.py, bpy 5.0.1): Blender's depsgraph, Cycles' scene sync and
  BVH build, rasterising the texels, the samples, writing the result into the image in
  memory (margin 0: no gutter); ``render.threads`` = ``--threads``.
CPU seconds (the process's, all its threads, over the call) are printed beside wall
seconds.  Other work on the cores is measured before, during and after each row
(benchmarks/_machine.py: the busy time of every core from /proc/stat less this process's and
its children's CPU time); a row with more than ``--threshold`` (0.3) cores of it before or
during is run again after waiting for a quiet second (``--wait``, ``--retries``) and, if
still loaded, marked "not comparable (load)", as is any time-to-error figure resting on it.

``--quick``: a smoke run (256 x 256, budgets 4 16 64, a 1024-ray reference, the limit
check at 256 samples, targets 0.05 and 0.03).  ``--json PATH`` writes every number.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE))

import _machine  # noqa: E402

SHARED_MESH = ROOT.parent / "shared" / "meshes" / "stanford-bunny.obj"
FALLBACK_MESH = ROOT / "assets" / "still_life.obj"
AOBAKE_RUNNER = HERE / "_aobake_lightmap.py"
CYCLES_RUNNER = HERE / "_cycles_bake.py"

FULL = {"resolution": 1024, "budgets": (16, 32, 64, 128, 256, 512, 1024, 2048),
        "cycles_budgets": (16, 32, 64, 128, 256, 512, 1024, 2048),
        "ref_rays": 4096, "ref_texel_samples": 16, "limit_samples": 1024,
        "targets": (0.01, 0.005)}
QUICK = {"resolution": 256, "budgets": (4, 16, 64), "cycles_budgets": (4, 16, 64),
         "ref_rays": 1024, "ref_texel_samples": 16, "limit_samples": 256,
         "targets": (0.05, 0.03)}
#: seed of the reference (the rows use 0, 1, ...; Cycles' limit check LIMIT_SEEDS)
REF_SEED = 987654321
LIMIT_SEEDS = (1001, 1002)
#: the floor (the error no budget removes) above which Cycles is said not to agree
FLOOR_SHARE = 0.3


def log(text: str = "") -> None:
    print(text, flush=True)


def file_key(path: Path) -> str:
    """A digest of a file's bytes (the atlas: the same file, the same reference)."""
    digest = hashlib.sha1()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()[:12]


def aobake_version() -> str:
    import aobake

    return aobake.__version__


# ---- the atlas and the reference ------------------------------------------------------------

def make_atlas(mesh: Path, resolution: int, threads: int, cache: Path) -> Path:
    """The mesh with its lightmap UVs as an OBJ (aobake's atlas, made once and cached)."""
    st = mesh.stat()
    key = hashlib.sha1(f"{mesh.resolve()}|{st.st_size}|{st.st_mtime_ns}|{resolution}|"
                       f"{aobake_version()}".encode()).hexdigest()[:12]
    atlas = cache / f"aobake_lightmap_atlas_{mesh.stem}_{resolution}_{key}.obj"
    if atlas.is_file():
        return atlas
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp, "atlas.exr")
        made = Path(tmp, "atlas.obj")
        cmd = [sys.executable, "-m", "aobake", str(mesh), "--out", str(out), "--resolution",
               str(resolution), "--rays", "1", "--texel-samples", "1", "--seams", "off",
               "--threads", str(threads), "--mesh-out", str(made), "--quiet"]
        done = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, check=False)
        if done.returncode != 0 or not made.is_file():
            raise SystemExit(f"making the atlas failed: {done.stderr.strip()[-800:]}")
        os.replace(made, atlas)
    return atlas


def run_child(cmd: list, out: Path, what: str) -> dict:
    """Run one row's process to its end; its NPZ as a dict (+ ``process_s``)."""
    out.unlink(missing_ok=True)
    clock = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, check=False, cwd=ROOT)
    process_s = time.perf_counter() - clock
    if done.returncode != 0 or not out.is_file():
        tail = "\n".join(done.stderr.strip().splitlines()[-8:])
        raise RuntimeError(f"{what} exited {done.returncode}: {tail}")
    with np.load(out) as data:
        res = {k: data[k] for k in data.files}
    for k, v in list(res.items()):
        if v.ndim == 0:
            res[k] = v.item()
    res["info"] = json.loads(res.get("info", "{}"))
    res["process_s"] = process_s
    return res


def run_aobake(args, atlas: Path, rays: int, texel_samples: int, seed: int, work: Path,
               warmup: bool = True) -> dict:
    out = work / "aobake.npz"
    cmd = [sys.executable, str(AOBAKE_RUNNER), str(atlas), "--out", str(out),
           "--resolution", str(args.resolution), "--rays", str(rays), "--texel-samples",
           str(texel_samples), "--seed", str(seed), "--threads", str(args.threads)]
    if warmup:
        cmd.append("--warmup")
    return run_child(cmd, out, f"aobake ({rays} rays)")


def run_cycles(args, atlas: Path, samples: int, seed: int, work: Path) -> dict:
    out = work / "cycles.npz"
    cmd = [args.blender_python, str(CYCLES_RUNNER), str(atlas), "--out", str(out), "--size",
           str(args.resolution), "--samples", str(samples), "--seed", str(seed),
           "--threads", str(args.threads), "--warmup"]
    return run_child(cmd, out, f"Cycles ({samples} samples)")


def reference(args, atlas: Path, work: Path) -> dict:
    """aobake at --ref-rays rays over --ref-texel-samples positions per texel, seed REF_SEED
    (its own process, untimed; cached in --cache)."""
    key = hashlib.sha1(json.dumps([file_key(atlas), args.resolution, args.ref_rays,
                                   args.ref_texel_samples, REF_SEED,
                                   aobake_version()]).encode()).hexdigest()[:12]
    cached = args.cache / f"aobake_lightmap_ref_{key}.npz"
    if cached.is_file() and not args.fresh_reference:
        with np.load(cached) as data:
            ref = {k: data[k] for k in data.files}
        ref["cached"], ref["path"] = True, str(cached)
        return ref
    log(f"baking the reference ({args.ref_rays} rays per texel over "
        f"{args.ref_texel_samples} positions; cached as {cached}) ...")
    res = run_aobake(args, atlas, args.ref_rays, args.ref_texel_samples, REF_SEED, work,
                     warmup=False)
    ref = {"ao": res["ao"], "ao_stderr": res["ao_stderr"], "coverage": res["coverage"],
           "seconds": np.float64(res["seconds"])}
    tmp = cached.with_suffix(".tmp.npz")
    np.savez(tmp, **ref)
    os.replace(tmp, cached)
    ref["cached"], ref["path"] = False, str(cached)
    return ref


# ---- errors ----------------------------------------------------------------------------------

def scores(estimate, ref: dict, mask) -> dict:
    """RMSE of ``estimate`` against the reference over ``mask``, raw and with the
    reference's noise taken out (``rmse``), and the mean difference."""
    e = np.asarray(estimate, dtype=np.float64)[mask] - ref["ao"][mask].astype(np.float64)
    se2 = float(np.mean(ref["ao_stderr"][mask].astype(np.float64) ** 2))
    ms = float(np.mean(e ** 2))
    return {"rmse": math.sqrt(max(0.0, ms - se2)), "rmse_raw": math.sqrt(ms),
            "bias": float(np.mean(e)), "texels": int(mask.sum())}


def limit_stats(c1, c2, ref: dict, mask) -> dict:
    """Cycles' two high-sample bakes against the reference over ``mask``: mean difference
    (and its standard error), RMSE, the noise both carry, and the floor left."""
    c1 = np.asarray(c1, dtype=np.float64)[mask]
    c2 = np.asarray(c2, dtype=np.float64)[mask]
    r = ref["ao"][mask].astype(np.float64)
    d = (c1 + c2) / 2 - r
    n = len(d)
    cyc2 = float(np.mean((c1 - c2) ** 2)) / 4  # the variance of the mean of the two
    ref2 = float(np.mean(ref["ao_stderr"][mask].astype(np.float64) ** 2))
    ms = float(np.mean(d ** 2))
    return {"texels": n, "bias": float(np.mean(d)),
            "bias_se": float(np.std(d) / math.sqrt(max(n, 1))),
            "rmse": math.sqrt(ms), "noise_cycles": math.sqrt(cyc2),
            "noise_ref": math.sqrt(ref2),
            "floor": math.sqrt(max(0.0, ms - cyc2 - ref2)),
            "ratio": math.sqrt(ms / (cyc2 + ref2)) if cyc2 + ref2 > 0 else float("nan")}


def time_to(rows: list, target: float, key: str = "seconds"):
    """(budget, seconds, how, comparable) at which ``rows`` reach RMSE ``target``:
    interpolated between the two budgets that bracket it (log RMSE against log budget,
    row[key] linear in the budget); at or below the first budget, that row ('<='); past the
    last, extrapolated as RMSE ~ 1/sqrt(budget), seconds ~ budget ('~')."""
    rows = sorted(rows, key=lambda r: r["budget"])
    for i, row in enumerate(rows):
        if row["rmse"] <= target:
            if i == 0:
                return row["budget"], row[key], "<=", row["comparable"]
            a, b = rows[i - 1], row
            x = ((math.log(a["rmse"]) - math.log(target))
                 / (math.log(a["rmse"]) - math.log(max(b["rmse"], 1e-12))))
            budget = math.exp(math.log(a["budget"])
                              + x * (math.log(b["budget"]) - math.log(a["budget"])))
            fraction = (budget - a["budget"]) / (b["budget"] - a["budget"])
            return (budget, a[key] + fraction * (b[key] - a[key]), "=",
                    a["comparable"] and b["comparable"])
    last = rows[-1]
    if last["rmse"] <= 0:
        return None, None, None, True
    budget = last["budget"] * (last["rmse"] / target) ** 2
    return budget, last[key] * budget / last["budget"], "~", last["comparable"]


# ---- the runs --------------------------------------------------------------------------------

def make_row(tool: str, budget: int, res: dict, load: dict) -> dict:
    others = [load[k]["others_cores"] for k in ("before", "during", "after")]
    if tool == "aobake":
        timings = res["info"].get("timings", {})
        binding = res["info"].get("embree_binding") or ""
        width = binding.split("packets of ")[1].split(":")[0] if "packets of " in binding \
            else "embreex"
        row = {"seconds": float(res["seconds"]), "cpu_s": float(res["cpu_s"]),
               "rays_per_texel": res["rays_cast"] / max(1, res["info"].get("texels_covered")
                                                        or 1),
               "note": (f"raster {timings.get('rasterize_s', 0):.2f} s, trace "
                        f"{timings.get('trace_s', 0):.2f} s, splat+gutters "
                        f"{timings.get('splat_dilate_s', 0):.2f} s; {width} lanes; "
                        f"file read {res['read_s']:.2f} s, warm-up {res['warmup_s']:.2f} s "
                        "(not counted)"),
               "timings": timings}
    else:
        info = res["info"]
        row = {"seconds": float(res["bake_s"]), "cpu_s": float(res["bake_cpu_s"]),
               "rays_per_texel": float(budget),
               "note": (f"Blender {res['version']}, {info.get('shading')} shading, custom "
                        f"normals {info.get('custom_normals')}; OBJ import "
                        f"{res['import_s']:.2f} s, import bpy {res['bpy_import_s']:.2f} s, "
                        f"warm-up {res['warmup_s']:.2f} s (not counted)")}
    row.update({"tool": tool, "budget": budget, "comparable": load["comparable"],
                "others_cores": others,
                "loadavg_1min": [load["before"]["loadavg_1min"][0],
                                 load["after"]["loadavg_1min"][1]],
                "attempts": load["attempts"], "process_s": res["process_s"]})
    return row


def series(args, tool: str, budgets, bake, ref, score_mask, images: dict) -> list:
    """Bake each budget in turn (stopping below the smallest target unless --all-budgets);
    each row's image is kept in ``images`` for the final scoring."""
    rows = []
    for budget in budgets:
        res, load = _machine.watched(args, lambda: bake(budget), log, f"{tool} {budget}")
        row = make_row(tool, budget, res, load)
        images[(tool, budget)] = res
        rows.append(row)
        s = scores(res["ao"], ref, score_mask(res))
        mark = "" if row["comparable"] else "  NOT COMPARABLE (load)"
        log(f"  {tool:7s} {budget:6d} rays/texel  {row['seconds']:8.2f} s  cpu "
            f"{row['cpu_s']:8.2f} s  RMSE {s['rmse']:.5f} (so far: on its own texels)  others "
            + "/".join(f"{o:.2f}" for o in row["others_cores"]) + mark)
        if s["rmse"] < min(args.targets) and not args.all_budgets:
            break
    return rows


def fmt_time(t) -> str:
    budget, seconds, how, comparable = t
    if seconds is None:
        return "—"
    text = {"=": "", "<=": "<= ", "~": "~ "}[how] + f"{seconds:.2f} s ({budget:.0f}/texel)"
    return text if comparable else f"{text} not comparable (load)"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mesh", type=Path, help="default: ../shared/meshes/stanford-bunny.obj"
                        ", else assets/still_life.obj")
    parser.add_argument("--quick", action="store_true", help="smoke run (see the docstring)")
    parser.add_argument("--resolution", type=int)
    parser.add_argument("--budgets", type=int, nargs="+", help="aobake's rays per texel")
    parser.add_argument("--cycles-budgets", type=int, nargs="+", help="Cycles' samples")
    parser.add_argument("--texel-samples", type=int, default=4,
                        help="aobake's positions per texel in the timed rows (4)")
    parser.add_argument("--ref-rays", type=int)
    parser.add_argument("--ref-texel-samples", type=int)
    parser.add_argument("--limit-samples", type=int,
                        help="Cycles' samples in the limit check (1024; 0: no check)")
    parser.add_argument("--targets", type=float, nargs="+", help="RMSE targets (0.01 0.005)")
    parser.add_argument("--texels", choices=["both", "interior"], default="both",
                        help="texels scored: all both tools bake, or only those inside a "
                             "chart (every reference position on the surface)")
    parser.add_argument("--all-budgets", action="store_true",
                        help="do not stop a series below the smallest target")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--tools", nargs="+", choices=["aobake", "cycles"],
                        default=["aobake", "cycles"])
    parser.add_argument("--blender-python", default=os.environ.get("AOBAKE_BLENDER_PYTHON"),
                        help="a Python with bpy (default: $AOBAKE_BLENDER_PYTHON)")
    parser.add_argument("--threshold", type=float, default=_machine.LOAD_THRESHOLD,
                        help="other work (cores) above which a row is not comparable (0.3)")
    parser.add_argument("--wait", type=float, default=60.0,
                        help="seconds to wait for other work below --threshold before a row")
    parser.add_argument("--retries", type=int, default=2,
                        help="times a row under load is run again (2)")
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()),
                        help="where the atlas and the reference are cached")
    parser.add_argument("--fresh-reference", action="store_true")
    parser.add_argument("--json", type=Path, help="also write every number here")
    args = parser.parse_args(argv)

    cfg = dict(QUICK if args.quick else FULL)
    for key in ("resolution", "budgets", "cycles_budgets", "ref_rays", "ref_texel_samples",
                "limit_samples", "targets"):
        value = getattr(args, key)
        if value is None:
            setattr(args, key, cfg[key])
    args.targets = tuple(sorted(args.targets, reverse=True))
    mesh = args.mesh or (SHARED_MESH if SHARED_MESH.is_file() else FALLBACK_MESH)
    if not mesh.is_file():
        sys.exit(f"{mesh}: not found")

    skipped = []
    tools = list(args.tools)
    blender = None
    if "cycles" in tools:
        if not args.blender_python:
            skipped.append("Cycles: no Python with bpy (set AOBAKE_BLENDER_PYTHON or "
                           "--blender-python; docs/renderers.md)")
            tools.remove("cycles")
        else:
            done = subprocess.run([args.blender_python, str(CYCLES_RUNNER), "--version"],
                                  capture_output=True, text=True, check=False)
            if done.returncode != 0:
                why = (done.stderr.strip().splitlines() or ["?"])[-1]
                skipped.append(f"Cycles: {args.blender_python} has no usable bpy ({why})")
                tools.remove("cycles")
            else:
                blender = done.stdout.strip().splitlines()[-1]

    machine = _machine.cpu()
    log(f"machine: {machine['model']}, {machine['logical_cpus']} logical CPUs, vector "
        f"{' '.join(machine['vector']) or 'none'}; {args.threads} threads per tool; load "
        f"average {os.getloadavg()[0]:.2f}")
    work = Path(tempfile.mkdtemp(prefix="aobake_bench_lightmap_"))
    args.cache.mkdir(parents=True, exist_ok=True)
    clock = time.perf_counter()
    atlas = make_atlas(mesh, args.resolution, args.threads, args.cache)
    log(f"mesh: {mesh}; atlas {atlas} ({time.perf_counter() - clock:.1f} s)")
    clock = time.perf_counter()
    ref = reference(args, atlas, work)
    ref_cov = ref["coverage"] > 0
    ref_full = ref["coverage"] >= 1.0
    log(f"reference: aobake {args.ref_rays} rays/texel over {args.ref_texel_samples} "
        f"positions, seed {REF_SEED}: {int(ref_cov.sum()):,} texels, noise rms "
        f"{math.sqrt(float(np.mean(ref['ao_stderr'][ref_cov] ** 2))):.5f}"
        + (" (cached)" if ref["cached"] else f" ({time.perf_counter() - clock:.0f} s)"))

    # Texels Cycles bakes are the same for every sample count: found by the limit check or
    # its first row. The mask of a row before that is its own coverage with the reference's.
    baked = {}

    def score_mask(res):
        own = res["baked"] if "baked" in res else res["coverage"] > 0
        mask = ref_cov & own
        if "cycles" in baked and "baked" not in res:
            mask &= baked["cycles"]
        return mask & ref_full if args.texels == "interior" else mask

    limit = None
    if "cycles" in tools and args.limit_samples:
        log(f"\nlimit check: Cycles at {args.limit_samples} samples, seeds {LIMIT_SEEDS} "
            "(untimed) ...")
        pair = [run_cycles(args, atlas, args.limit_samples, seed, work)
                for seed in LIMIT_SEEDS]
        baked["cycles"] = pair[0]["baked"]
        both = ref_cov & baked["cycles"]
        limit = {"samples": args.limit_samples, "seeds": list(LIMIT_SEEDS),
                 "texels_cycles": int(pair[0]["baked"].sum()),
                 "texels_aobake": int(ref_cov.sum()),
                 "cycles_only": int((pair[0]["baked"] & ~ref_cov).sum())}
        for name, mask in (("both", both), ("interior", both & ref_full),
                           ("chart edge", both & ~ref_full)):
            limit[name] = limit_stats(pair[0]["ao"], pair[1]["ao"], ref, mask)
        scored = limit[args.texels if args.texels == "interior" else "both"]
        limit["agree"] = (abs(scored["bias"]) <= max(4 * scored["bias_se"], 5e-4)
                          and scored["floor"] <= FLOOR_SHARE * min(args.targets))
        log(f"texels: Cycles bakes {limit['texels_cycles']:,}, aobake {limit['texels_aobake']:,}"
            f", Cycles only {limit['cycles_only']:,}")
        for name in ("both", "interior", "chart edge"):
            s = limit[name]
            log(f"  {name:10s} {s['texels']:9,d} texels: mean diff {s['bias']:+.5f} "
                f"(se {s['bias_se']:.5f}), RMSE {s['rmse']:.5f}, noise Cycles "
                f"{s['noise_cycles']:.5f} ref {s['noise_ref']:.5f}, ratio {s['ratio']:.3f}, "
                f"floor {s['floor']:.5f}")
        log(f"  -> Cycles {'agrees' if limit['agree'] else 'DOES NOT AGREE'} with aobake's "
            f"reference on the scored texels ({args.texels}; floor <= {FLOOR_SHARE} x "
            f"{min(args.targets)}, mean within 4 se)")

    log(f"\nrows ({args.threads} threads; other work before/during/after in cores):")
    images: dict = {}
    rows = {}
    if "aobake" in tools:
        rows["aobake"] = series(
            args, "aobake", args.budgets,
            lambda b: run_aobake(args, atlas, b, args.texel_samples, 0, work), ref,
            score_mask, images)
    if "cycles" in tools:
        rows["cycles"] = series(
            args, "cycles", args.cycles_budgets,
            lambda b: run_cycles(args, atlas, b, 1, work), ref, score_mask, images)
        baked.setdefault("cycles", images[("cycles", rows["cycles"][0]["budget"])]["baked"])

    # The scored texels: the reference's, every row's, Cycles' (the same for every row).
    mask = ref_cov.copy()
    for res in images.values():
        mask &= res["baked"] if "baked" in res else res["coverage"] > 0
    if args.texels == "interior":
        mask &= ref_full
    for tool, tool_rows in rows.items():
        for row in tool_rows:
            row.update(scores(images[(tool, row["budget"])]["ao"], ref, mask))

    name = {"aobake": f"aobake (K={args.texel_samples})",
            "cycles": f"Cycles AO bake ({blender})"}
    log(f"\n{mesh.name}, {args.resolution}x{args.resolution}, {int(mask.sum()):,} texels "
        f"scored ({args.texels}: baked by both); RMSE with the reference's noise taken out\n")
    header = ("| tool | rays/texel | wall s | CPU s | RMSE | raw RMSE | mean diff | "
              "other work before / during / after (cores) | notes |")
    log(header)
    log("|---|---|---|---|---|---|---|---|---|")
    for tool, tool_rows in rows.items():
        for r in tool_rows:
            secs = f"{r['seconds']:.2f}" if r["comparable"] else \
                f"not comparable (load): {r['seconds']:.2f}"
            log(f"| {name[tool]} | {r['budget']} | {secs} | {r['cpu_s']:.2f} | "
                f"{r['rmse']:.5f} | {r['rmse_raw']:.5f} | {r['bias']:+.5f} | "
                + " / ".join(f"{o:.2f}" for o in r["others_cores"]) + f" | {r['note']} |")
    summary = {}
    for tool, tool_rows in rows.items():
        summary[tool] = {t: {"wall": time_to(tool_rows, t), "cpu": time_to(tool_rows, t,
                                                                           "cpu_s")}
                         for t in args.targets}
    log("")
    head = " | ".join(f"to RMSE {t:g}: wall | CPU" for t in args.targets)
    log(f"| tool | {head} |")
    log("|---|" + "---|---|" * len(args.targets))
    for tool in rows:
        cells = []
        for t in args.targets:
            cells += [fmt_time(summary[tool][t]["wall"]), fmt_time(summary[tool][t]["cpu"])]
        log(f"| {name[tool]} | " + " | ".join(cells) + " |")
    ratios = {}
    if "aobake" in rows and "cycles" in rows:
        log("")
        for t in args.targets:
            for kind in ("wall", "cpu"):
                a, c = summary["aobake"][t][kind], summary["cycles"][t][kind]
                if a[1] is None or c[1] is None:
                    continue
                exact = a[2] == "=" and c[2] == "="
                ratio = c[1] / a[1]
                ratios[f"{t:g} {kind}"] = {"cycles_over_aobake": ratio, "interpolated": exact,
                                           "comparable": a[3] and c[3]}
                log(f"  RMSE {t:g}, {kind}: Cycles / aobake = {ratio:.2f}"
                    + ("" if exact else " (rests on a bound or an extrapolation)")
                    + ("" if a[3] and c[3] else " (not comparable: load)"))
            # an interpolated budget is not one aobake can cast (sobol: R 2^k): its first
            # row that reaches the target, as run, against Cycles' interpolated time
            reached = [r for r in sorted(rows["aobake"], key=lambda r: r["budget"])
                       if r["rmse"] <= t]
            c = summary["cycles"][t]["wall"]
            if reached and c[1] is not None:
                r = reached[0]
                log(f"  RMSE {t:g}, wall, aobake as run ({r['budget']} rays/texel, RMSE "
                    f"{r['rmse']:.5f}, {r['seconds']:.2f} s): Cycles / aobake = "
                    f"{c[1] / r['seconds']:.2f}")
    for line in skipped:
        log(f"skipped: {line}")
    if args.json:
        out = {"mesh": str(mesh), "atlas": str(atlas), "resolution": args.resolution,
               "threads": args.threads, "texel_samples": args.texel_samples,
               "texels": args.texels, "texels_scored": int(mask.sum()),
               "targets": list(args.targets), "machine": machine,
               "versions": {"python": platform.python_version(), "aobake": aobake_version(),
                            "blender": blender, "numpy": np.__version__},
               "reference": {"rays": args.ref_rays, "texel_samples": args.ref_texel_samples,
                             "seed": REF_SEED, "cache": ref["path"],
                             "noise_rms": math.sqrt(float(np.mean(
                                 ref["ao_stderr"][mask] ** 2))) if mask.any() else None},
               "limit_check": limit, "rows": rows, "time_to": {
                   tool: {f"{t:g}": {kind: dict(zip(("budget", "seconds", "how", "comparable"),
                                                    v)) for kind, v in by.items()}
                          for t, by in s.items()} for tool, s in summary.items()},
               "cycles_over_aobake": ratios, "skipped": skipped}
        args.json.write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
