"""Side by side: aobake and its peers, in seconds to the same error, on real meshes.

    pip install -e '.[peers]'            # libigl, open3d, matplotlib
    pip install --no-deps bpy==5.0.1     # Blender (Python 3.11 wheel; see below)
    python benchmarks/bench_peers.py [--meshes bunny ogre] [--threads 2] [--json peers.json]
        [--skip PEER ...] [--quick] [--packet-width W] [--wait S] [--retries K]

Installing: bpy 5.0.1 pins numpy<2 (which would move numpy to 1.26 and OpenImageIO to 3.0),
so it is not in the extra: ``pip install --no-deps bpy==5.0.1`` keeps numpy 2 (it bakes under
numpy 2; only its audio module fails to load, harmlessly), or put bpy in a venv of its own
and pass ``--blender-python``.  Open3D needs libusb
(``apt-get install libusb-1.0-0``).  A peer that does not import is skipped with a message.

Every method bakes per-vertex AO of every vertex of each mesh (default: the Stanford bunny
and the ogre from ../shared/meshes), max distance infinite, on ``--threads`` threads, at
several ray counts, and is scored by its RMSE against a shared reference over the vertices
with a normal (the bunny has 1,113 unreferenced vertices, baked as "no information").

**Every row is timed in a fresh process** (the CLI as itself, the others through
benchmarks/_peers_runner.py, Blender through benchmarks/_peers_blender.py), so no row
inherits the state another left behind (inside this script's own process the library call
once took 4.29 s on the bunny at 256 rays where a fresh process took 1.8-2.3 s).

**What the figures were taken on, and under what load.**  The header names the CPU model
(/proc/cpuinfo), its vector extensions (AVX2, AVX-512F, ...), Embree's native packet width
on it and the packet width each aobake row used (read back from its report).  Around each
row (benchmarks/_machine.py) the CPU time *other* work used is measured: 0.5 s while this
script sleeps before the row, over the row itself (all cores' busy time from /proc/stat
less the CPU time of this process and its children), and 0.5 s after.  A row where other
work used more than ``--threshold`` cores (0.3) before it or during it is printed as "not
comparable (load)" (the load after it is recorded beside); it is run again up to
``--retries`` times (2), each time after waiting up to ``--wait`` seconds (60) for a quiet
second (two samples in a row below the threshold), and every attempt is kept in the JSON.  A time-to-error figure interpolated from a row under load is marked
"(load)" too.  The figures mean something only next to the CPU they came from.

The reference, one per mesh and AO convention: aobake, ``sobol``, 16,384 rays per vertex,
with another seed than the runs (with the same seed it would share their randomisation and
their errors would look smaller than they are).  Its own rms reported stderr is printed: a
measured RMSE r includes it in quadrature, the method's own error is sqrt(r^2 - ref^2).
References are cached in ``--cache`` (default /tmp) as NPZ, keyed by mesh file (path,
size, mtime) + convention + rays + seed, so reruns skip them.

Rows (``--skip`` takes the names in brackets):

* [cli] the aobake CLI as a subprocess, ``aobake MESH --out X.npz --rays N --threads T
  --quiet --report r.json``: the whole process (interpreter start, import, file read, bake,
  writing); rays cast and packet width from the report, error from the NPZ.
* [replicates] the CLI as [cli] with ``--replicates 2``: the same sampler in two
  replicates (a more accurate value for the rays; the stderr on one degree of freedom).
* [library] ``aobake.bake(path, rays=N, threads=T)``, file read included, in a fresh
  process with aobake's modules imported before the clock starts.
* [tolerance] the CLI with ``--tolerance E`` (default pilot, the CLI's ``--rays`` default;
  ``--pilot`` to change it): rays cast (pilot + final) from its report.
* [bare] a bare embreex loop (as benchmarks/bench_throughput.py): the rays of the library
  run at the same N, generated beforehand by aobake's own generator (not timed), traced
  through ``EmbreeScene.run(query="OCCLUDED")`` (one ray at a time) on T threads in the
  same chunks; two rows: the tracing alone, and build + tracing.  AO = the unoccluded
  fraction (cosine-distributed rays).  It shows what is left to gain below aobake.
* [libigl] ``igl.embree.ambient_occlusion(V, F, V, N, n)`` (whole call: it builds its Embree
  scene each time), scored against the **uniform** reference: libigl averages visibility over
  uniformly distributed hemisphere directions and returns the occluded fraction, so
  AO = 1 - result.  Its directions are one stratified-random set shared by every vertex
  (flipped into each hemisphere), traced with an absolute tnear of 1e-4 scene units; its
  thread pool is sized by IGL_NUM_THREADS, set to T for its process.  It is handed all
  vertices, the unreferenced ones too (its call as documented), and they count in its rays.
* [open3d] ``o3d.t.geometry.RaycastingScene.test_occlusions`` on rays generated in
  numpy: cosine-weighted (u -> (sqrt(u0) cos 2 pi u1, sqrt(u0) sin 2 pi u1, sqrt(1 - u0))
  in a frame about the vertex normal), i.i.d. from one PCG64 stream, origins lifted along
  the normal by aobake's own per-vertex offset rule (computed once, untimed), tnear 0,
  tfar inf, nthreads T.  Its seconds are scene build + ray generation in numpy + tracing +
  the per-vertex mean: the numpy generation is single-threaded and part of what a user of
  Open3D pays (the notes give its share).
* [blender] Blender Cycles' AO bake to a CORNER colour attribute through ``bpy``
  (benchmarks/_peers_blender.py, one process per sample count: CPU, FIXED threads = T,
  samples = n, world AO distance 1e10).  Cycles bakes each face corner with n samples of
  its own; corners are averaged to vertices by vertex index, and its rays are corners x
  samples.  Its seconds are the bake call; the notes give the OBJ import and ``import bpy``.
  It is scored against both references; the one with the lower RMSE at its highest sample
  count is taken as its convention.  Measured: cosine-weighted, 1 = open (the bunny at 64
  samples: mean error +0.0006 against the cosine reference, +0.067 against the uniform one;
  a floor vertex under a coaxial 64-gon of radius 1 at height 1, 8 corners x 4096 samples:
  0.5002, where cosine AO is 0.5004 and uniform AO 0.707).

Per row: seconds, rays/s (rays cast / seconds), RMSE, the packet width (aobake rows), the
other work before / during / after (cores); per method the time to reach RMSE 0.01 and
0.005 (``--targets``), interpolated log-log between the two measured ray counts that
bracket it ("--" when not reached, "<= t" when the first count already reaches it), and its
ratio to the aobake CLI's time (> 1: slower than the CLI).  A method stops at the first
count whose RMSE is below the smallest target (``--all-counts`` runs them all).
``--packet-width W`` sets AOBAKE_PACKET_WIDTH for every aobake process (default: aobake's
own choice for this CPU, aobake.backends.native.packet_width).  Markdown tables per mesh on
stdout; ``--json PATH`` writes the same numbers, the machine and every attempt's load.

``--quick`` is a smoke run (about a minute): one mesh, three tiny ray counts, a 1,024-ray
reference, targets 0.05 / 0.04.
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

import aobake  # noqa: E402
from aobake.scene import load_scene  # noqa: E402

import _machine  # noqa: E402
from _peers_runner import packet_width_of  # noqa: E402

DEFAULT_MESH_DIR = HERE.parents[1] / "shared" / "meshes"
MESHES = {"bunny": "stanford-bunny.obj", "ogre": "ogre.obj"}
PEERS = ("cli", "replicates", "library", "tolerance", "bare", "libigl", "open3d", "blender")
RUNNER = HERE / "_peers_runner.py"

FULL = {"rays": (16, 32, 64, 128, 256, 512, 1024, 2048, 4096),
        "blender_rays": (16, 64, 256, 512),
        "tolerances": (0.02, 0.01, 0.005),
        "targets": (0.01, 0.005),
        "ref_rays": 16384}
QUICK = {"rays": (16, 32, 64), "blender_rays": (4, 8, 16), "tolerances": (0.05, 0.03),
         "targets": (0.05, 0.04), "ref_rays": 1024}

#: seed of the references; the runs use aobake's default (0)
REF_SEED = 987654321


# --------------------------------------------------------------------------- helpers

def pkg_version(name: str) -> str | None:
    try:
        return version(name)
    except PackageNotFoundError:
        return None


def errors(estimate: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> tuple:
    """(RMS, mean) of estimate - reference over mask (vertices with a normal), and how many
    of them the estimate leaves undefined (NaN), which are left out."""
    have = mask & np.isfinite(estimate)
    err = estimate[have] - reference[have]
    return (float(np.sqrt(np.mean(err**2))), float(np.mean(err)),
            int(np.count_nonzero(mask & ~have)))


def time_to(points: list, target: float):
    """Seconds to reach RMSE ``target`` from measured (rays, seconds, rmse, comparable)
    points: log-log interpolation between the first bracketing pair.  Returns (seconds,
    bound, comparable) with bound '=' (interpolated), '<=' (the first point is already
    below: its time is an upper bound) or None (never reached: seconds None), and
    comparable False when a point it rests on was taken under load."""
    pts = sorted(p for p in points if p[2] > 0 and p[1] > 0)
    if not pts:
        return None, None, True
    if pts[0][2] <= target:
        return pts[0][1], "<=", pts[0][3]
    for (_, ta, ea, ca), (_, tb, eb, cb) in itertools.pairwise(pts):
        if ea > target >= eb:
            f = (math.log(target) - math.log(ea)) / (math.log(eb) - math.log(ea))
            return math.exp((1 - f) * math.log(ta) + f * math.log(tb)), "=", ca and cb
    return None, None, True


def ratio(mine, cli):
    """(value, bound, comparable) of mine / cli for two time_to() results."""
    (tm, bm, cm), (tc, bc, cc) = mine, cli
    if tm is None or tc is None:
        return None, None, True
    bound = {("=", "="): "=", ("<=", "="): "<=", ("=", "<="): ">="}.get((bm, bc))
    return (tm / tc, bound, cm and cc) if bound else (None, None, True)


def fmt_bound(value, bound, comparable=True, digits=3) -> str:
    if value is None:
        return "—"
    text = f"{value:.{digits}g}" if value < 1000 else f"{value:.0f}"
    text = text if bound == "=" else f"{bound} {text}"
    return text if comparable else f"{text} (load)"


def file_key(path: Path) -> str:
    st = path.stat()
    return hashlib.sha1(f"{path.resolve()}|{st.st_size}|{st.st_mtime_ns}".encode()).hexdigest()[:10]


def valid_mask(ref: dict) -> np.ndarray:
    return ref["rays"] > 0


def child_env(args, **extra) -> dict:
    """The environment of every timed process: this one's, the packet width if given."""
    env = dict(os.environ, **extra)
    if args.packet_width is not None:
        env["AOBAKE_PACKET_WIDTH"] = str(args.packet_width)
    return env


def run_process(cmd: list, env: dict, what: str) -> float:
    """Run cmd to its end; its wall seconds.  RuntimeError with its stderr's tail."""
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False, env=env)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        tail = "\n".join(proc.stderr.strip().splitlines()[-5:])
        raise RuntimeError(f"{what} exited {proc.returncode}: {tail}")
    return wall


def run_runner(args, kind: str, path: Path, rays: int, work: Path, **options) -> dict:
    """One _peers_runner.py process: its ao, seconds, rays_cast, info (+ its process_s)."""
    out = work / f"{kind}.npz"
    out.unlink(missing_ok=True)
    cmd = [sys.executable, str(RUNNER), kind, str(path), "--rays", str(rays), "--threads",
           str(args.threads), "--out", str(out)]
    for key, value in options.items():
        cmd += [f"--{key}", str(value)]
    # libigl sizes its pool from IGL_NUM_THREADS once, when it is first used
    process_s = run_process(cmd, child_env(args, IGL_NUM_THREADS=str(args.threads)),
                            f"{kind} ({rays} rays)")
    with np.load(out) as data:
        res = {k: data[k] for k in data.files}
    res["info"] = json.loads(str(res["info"]))
    res["seconds"], res["rays_cast"] = float(res["seconds"]), int(res["rays_cast"])
    res["process_s"] = process_s
    return res


# --------------------------------------------------------------------------- reference

def reference(args, path: Path, weighting: str, rays: int, work: Path, log) -> dict:
    """aobake sobol at ``rays`` rays per vertex, seed REF_SEED: ao, ao_stderr, rays per vertex
    (baked in a process of its own, untimed; cached in --cache)."""
    name = f"aobake_peers_ref_{path.stem}_{weighting}_{rays}_{REF_SEED}_{file_key(path)}.npz"
    cached = args.cache / name
    if cached.is_file() and not args.fresh_reference:
        with np.load(cached) as data:
            out = {k: data[k] for k in data.files}
        out["cache"], out["cached"] = str(cached), True
        return out
    log(f"  baking the {weighting} reference ({rays} rays/vertex; cached as {cached}) ...")
    res = run_runner(args, "library", path, rays, work, sampler="sobol", seed=REF_SEED,
                     weighting=weighting)
    out = {"ao": res["ao"], "ao_stderr": res["ao_stderr"], "rays": res["rays"],
           "wall_s": np.float64(res["seconds"])}
    args.cache.mkdir(parents=True, exist_ok=True)
    tmp = cached.with_suffix(".tmp.npz")
    np.savez(tmp, **out)
    os.replace(tmp, cached)
    out["cache"], out["cached"] = str(cached), False
    return out


# --------------------------------------------------------------------------- aobake CLI

def aobake_command() -> list:
    exe = Path(sys.executable).with_name("aobake")
    if exe.is_file():
        return [str(exe)]
    found = shutil.which("aobake")
    return [found] if found else [sys.executable, "-m", "aobake"]


def run_cli(args, path: Path, rays: int | None, work: Path, tolerance: float | None = None,
            extra: tuple = ()) -> dict:
    out, report = work / "cli.npz", work / "cli.json"
    for f in (out, report):
        f.unlink(missing_ok=True)
    cmd = aobake_command() + [str(path), "--out", str(out), "--threads", str(args.threads),
                              "--quiet", "--report", str(report)]
    if rays is not None:
        cmd += ["--rays", str(rays)]
    if tolerance is not None:
        cmd += ["--tolerance", f"{tolerance:g}"]
    cmd += list(extra)
    wall = run_process(cmd, child_env(args), " ".join(cmd))
    rep = json.loads(report.read_text())
    with np.load(out) as data:
        ao = data["ao"].astype(np.float64)
    return {"seconds": wall, "rays_cast": int(rep["rays_cast"]), "ao": ao,
            "inner_s": float(rep["wall_time_s"]), "report": rep,
            "info": {"packet_width": packet_width_of(rep)}}


# --------------------------------------------------------------------------- Blender

def blender_python(args) -> list:
    return [args.blender_python or sys.executable, str(HERE / "_peers_blender.py")]


def blender_version(args):
    """bpy's version string, or (None, why not)."""
    try:
        proc = subprocess.run(blender_python(args) + ["--version"], capture_output=True,
                              text=True, timeout=300, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return None, str(exc)
    if proc.returncode != 0:
        tail = (proc.stderr.strip().splitlines() or ["?"])[-1]
        return None, tail
    return proc.stdout.strip().splitlines()[-1], None


def run_blender(args, path: Path, samples: int, work: Path, scene) -> dict:
    out = work / "blender.npz"
    out.unlink(missing_ok=True)
    cmd = blender_python(args) + [str(path), "--samples", str(samples), "--threads",
                                  str(args.threads), "--out", str(out)]
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    process_s = time.perf_counter() - start
    if proc.returncode != 0 or not out.is_file():
        tail = "\n".join(proc.stderr.strip().splitlines()[-5:])
        raise RuntimeError(f"Blender bake failed ({proc.returncode}): {tail}")
    with np.load(out) as data:
        co, ao_b, corners = data["co"], data["ao"], data["corners"]
        bake_s, import_s, bpy_s = (float(data[k]) for k in ("bake_s", "import_s", "bpy_import_s"))
    index = map_vertices(scene, co)
    ao = np.full(len(scene.vertices), np.nan)
    ao[index] = ao_b
    return {"seconds": bake_s, "rays_cast": int(corners.sum()) * samples, "ao": ao,
            "import_s": import_s, "bpy_import_s": bpy_s, "process_s": process_s,
            "corners": int(corners.sum())}


def map_vertices(scene, co: np.ndarray) -> np.ndarray:
    """(b,) int64: the aobake vertex of each of Blender's vertices.  Blender's OBJ importer
    keeps the file's order but drops unreferenced vertices; checked, else nearest point."""
    used = np.unique(scene.faces)
    if len(used) == len(co) and np.array_equal(scene.vertices[used].astype(np.float32), co):
        return used
    from scipy.spatial import cKDTree

    dist, index = cKDTree(scene.vertices).query(co.astype(np.float64))
    if dist.max() > 1e-5 * scene.diagonal:
        raise RuntimeError(f"Blender's vertices do not match the file's (off by {dist.max():g})")
    return index


# --------------------------------------------------------------------------- driver

def measure_mesh(args, cfg, path: Path, work: Path, available: dict, log) -> dict:
    scene = load_scene(path)
    V = scene.vertices
    log(f"\n## {path.name}: {len(V):,} vertices, {len(scene.faces):,} triangles, "
        f"{args.threads} threads")
    conventions = ["cosine"]
    if available.get("libigl") or available.get("blender"):
        conventions.append("uniform")
    refs = {w: reference(args, path, w, cfg["ref_rays"], work, log) for w in conventions}
    mask = valid_mask(refs["cosine"])
    ref_info = {}
    for w, ref in refs.items():
        se = float(np.sqrt(np.mean(ref["ao_stderr"][mask] ** 2)))
        ref_info[w] = {"rays": cfg["ref_rays"], "sampler": "sobol", "seed": REF_SEED,
                       "rms_stderr": se, "mean_ao": float(ref["ao"][mask].mean()),
                       "cache": ref["cache"], "cached": bool(ref["cached"])}
        log(f"reference ({w}): aobake sobol {cfg['ref_rays']} rays/vertex, seed {REF_SEED}, "
            f"{int(mask.sum()):,} vertices with a normal: rms stderr {se:.5f}, mean AO "
            f"{ref_info[w]['mean_ao']:.4f}" + (" (cached)" if ref["cached"] else
                                              f" ({float(ref['wall_s']):.0f} s)"))
    stop_at = min(cfg["targets"])
    rows: list = []

    def add(method, convention, param, res, load, seconds=None, note="", echo=True, **extra):
        err, bias, missing = errors(res["ao"], refs[convention]["ao"], mask)
        s = res["seconds"] if seconds is None else seconds
        if missing:
            note = (note + "; " if note else "") + f"{missing} vertices undefined, left out"
        width = res.get("info", {}).get("packet_width")
        row = {"method": method, "convention": convention, "param": param,
               "rays_cast": int(res["rays_cast"]), "seconds": s,
               "rays_per_s": res["rays_cast"] / s if s > 0 else None, "rmse": err, "bias": bias,
               "packet_width": width, "comparable": load["comparable"],
               "others_cores": [load[k]["others_cores"] for k in ("before", "during", "after")],
               "loadavg_1min": [load["before"]["loadavg_1min"][0],
                                load["after"]["loadavg_1min"][1]],
               "attempts": load["attempts"], "note": note, **extra}
        rows.append(row)
        if echo:
            mark = "" if load["comparable"] else "  NOT COMPARABLE (load)"
            log(f"  {method:28s} {param!s:>12s}  {s:8.3f} s  RMSE {err:.5f}  "
                f"mean err {bias:+.5f}  " + (f"{width} lanes  " if width else "")
                + "others " + "/".join(f"{o:.2f}" for o in row["others_cores"])
                + f"  {note}{mark}")
        return err

    def done(err):
        return err < stop_at and not args.all_counts

    def cli_rows(method, extra=()):
        for n in cfg["rays"]:
            res, load = _machine.watched(args, lambda: run_cli(args, path, n, work, extra=extra), log,
                                f"{method} {n}")
            if done(add(method, "cosine", n, res, load,
                        note=f"bake inside {res['inner_s']:.2f} s")):
                break

    if "cli" in available:
        cli_rows("aobake CLI")
    if "replicates" in available:
        cli_rows("aobake CLI --replicates 2", ("--replicates", "2"))
    if "library" in available or "bare" in available:
        for n in cfg["rays"]:
            err = None
            if "library" in available:
                res, load = _machine.watched(args, lambda: run_runner(args, "library", path, n, work),
                                    log, f"library {n}")
                err = add("aobake.bake()", "cosine", n, res, load,
                          note=f"process {res['process_s']:.2f} s")
            if "bare" in available:
                res, load = _machine.watched(args, lambda: run_runner(args, "bare", path, n, work), log,
                                    f"bare {n}")
                build_s, trace_s = res["info"]["build_s"], res["info"]["trace_s"]
                e1 = add("bare embreex, trace", "cosine", n, res, load, seconds=trace_s,
                         note="rays pre-generated, not timed")
                add("bare embreex, build+trace", "cosine", n, res, load,
                    seconds=build_s + trace_s, note=f"build {build_s:.3f} s")
                err = e1 if err is None else err
            if done(err):
                break
    if "tolerance" in available:
        for e in cfg["tolerances"]:
            res, load = _machine.watched(args, lambda: run_cli(args, path, args.pilot, work, tolerance=e),
                                log, f"tolerance {e:g}")
            t = res["report"].get("tolerance", {})
            add("aobake CLI --tolerance", "cosine", f"E={e:g}", res, load,
                note=f"{res['rays_cast'] / int(mask.sum()):.0f} rays/vertex; met "
                     f"{t.get('points_met', '?')}, missed {t.get('points_missed', '?')}, "
                     f"capped {t.get('points_capped', '?')}")

    def peer_libigl():
        for n in cfg["rays"]:
            res, load = _machine.watched(args, lambda: run_runner(args, "libigl", path, n, work), log,
                                f"libigl {n}")
            if done(add("libigl (embree)", "uniform", n, res, load,
                        note=f"process {res['process_s']:.2f} s")):
                break

    def peer_open3d():
        for n in cfg["rays"]:
            res, load = _machine.watched(args, lambda: run_runner(args, "open3d", path, n, work), log,
                                f"open3d {n}")
            if done(add("Open3D RaycastingScene", "cosine", n, res, load,
                        note=f"numpy ray generation {res['info']['gen_s']:.2f} s of it")):
                break

    def peer_blender():
        probes = []
        for n in cfg["blender_rays"]:
            res, load = _machine.watched(args, lambda: run_blender(args, path, n, work, scene), log,
                                f"blender {n}")
            errs = {w: errors(res["ao"], refs[w]["ao"], mask)[0] for w in refs}
            probes.append((n, res, load, errs))
            log(f"  {'Blender Cycles':28s} {n:>12d}  {res['seconds']:8.3f} s  "
                + "  ".join(f"RMSE vs {w} {e:.5f}" for w, e in errs.items())
                + ("" if load["comparable"] else "  NOT COMPARABLE (load)"))
            if min(errs.values()) < stop_at and not args.all_counts:
                break
        # Its convention: the reference it is closer to at its highest sample count.
        last = probes[-1][3]
        matched = min(last, key=last.get)
        for n, res, load, errs in probes:
            others = ", ".join(f"vs {w} {e:.5f}" for w, e in errs.items() if w != matched)
            add("Blender Cycles", matched, n, res, load,
                note=f"samples/corner, {res['corners']:,} corners; import "
                     f"{res['import_s']:.2f} s, import bpy {res['bpy_import_s']:.2f} s, "
                     f"process {res['process_s']:.1f} s; RMSE {others}",
                rmse_by_convention=errs, echo=False)
        return {"convention": matched, "rmse_at_highest": last, "samples_at_highest": probes[-1][0]}

    # A peer that fails mid-run is reported and left out; aobake's own rows are not guarded.
    blender, failures = None, {}
    for name, run in (("libigl", peer_libigl), ("open3d", peer_open3d),
                      ("blender", peer_blender)):
        if name not in available:
            continue
        try:
            found = run()
        except Exception as exc:  # noqa: BLE001 - any failure of a peer skips that peer
            failures[name] = f"{type(exc).__name__}: {exc}"
            log(f"  {name} failed, its rows are left out: {failures[name]}")
            continue
        if name == "blender":
            blender = found

    methods = []
    for row in rows:
        if row["method"] not in methods:
            methods.append(row["method"])
    summary = []
    cli_times = None
    for m in methods:
        pts = [(r["rays_cast"], r["seconds"], r["rmse"], r["comparable"]) for r in rows
               if r["method"] == m]
        times = [time_to(pts, tgt) for tgt in cfg["targets"]]
        if m == "aobake CLI":
            cli_times = times
        summary.append({"method": m, "convention": next(r["convention"] for r in rows
                                                          if r["method"] == m),
                        "time_to": times})
    for s in summary:
        s["vs_cli"] = ([ratio(t, c) for t, c in zip(s["time_to"], cli_times)]
                       if cli_times else [(None, None, True)] * len(cfg["targets"]))
    return {"mesh": str(path), "name": path.name, "vertices": len(V),
            "vertices_with_normal": int(mask.sum()), "triangles": len(scene.faces),
            "references": ref_info, "rows": rows, "summary": summary, "blender": blender,
            "failures": failures}


def machine_line(machine: dict) -> str:
    c = machine["cpu"]
    has512 = "avx512f" in c["vector"]
    return (f"CPU: **{c['model']}** ({c['logical_cpus']} logical CPUs), vector extensions "
            f"{' '.join(c['vector']) or 'none reported'}"
            + ("" if has512 else " (no AVX-512)")
            + f"; Embree's native packet width {machine['embree_native_width']}; aobake's "
            f"packet width {machine['packet_width']} ({machine['packet_width_by']}); other "
            f"work above {machine['threshold_cores']} cores marks a row not comparable")


def markdown(result: dict, targets, machine: dict) -> str:
    title = (f"### {result['name']}: {result['vertices']:,} vertices "
             f"({result['vertices_with_normal']:,} with a normal), {result['triangles']:,} "
             f"triangles")
    lines = [title, "", machine_line(machine), ""]
    for w, ref in result["references"].items():
        lines.append(f"- reference, {w}: aobake sobol {ref['rays']} rays/vertex, seed "
                     f"{ref['seed']}: rms stderr **{ref['rms_stderr']:.5f}**")
    if result["blender"]:
        b = result["blender"]
        lines.append(f"- Blender's AO matches the **{b['convention']}** reference (at "
                     f"{b['samples_at_highest']} samples: "
                     + ", ".join(f"RMSE vs {w} {e:.5f}" for w, e in b["rmse_at_highest"].items())
                     + ")")
    for name, why in result["failures"].items():
        lines.append(f"- {name} failed and is left out: {why}")
    widths = sorted({r["packet_width"] for r in result["rows"] if r["packet_width"]})
    lines.append(f"- packet width of the aobake rows: {', '.join(map(str, widths)) or '—'}")
    header = ("| method | AO | rays/vertex | rays cast | seconds | Mrays/s | RMSE | mean err "
              "| other work before / during / after (cores) | notes |")
    lines += ["", header, "|---|---|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        rps = "—" if r["rays_per_s"] is None else f"{r['rays_per_s'] / 1e6:.2f}"
        secs = f"{r['seconds']:.3f}" if r["comparable"] else \
            f"not comparable (load): {r['seconds']:.3f}"
        tries = len(r["attempts"])
        note = r["note"] + (f"; attempt {tries} of {tries}" if tries > 1 else "")
        lines.append(f"| {r['method']} | {r['convention']} | {r['param']} | {r['rays_cast']:,} "
                     f"| {secs} | {rps} | {r['rmse']:.5f} | {r['bias']:+.5f} | "
                     + " / ".join(f"{o:.2f}" for o in r["others_cores"]) + f" | {note} |")
    head = " | ".join(f"s to RMSE {t:g}" for t in targets)
    vs = " | ".join(f"× aobake CLI @{t:g}" for t in targets)
    lines += ["", f"| method | AO | {head} | {vs} |",
              "|---|---|" + "---|" * (2 * len(targets))]
    for s in result["summary"]:
        cells = [fmt_bound(*t) for t in s["time_to"]] + [fmt_bound(*v) for v in s["vs_cli"]]
        lines.append(f"| {s['method']} | {s['convention']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def jsonable(result: dict, targets) -> dict:
    out = dict(result)
    out["summary"] = [{"method": s["method"], "convention": s["convention"],
                       **{f"seconds_to_rmse_{t:g}": {"seconds": v, "bound": b, "comparable": c}
                          for t, (v, b, c) in zip(targets, s["time_to"])},
                       **{f"vs_aobake_cli_at_{t:g}": {"ratio": v, "bound": b, "comparable": c}
                          for t, (v, b, c) in zip(targets, s["vs_cli"])}}
                      for s in result["summary"]]
    return out


def parse_list(kind):
    return lambda text: tuple(kind(x) for x in text.replace(",", " ").split())


def aobake_packet_width(args) -> dict:
    """Embree's native packet width here and the width aobake's processes will use, asked of
    a process of their own (so this one never opens Embree)."""
    code = ("import json; from aobake.backends import native; b = native.binding(); "
            "w = native.packet_width(b[1]) if b else (None, 'embreex'); "
            "print(json.dumps([native.native_width(), w[0], w[1]]))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=child_env(args), check=False)
    if proc.returncode != 0:
        sys.exit(f"aobake does not start here: {proc.stderr.strip().splitlines()[-1:]}")
    native_w, width, by = json.loads(proc.stdout.strip().splitlines()[-1])
    return {"embree_native_width": native_w, "packet_width": width, "packet_width_by": by}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n".join(__doc__.splitlines()[2:7]))
    parser.add_argument("--meshes", nargs="+", default=list(MESHES),
                        help=f"names ({', '.join(MESHES)}: files in --mesh-dir) or paths")
    parser.add_argument("--mesh-dir", type=Path, default=DEFAULT_MESH_DIR)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: first mesh only, tiny ray counts, 1024-ray reference")
    parser.add_argument("--skip", action="append", default=[], metavar="PEER",
                        help=f"leave out a row kind (repeatable or comma-separated): "
                             f"{', '.join(PEERS)}")
    parser.add_argument("--rays", type=parse_list(int), help="ray counts (default 16 .. 4096)")
    parser.add_argument("--blender-rays", type=parse_list(int),
                        help="Blender's samples per corner (default 16 64 256 512)")
    parser.add_argument("--tolerances", type=parse_list(float),
                        help="--tolerance values (default 0.02 0.01 0.005)")
    parser.add_argument("--targets", type=parse_list(float), help="RMSE targets (0.01 0.005)")
    parser.add_argument("--ref-rays", type=int, help="reference rays per vertex (16384)")
    parser.add_argument("--pilot", type=int, default=None,
                        help="--rays given to the --tolerance runs (default: the CLI's own)")
    parser.add_argument("--all-counts", action="store_true",
                        help="do not stop a method once it is below the smallest target")
    parser.add_argument("--packet-width", type=int, choices=[1, 4, 8, 16],
                        help="AOBAKE_PACKET_WIDTH for every aobake process (default: "
                             "aobake's choice for this CPU)")
    parser.add_argument("--threshold", type=float, default=_machine.LOAD_THRESHOLD,
                        help="other work (cores) above which a row is not comparable (0.3)")
    parser.add_argument("--wait", type=float, default=60.0,
                        help="seconds to wait for other work below --threshold before a row")
    parser.add_argument("--retries", type=int, default=2,
                        help="times a row under load is run again (default 2)")
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()),
                        help="where the references are cached (default /tmp)")
    parser.add_argument("--fresh-reference", action="store_true", help="re-bake the references")
    parser.add_argument("--blender-python", help="interpreter with bpy (default: this one)")
    parser.add_argument("--json", type=Path, help="also write the results here")
    args = parser.parse_args(argv)

    cfg = dict(QUICK if args.quick else FULL)
    for key in ("rays", "blender_rays", "tolerances", "targets", "ref_rays"):
        if getattr(args, key) is not None:
            cfg[key] = getattr(args, key)
    skip = {p.strip() for s in args.skip for p in s.split(",") if p.strip()}
    unknown = skip - set(PEERS)
    if unknown:
        parser.error(f"--skip: unknown {', '.join(sorted(unknown))} "
                     f"(choose from {', '.join(PEERS)})")
    # The CLI runs as a user's install runs it: with its modules' bytecode, which `pip
    # install .` compiles.  An editable checkout under PYTHONDONTWRITEBYTECODE=1 (set on the
    # machines this was measured on) has none and would compile every module of aobake in
    # every CLI process: ~40 ms, measured.
    import compileall

    compileall.compile_dir(str(Path(aobake.__file__).parent), quiet=1)

    paths = []
    for m in args.meshes[:1] if args.quick else args.meshes:
        p = args.mesh_dir / MESHES[m] if m in MESHES else Path(m)
        if not p.is_file():
            sys.exit(f"{p}: not found (the benchmark meshes live in ../shared/meshes)")
        paths.append(p)

    def log(text):
        print(text, flush=True)

    versions = {"python": platform.python_version(), "aobake": pkg_version("aobake"),
                "embreex": pkg_version("embreex"), "numpy": np.__version__}
    available = {p: True for p in PEERS if p not in skip}
    for peer, module, hint in (("libigl", "igl.embree", "pip install libigl"),
                               ("open3d", "open3d", "pip install open3d; open3d needs "
                                                    "libusb-1.0-0")):
        if peer not in available:
            continue
        # imported in a process of its own: this one stays small and never starts a pool
        proc = subprocess.run([sys.executable, "-c", f"import {module}"], capture_output=True,
                              text=True, check=False)
        if proc.returncode != 0:
            why = (proc.stderr.strip().splitlines() or ["?"])[-1]
            log(f"skipping {peer}: {why} ({hint})")
            del available[peer]
        else:
            versions[peer] = pkg_version(peer)
    if "blender" in available:
        found, why = blender_version(args)
        if found is None:
            log(f"skipping blender: bpy does not import ({why}); pip install bpy==5.0.1 "
                f"(Python 3.11), or --blender-python PATH")
            del available["blender"]
        else:
            versions["bpy"] = found
    machine = {"cpu": _machine.cpu(), "platform": platform.platform(),
               "threshold_cores": args.threshold, **aobake_packet_width(args)}
    log(f"# aobake vs peers ({'quick smoke run' if args.quick else 'full run'})")
    log(machine_line(machine))
    log(f"versions: {json.dumps(versions)}; threads {args.threads}; "
        f"rows: {', '.join(available)}; RMSE targets {', '.join(f'{t:g}' for t in cfg['targets'])}")

    results = []
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench_peers_") as tmp:
        for p in paths:
            results.append(measure_mesh(args, cfg, p, Path(tmp), available, log))
    for r in results:
        log("\n" + markdown(r, cfg["targets"], machine))
    under = sum(not row["comparable"] for r in results for row in r["rows"])
    log(f"\n(total {time.perf_counter() - start:.0f} s; {under} row(s) not comparable (load))")
    if args.json:
        payload = {"versions": versions, "threads": args.threads, "quick": args.quick,
                   "config": {k: list(v) if isinstance(v, tuple) else v for k, v in cfg.items()},
                   "machine": machine, "packet_width_forced": args.packet_width,
                   "meshes": [jsonable(r, cfg["targets"]) for r in results]}
        args.json.write_text(json.dumps(payload, indent=1))
        log(f"wrote {args.json}")


if __name__ == "__main__":
    main()
