"""Side by side: aobake and its peers, in seconds to the same error, on real meshes.

    pip install -e '.[peers]'            # libigl, open3d, matplotlib
    pip install --no-deps bpy==5.0.1     # Blender (Python 3.11 wheel; see below)
    python benchmarks/bench_peers.py [--meshes bunny ogre] [--threads 2] [--json peers.json]
        [--skip PEER ...] [--quick]

Installing: bpy 5.0.1 pins numpy<2 (which would move numpy to 1.26 and OpenImageIO to 3.0),
so it is not in the extra: ``pip install --no-deps bpy==5.0.1`` keeps numpy 2 (it bakes under
numpy 2; only its audio module fails to load, harmlessly), or put bpy in a venv of its own
and pass ``--blender-python``.  Open3D needs libusb
(``apt-get install libusb-1.0-0``).  A peer that does not import is skipped with a message.

Every method bakes per-vertex AO of every vertex of each mesh (default: the Stanford bunny
and the ogre from ../shared/meshes), max distance infinite, on ``--threads`` threads, at
several ray counts, and is scored by its RMSE against a shared reference over the vertices
with a normal (the bunny has 1,113 unreferenced vertices, baked as "no information").

The reference, one per mesh and AO convention: aobake, ``sobol``, 16,384 rays per vertex,
with another seed than the runs (with the same seed it would share their randomisation and
their errors would look smaller than they are).  Its own rms reported stderr is printed: a
measured RMSE r includes it in quadrature, the method's own error is sqrt(r^2 - ref^2).
References are cached in ``--cache`` (default /tmp) as NPZ, keyed by mesh file (path,
size, mtime) + convention + rays + seed, so reruns skip them.

Rows (``--skip`` takes the names in brackets):

* [cli] the aobake CLI as a subprocess, ``aobake MESH --out X.npz --rays N --threads T
  --quiet --report r.json``: the whole process (interpreter start, import, file read, bake,
  writing); rays cast from the report, error from the NPZ.
* [replicates] the CLI as [cli] with ``--replicates 2``: the same sampler in two
  replicates (a more accurate value for the rays; the stderr on one degree of freedom).
* [library] ``aobake.bake(path, rays=N, threads=T)``, file read included.
* [tolerance] the CLI with ``--tolerance E`` (default pilot, the CLI's ``--rays`` default;
  ``--pilot`` to change it): rays cast (pilot + final) from its report.
* [bare] a bare embreex loop (as benchmarks/bench_throughput.py): the rays of the library
  run at the same N, generated beforehand by aobake's own generator (not timed), traced
  through ``EmbreeScene.run(query="OCCLUDED")`` on T threads in the same chunks; two rows:
  the tracing alone, and build + tracing.  AO = the unoccluded fraction (cosine-distributed
  rays).  It shows what is left to gain below aobake.
* [libigl] ``igl.embree.ambient_occlusion(V, F, V, N, n)`` (whole call: it builds its Embree
  scene each time), scored against the **uniform** reference: libigl averages visibility over
  uniformly distributed hemisphere directions and returns the occluded fraction, so
  AO = 1 - result.  Its directions are one stratified-random set shared by every vertex
  (flipped into each hemisphere), traced with an absolute tnear of 1e-4 scene units; its
  thread pool is sized by IGL_NUM_THREADS, set to T here before libigl is first used.  It is
  handed all vertices, the unreferenced ones too (its call as documented), and they count
  in its rays.
* [open3d] ``o3d.t.geometry.RaycastingScene.test_occlusions`` on rays generated here in
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

Per row: seconds, rays/s (rays cast / seconds), RMSE; per method the time to reach RMSE
0.01 and 0.005 (``--targets``), interpolated log-log between the two measured ray counts
that bracket it ("--" when not reached, "<= t" when the first count already reaches it),
and its ratio to the aobake CLI's time (> 1: slower than the CLI).  A method stops at the
first count whose RMSE is below the smallest target (``--all-counts`` runs them all).
Markdown tables per mesh on stdout; ``--json PATH`` writes the same numbers.

``--quick`` is a smoke run (under a minute): one mesh, three tiny ray counts, a 1,024-ray
reference, targets 0.05 / 0.04.  The timings mean something only on an otherwise idle
machine.
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
from concurrent.futures import ThreadPoolExecutor
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import aobake  # noqa: E402
from aobake.settings import DEFAULT_RAY_OFFSET, BakeConfig  # noqa: E402
from aobake.scene import load_scene  # noqa: E402
from aobake.targets.vertices import vertex_sizes  # noqa: E402
from aobake.occluders import build as build_occluders  # noqa: E402
from aobake.trace import DEFAULT_CHUNK_RAYS, Tracer, morton_order, point_offsets  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_MESH_DIR = HERE.parents[1] / "shared" / "meshes"
MESHES = {"bunny": "stanford-bunny.obj", "ogre": "ogre.obj"}
PEERS = ("cli", "replicates", "library", "tolerance", "bare", "libigl", "open3d", "blender")

FULL = {"rays": (16, 32, 64, 128, 256, 512, 1024, 2048, 4096),
        "blender_rays": (16, 64, 256, 512),
        "tolerances": (0.02, 0.01, 0.005),
        "targets": (0.01, 0.005),
        "ref_rays": 16384}
QUICK = {"rays": (16, 32, 64), "blender_rays": (4, 8, 16), "tolerances": (0.05, 0.03),
         "targets": (0.05, 0.04), "ref_rays": 1024}

#: seed of the references; the runs use aobake's default (0)
REF_SEED = 987654321
#: rays per Open3D call (a chunk of whole vertices), and per pre-generated batch of the
#: bare loop (bounds their memory: 24 bytes a ray)
OPEN3D_CHUNK_RAYS = 1 << 21
BARE_BATCH_RAYS = 1 << 24


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
    """Seconds to reach RMSE ``target`` from measured (rays, seconds, rmse) points, sorted
    by rays: log-log interpolation between the first bracketing pair.  Returns
    (seconds, bound) with bound '=' (interpolated), '<=' (the first point is already below:
    its time is an upper bound) or None (never reached: seconds None)."""
    pts = sorted(p for p in points if p[2] > 0 and p[1] > 0)
    if not pts:
        return None, None
    if pts[0][2] <= target:
        return pts[0][1], "<="
    for (_, ta, ea), (_, tb, eb) in itertools.pairwise(pts):
        if ea > target >= eb:
            f = (math.log(target) - math.log(ea)) / (math.log(eb) - math.log(ea))
            return math.exp((1 - f) * math.log(ta) + f * math.log(tb)), "="
    return None, None


def ratio(mine, cli):
    """(value, bound) of mine / cli for two time_to() results."""
    (tm, bm), (tc, bc) = mine, cli
    if tm is None or tc is None:
        return None, None
    if bm == "=" and bc == "=":
        return tm / tc, "="
    if bm == "<=" and bc == "=":
        return tm / tc, "<="
    if bm == "=" and bc == "<=":
        return tm / tc, ">="
    return None, None


def fmt_bound(value, bound, digits=3) -> str:
    if value is None:
        return "—"
    text = f"{value:.{digits}g}" if value < 1000 else f"{value:.0f}"
    return text if bound == "=" else f"{bound} {text}"


def file_key(path: Path) -> str:
    st = path.stat()
    return hashlib.sha1(f"{path.resolve()}|{st.st_size}|{st.st_mtime_ns}".encode()).hexdigest()[:10]


def valid_mask(ref: dict) -> np.ndarray:
    return ref["rays"] > 0


# --------------------------------------------------------------------------- reference

def reference(path: Path, weighting: str, rays: int, threads: int, cache: Path, fresh: bool,
              log) -> dict:
    """aobake sobol at ``rays`` rays per vertex, seed REF_SEED: ao, ao_stderr, rays per vertex."""
    name = f"aobake_peers_ref_{path.stem}_{weighting}_{rays}_{REF_SEED}_{file_key(path)}.npz"
    cached = cache / name
    if cached.is_file() and not fresh:
        with np.load(cached) as data:
            out = {k: data[k] for k in data.files}
        out["cache"], out["cached"] = str(cached), True
        return out
    log(f"  baking the {weighting} reference ({rays} rays/vertex; cached as {cached}) ...")
    start = time.perf_counter()
    res = aobake.bake(str(path), rays=rays, sampler="sobol", seed=REF_SEED, weighting=weighting,
                      threads=threads)
    wall = time.perf_counter() - start
    out = {"ao": res.ao.astype(np.float64), "ao_stderr": res.ao_stderr.astype(np.float64),
           "rays": res.rays.astype(np.int64), "wall_s": np.float64(wall)}
    cache.mkdir(parents=True, exist_ok=True)
    tmp = cached.with_suffix(".tmp.npz")
    np.savez(tmp, **out)
    os.replace(tmp, cached)
    out["cache"], out["cached"] = str(cached), False
    return out


# --------------------------------------------------------------------------- aobake

def aobake_command() -> list:
    exe = Path(sys.executable).with_name("aobake")
    if exe.is_file():
        return [str(exe)]
    found = shutil.which("aobake")
    return [found] if found else [sys.executable, "-m", "aobake"]


def run_cli(path: Path, rays: int | None, threads: int, work: Path,
            tolerance: float | None = None, extra: tuple = ()) -> dict:
    out, report = work / "cli.npz", work / "cli.json"
    for f in (out, report):
        f.unlink(missing_ok=True)
    cmd = aobake_command() + [str(path), "--out", str(out), "--threads", str(threads), "--quiet",
                              "--report", str(report)]
    if rays is not None:
        cmd += ["--rays", str(rays)]
    if tolerance is not None:
        cmd += ["--tolerance", f"{tolerance:g}"]
    cmd += list(extra)
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}: {proc.stderr.strip()}")
    rep = json.loads(report.read_text())
    with np.load(out) as data:
        ao = data["ao"].astype(np.float64)
    return {"seconds": wall, "rays_cast": int(rep["rays_cast"]), "ao": ao,
            "inner_s": float(rep["wall_time_s"]), "report": rep}


def run_library(path: Path, rays: int, threads: int) -> dict:
    start = time.perf_counter()
    res = aobake.bake(str(path), rays=rays, threads=threads)
    wall = time.perf_counter() - start
    return {"seconds": wall, "rays_cast": int(res.report["rays_cast"]),
            "ao": res.ao.astype(np.float64)}


def run_bare(scene, rays: int, threads: int) -> dict:
    """bench_throughput's bare loop on the library run's rays, keeping the answers.

    The points are the distinct (position, normal) pairs with a normal, as aobake traces
    them; each chunk's rays come from aobake's generator and are made before the clock
    starts (in batches of BARE_BATCH_RAYS, whose generation is not timed either)."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    config = BakeConfig(rays=rays)
    tracer = Tracer(scene, config, build_occluders(scene, config))
    V, N = scene.vertices, scene.vertex_normals
    keys = np.ascontiguousarray(np.concatenate([V, N], axis=1))
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    good = np.linalg.norm(N[first], axis=1) > 0.5
    valid = first[good]
    sizes = vertex_sizes(scene)[valid]
    points, normals, ids = V[valid], N[valid], valid.astype(np.int64)
    per_point = tracer.samples.rays
    per_chunk = max(1, DEFAULT_CHUNK_RAYS // per_point)
    order = morton_order(points)
    chunks = [order[s:s + per_chunk] for s in range(0, len(order), per_chunk)]

    vertices = (scene.vertices - tracer.center).astype(np.float32)
    faces = scene.faces.astype(np.int32)
    tmax = np.float32(1e37)
    start = time.perf_counter()
    emb = rtcore_scene.EmbreeScene()
    TriangleMesh(emb, vertices, faces)
    emb.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32), query="OCCLUDED")  # commit
    build_s = time.perf_counter() - start

    def make(sel):
        rebased = points[sel] - tracer.center
        offsets = point_offsets(rebased, sizes[sel], tracer.config.ray_offset)
        origins = rebased + offsets[:, None] * normals[sel]
        r = tracer.generator.rays(origins, normals[sel], ids[sel])
        return r.origins, r.directions.reshape(-1, 3).copy()

    def trace(chunk):
        o, d = chunk
        return emb.run(o, d, dists=np.full(len(o), tmax, np.float32), query="OCCLUDED")

    ao_points = np.empty(len(points))
    trace_s, total, i = 0.0, 0, 0
    per_batch = max(1, BARE_BATCH_RAYS // (per_chunk * per_point))
    with ThreadPoolExecutor(threads) as pool:
        while i < len(chunks):
            batch = chunks[i:i + per_batch]
            made = [make(sel) for sel in batch]
            clock = time.perf_counter()
            hits = list(pool.map(trace, made))
            trace_s += time.perf_counter() - clock
            for sel, (o, _), hit in zip(batch, made, hits):
                total += len(o)
                occluded = (hit >= 0).reshape(len(sel), -1)
                ao_points[sel] = 1.0 - occluded.mean(axis=1)
            i += per_batch
    per_unique = np.full(len(first), np.nan)
    per_unique[np.flatnonzero(good)] = ao_points
    return {"rays_cast": total, "build_s": build_s, "trace_s": trace_s,
            "ao": per_unique[inverse]}


# --------------------------------------------------------------------------- peers

def run_libigl(scene, rays: int) -> dict:
    import igl.embree

    V = np.ascontiguousarray(scene.vertices, dtype=np.float64)
    F = np.ascontiguousarray(scene.faces, dtype=np.int64)
    N = np.ascontiguousarray(scene.vertex_normals, dtype=np.float64)
    start = time.perf_counter()
    occluded = igl.embree.ambient_occlusion(V, F, V, N, rays)
    wall = time.perf_counter() - start
    return {"seconds": wall, "rays_cast": len(V) * rays, "ao": 1.0 - np.asarray(occluded)}


def hemisphere_frames(n: np.ndarray):
    """(k, 3) unit normals -> tangents, bitangents (k, 3) (Duff et al. 2017, branchless)."""
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    s = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return t, s


def run_open3d(scene, rays: int, threads: int, origins: np.ndarray, normals: np.ndarray,
               seed: int = 0) -> dict:
    """origins, normals (k, 3) float64: the vertices with a normal, already lifted."""
    import open3d as o3d

    gen_s = 0.0
    start = time.perf_counter()
    rs = o3d.t.geometry.RaycastingScene(nthreads=threads)
    rs.add_triangles(o3d.core.Tensor(scene.vertices.astype(np.float32)),
                     o3d.core.Tensor(scene.faces.astype(np.uint32)))
    rng = np.random.default_rng(seed)
    ao = np.empty(len(origins))
    per_chunk = max(1, OPEN3D_CHUNK_RAYS // rays)
    for s in range(0, len(origins), per_chunk):
        clock = time.perf_counter()
        o, n = origins[s:s + per_chunk], normals[s:s + per_chunk]
        k = len(o)
        u = rng.random((k, rays, 2))
        r = np.sqrt(u[..., 0])
        phi = 2.0 * np.pi * u[..., 1]
        x, y, z = r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - u[..., 0])
        t, b = hemisphere_frames(n)
        d = x[..., None] * t[:, None] + y[..., None] * b[:, None] + z[..., None] * n[:, None]
        block = np.empty((k, rays, 6), dtype=np.float32)
        block[..., :3] = o[:, None]
        block[..., 3:] = d
        gen_s += time.perf_counter() - clock
        hit = rs.test_occlusions(o3d.core.Tensor(block.reshape(-1, 6)), nthreads=threads)
        ao[s:s + per_chunk] = 1.0 - hit.numpy().reshape(k, rays).mean(axis=1)
    wall = time.perf_counter() - start
    return {"seconds": wall, "rays_cast": len(origins) * rays, "ao": ao, "gen_s": gen_s}


def open3d_rays_setup(scene):
    """The vertices with a normal, lifted along it by aobake's offset rule (untimed)."""
    N = scene.vertex_normals
    has = np.linalg.norm(N, axis=1) > 0.5
    offsets = point_offsets(scene.vertices[has], vertex_sizes(scene)[has], DEFAULT_RAY_OFFSET)
    return has, scene.vertices[has] + offsets[:, None] * N[has], N[has]


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
    refs = {w: reference(path, w, cfg["ref_rays"], args.threads, args.cache,
                         args.fresh_reference, log) for w in conventions}
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

    def add(method, convention, param, res, seconds=None, note="", echo=True, **extra):
        err, bias, missing = errors(res["ao"], refs[convention]["ao"], mask)
        s = res["seconds"] if seconds is None else seconds
        if missing:
            note = (note + "; " if note else "") + f"{missing} vertices undefined, left out"
        row = {"method": method, "convention": convention, "param": param,
               "rays_cast": int(res["rays_cast"]), "seconds": s,
               "rays_per_s": res["rays_cast"] / s if s > 0 else None, "rmse": err, "bias": bias,
               "note": note, **extra}
        rows.append(row)
        if echo:
            log(f"  {method:28s} {param!s:>12s}  {s:8.3f} s  RMSE {err:.5f}  "
                f"mean err {bias:+.5f}  {note}")
        return err

    def done(err):
        return err < stop_at and not args.all_counts

    if "cli" in available:
        for n in cfg["rays"]:
            res = run_cli(path, n, args.threads, work)
            if done(add("aobake CLI", "cosine", n, res,
                        note=f"bake inside {res['inner_s']:.2f} s")):
                break
    if "replicates" in available:
        for n in cfg["rays"]:
            res = run_cli(path, n, args.threads, work, extra=("--replicates", "2"))
            if done(add("aobake CLI --replicates 2", "cosine", n, res,
                        note=f"bake inside {res['inner_s']:.2f} s")):
                break
    if "library" in available or "bare" in available:
        for n in cfg["rays"]:
            err = None
            if "library" in available:
                err = add("aobake.bake()", "cosine", n, run_library(path, n, args.threads))
            if "bare" in available:
                res = run_bare(scene, n, args.threads)
                e1 = add("bare embreex, trace", "cosine", n, res, seconds=res["trace_s"],
                         note="rays pre-generated, not timed")
                add("bare embreex, build+trace", "cosine", n, res,
                    seconds=res["build_s"] + res["trace_s"], note=f"build {res['build_s']:.3f} s")
                err = e1 if err is None else err
            if done(err):
                break
    if "tolerance" in available:
        for e in cfg["tolerances"]:
            res = run_cli(path, args.pilot, args.threads, work, tolerance=e)
            t = res["report"].get("tolerance", {})
            add("aobake CLI --tolerance", "cosine", f"E={e:g}", res,
                note=f"{res['rays_cast'] / int(mask.sum()):.0f} rays/vertex; met "
                     f"{t.get('points_met', '?')}, missed {t.get('points_missed', '?')}, "
                     f"capped {t.get('points_capped', '?')}")
    def peer_libigl():
        for n in cfg["rays"]:
            if done(add("libigl (embree)", "uniform", n, run_libigl(scene, n))):
                break

    def peer_open3d():
        has, origins, normals = open3d_rays_setup(scene)
        for n in cfg["rays"]:
            res = run_open3d(scene, n, args.threads, origins, normals)
            ao = np.full(len(V), np.nan)
            ao[has] = res["ao"]
            res["ao"] = ao
            if done(add("Open3D RaycastingScene", "cosine", n, res,
                        note=f"numpy ray generation {res['gen_s']:.2f} s of it")):
                break

    def peer_blender():
        probes = []
        for n in cfg["blender_rays"]:
            res = run_blender(args, path, n, work, scene)
            errs = {w: errors(res["ao"], refs[w]["ao"], mask)[0] for w in refs}
            probes.append((n, res, errs))
            log(f"  {'Blender Cycles':28s} {n:>12d}  {res['seconds']:8.3f} s  "
                + "  ".join(f"RMSE vs {w} {e:.5f}" for w, e in errs.items()))
            if min(errs.values()) < stop_at and not args.all_counts:
                break
        # Its convention: the reference it is closer to at its highest sample count.
        last = probes[-1][2]
        matched = min(last, key=last.get)
        for n, res, errs in probes:
            others = ", ".join(f"vs {w} {e:.5f}" for w, e in errs.items() if w != matched)
            add("Blender Cycles", matched, n, res,
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
        pts = [(r["rays_cast"], r["seconds"], r["rmse"]) for r in rows if r["method"] == m]
        times = [time_to(pts, tgt) for tgt in cfg["targets"]]
        if m == "aobake CLI":
            cli_times = times
        summary.append({"method": m, "convention": next(r["convention"] for r in rows
                                                          if r["method"] == m),
                        "time_to": times})
    for s in summary:
        s["vs_cli"] = ([ratio(t, c) for t, c in zip(s["time_to"], cli_times)]
                       if cli_times else [(None, None)] * len(cfg["targets"]))
    return {"mesh": str(path), "name": path.name, "vertices": len(V),
            "vertices_with_normal": int(mask.sum()), "triangles": len(scene.faces),
            "references": ref_info, "rows": rows, "summary": summary, "blender": blender,
            "failures": failures}


def markdown(result: dict, targets) -> str:
    title = (f"### {result['name']}: {result['vertices']:,} vertices "
             f"({result['vertices_with_normal']:,} with a normal), {result['triangles']:,} "
             f"triangles")
    lines = [title, ""]
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
    header = "| method | AO | rays/vertex | rays cast | seconds | Mrays/s | RMSE | mean err | notes |"
    lines += ["", header, "|---|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        rps = "—" if r["rays_per_s"] is None else f"{r['rays_per_s'] / 1e6:.2f}"
        lines.append(f"| {r['method']} | {r['convention']} | {r['param']} | {r['rays_cast']:,} "
                     f"| {r['seconds']:.3f} | {rps} | {r['rmse']:.5f} | {r['bias']:+.5f} "
                     f"| {r['note']} |")
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
                       **{f"seconds_to_rmse_{t:g}": {"seconds": v, "bound": b}
                          for t, (v, b) in zip(targets, s["time_to"])},
                       **{f"vs_aobake_cli_at_{t:g}": {"ratio": v, "bound": b}
                          for t, (v, b) in zip(targets, s["vs_cli"])}}
                      for s in result["summary"]]
    return out


def parse_list(kind):
    return lambda text: tuple(kind(x) for x in text.replace(",", " ").split())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n".join(__doc__.splitlines()[2:6]))
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
    # libigl reads IGL_NUM_THREADS once, when it first sizes its pool: set before any use.
    os.environ["IGL_NUM_THREADS"] = str(args.threads)
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
    if "libigl" in available:
        try:
            import igl.embree  # noqa: F401
            versions["libigl"] = pkg_version("libigl")
        except ImportError as exc:
            log(f"skipping libigl: {exc} (pip install libigl)")
            del available["libigl"]
    if "open3d" in available:
        try:
            import open3d  # noqa: F401
            versions["open3d"] = pkg_version("open3d")
        except ImportError as exc:  # e.g. libusb-1.0.so.0 missing: apt-get install libusb-1.0-0
            log(f"skipping open3d: {exc} (pip install open3d)")
            del available["open3d"]
    if "blender" in available:
        found, why = blender_version(args)
        if found is None:
            log(f"skipping blender: bpy does not import ({why}); pip install bpy==5.0.1 "
                f"(Python 3.11), or --blender-python PATH")
            del available["blender"]
        else:
            versions["bpy"] = found
    log(f"# aobake vs peers ({'quick smoke run' if args.quick else 'full run'})")
    log(f"versions: {json.dumps(versions)}; threads {args.threads}; "
        f"rows: {', '.join(available)}; RMSE targets {', '.join(f'{t:g}' for t in cfg['targets'])}")

    results = []
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench_peers_") as tmp:
        for p in paths:
            results.append(measure_mesh(args, cfg, p, Path(tmp), available, log))
    for r in results:
        log("\n" + markdown(r, cfg["targets"]))
    log(f"\n(total {time.perf_counter() - start:.0f} s)")
    if args.json:
        payload = {"versions": versions, "threads": args.threads, "quick": args.quick,
                   "config": {k: list(v) if isinstance(v, tuple) else v for k, v in cfg.items()},
                   "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
                   "meshes": [jsonable(r, cfg["targets"]) for r in results]}
        args.json.write_text(json.dumps(payload, indent=1))
        log(f"wrote {args.json}")


if __name__ == "__main__":
    main()
