"""One timed bake of one tool, in a process of its own, for bench_peers.py.

    python benchmarks/_peers_runner.py KIND MESH --rays N --threads T --out OUT.npz
        [--sampler S] [--seed K] [--weighting W]

Every row of bench_peers is timed in a fresh process, so no row inherits another's state:
a heap grown by earlier bakes, another library's thread pool, a warm or cold page cache of
its own making.  (Timed inside the benchmark's own process, after the references and the
other rows, ``aobake.bake`` once took 4.29 s on the bunny at 256 rays where a fresh process
took 1.8-2.3 s.)  Each kind imports its tool before the clock starts, as a user's script
would have; what is timed is the call:

* ``library``: ``aobake.bake(MESH, rays=N, threads=T)`` (file read, scene build, bake).
  The package's modules are imported first (aobake resolves names lazily).  Also bakes
  the references (``--sampler``, ``--seed``, ``--weighting``), untimed by the caller.
* ``bare``: a bare embreex loop on the library run's rays (aobake's own generator, run
  before the clock starts), ``EmbreeScene.run(query="OCCLUDED")`` on T threads in
  aobake's chunks: ``build_s`` (scene) and ``trace_s`` (tracing only).
* ``libigl``: ``igl.embree.ambient_occlusion(V, F, V, N, n)`` on the vertices and normals
  aobake loads (untimed); IGL_NUM_THREADS is the caller's to set.
* ``open3d``: ``RaycastingScene.test_occlusions`` on cosine rays made in numpy (timed, as
  a user of Open3D pays for them; ``gen_s`` gives their share), origins lifted by aobake's
  offset rule (untimed).

OUT.npz: ``ao`` (v,) float64 per vertex of the file (1 = open; NaN where the tool gives
nothing), ``seconds`` (the timed call), ``rays_cast``, and ``info``: a JSON string of what
else the kind measured (the packet width aobake used, build and trace seconds, ...).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

#: rays per Open3D call (a chunk of whole vertices), and per pre-generated batch of the
#: bare loop (bounds their memory: 24 bytes a ray)
OPEN3D_CHUNK_RAYS = 1 << 21
BARE_BATCH_RAYS = 1 << 24


def packet_width_of(report: dict):
    """The occlusion packet width a bake's report names (None: embreex, one ray at a time)."""
    import re

    found = re.search(r"packets of (\d+)", report["parameters"].get("embree_binding", ""))
    return int(found.group(1)) if found else None


def run_library(path: Path, rays: int, threads: int, sampler, seed, weighting) -> dict:
    import aobake
    import aobake.api  # noqa: F401  (the modules bake() resolves, imported before the clock)

    options = {k: v for k, v in (("sampler", sampler), ("seed", seed),
                                 ("weighting", weighting)) if v is not None}
    modules = len(sys.modules)
    start = time.perf_counter()
    res = aobake.bake(str(path), rays=rays, threads=threads, **options)
    seconds = time.perf_counter() - start
    return {"ao": res.ao.astype(np.float64), "ao_stderr": res.ao_stderr.astype(np.float64),
            "rays": res.rays.astype(np.int64), "seconds": seconds,
            "rays_cast": int(res.report["rays_cast"]),
            "info": {"packet_width": packet_width_of(res.report),
                     "embree_binding": res.report["parameters"].get("embree_binding"),
                     "modules_imported_in_call": len(sys.modules) - modules}}


def run_bare(path: Path, rays: int, threads: int) -> dict:
    """bench_throughput's bare loop on the library run's rays, keeping the answers.

    The points are the distinct (position, normal) pairs with a normal, as aobake traces
    them; each chunk's rays come from aobake's generator and are made before the clock
    starts (in batches of BARE_BATCH_RAYS, whose generation is not timed either)."""
    from concurrent.futures import ThreadPoolExecutor

    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    from aobake.settings import BakeConfig
    from aobake.occluders import build as build_occluders
    from aobake.scene import load_scene
    from aobake.targets.vertices import vertex_sizes
    from aobake.trace import DEFAULT_CHUNK_RAYS, Tracer, morton_order, point_offsets

    scene = load_scene(path)
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
    return {"ao": per_unique[inverse], "seconds": build_s + trace_s, "rays_cast": total,
            "info": {"build_s": build_s, "trace_s": trace_s}}


def run_libigl(path: Path, rays: int) -> dict:
    import igl.embree

    from aobake.scene import load_scene

    scene = load_scene(path)
    V = np.ascontiguousarray(scene.vertices, dtype=np.float64)
    F = np.ascontiguousarray(scene.faces, dtype=np.int64)
    N = np.ascontiguousarray(scene.vertex_normals, dtype=np.float64)
    start = time.perf_counter()
    occluded = igl.embree.ambient_occlusion(V, F, V, N, rays)
    seconds = time.perf_counter() - start
    return {"ao": 1.0 - np.asarray(occluded, dtype=np.float64), "seconds": seconds,
            "rays_cast": len(V) * rays, "info": {}}


def hemisphere_frames(n: np.ndarray):
    """(k, 3) unit normals -> tangents, bitangents (k, 3) (Duff et al. 2017, branchless)."""
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    s = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return t, s


def run_open3d(path: Path, rays: int, threads: int, seed: int = 0) -> dict:
    """Cosine rays from the vertices with a normal, lifted by aobake's offset rule."""
    import open3d as o3d

    from aobake.settings import DEFAULT_RAY_OFFSET
    from aobake.scene import load_scene
    from aobake.targets.vertices import vertex_sizes
    from aobake.trace import point_offsets

    scene = load_scene(path)
    N = scene.vertex_normals
    has = np.linalg.norm(N, axis=1) > 0.5
    lift = point_offsets(scene.vertices[has], vertex_sizes(scene)[has], DEFAULT_RAY_OFFSET)
    origins, normals = scene.vertices[has] + lift[:, None] * N[has], N[has]

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
    seconds = time.perf_counter() - start
    out = np.full(len(scene.vertices), np.nan)
    out[has] = ao
    return {"ao": out, "seconds": seconds, "rays_cast": len(origins) * rays,
            "info": {"gen_s": gen_s}}


KINDS = ("library", "bare", "libigl", "open3d")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("kind", choices=KINDS)
    parser.add_argument("mesh", type=Path)
    parser.add_argument("--rays", type=int, required=True)
    parser.add_argument("--threads", type=int, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--sampler")
    parser.add_argument("--seed", type=int)
    parser.add_argument("--weighting")
    args = parser.parse_args(argv)
    if args.kind == "library":
        res = run_library(args.mesh, args.rays, args.threads, args.sampler, args.seed,
                          args.weighting)
    elif args.kind == "bare":
        res = run_bare(args.mesh, args.rays, args.threads)
    elif args.kind == "libigl":
        res = run_libigl(args.mesh, args.rays)
    else:
        res = run_open3d(args.mesh, args.rays, args.threads)
    res["info"] = json.dumps(res["info"])
    tmp = args.out.with_suffix(".tmp.npz")
    np.savez(tmp, **res)
    tmp.replace(args.out)


if __name__ == "__main__":
    main()
