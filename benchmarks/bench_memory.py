"""Peak resident memory per unique triangle: the ogre subdivided to ~2M and ~8M triangles,
and sets of ogres placed as instances.

    python benchmarks/bench_memory.py [--cases imports,floor,vertices-2m,vertices-8m,lightmap-2m]
        [--rays 64] [--lightmap-rays 16] [--instance-rays 4] [--threads 2] [--before TREE]
        [--repeat 1] [--breakdown] [--meshes /tmp/aobake_memory] [--max-mib 8192]
        [--json OUT.json]

Every case runs in a fresh interpreter, and its peak is that process's own high-water mark
(``VmHWM`` of /proc/self/status, read as the case ends: everything it ever held resident,
imports included; ``os.wait4``'s ``ru_maxrss`` is kept beside it, but on Linux it also
counts the parent's resident size when it forked), with its wall and CPU seconds
(``os.wait4``).  Bytes per triangle are that peak over the mesh's unique triangles: the
issue's measure (1.09 GB for the 2M-triangle per-vertex bake, ~550 bytes a triangle).  A
case whose process grows past ``--max-mib`` is stopped and reported so (the machine is
shared).

* ``vertices-2m``, ``vertices-8m``: ``aobake.bake`` of the ogre (../shared/meshes)
  subdivided twice (1,984,128 triangles) and three times (7,936,512) by trimesh, written
  once as binary PLY into ``--meshes``; ``--rays`` per vertex (64), 2 threads.
* ``lightmap-2m``: ``aobake.bake_texels`` of the 2M mesh at 2048^2 (it has no UVs: xatlas
  unwraps it), ``--lightmap-rays`` per texel (16).
* ``instances`` (not run unless named): 1,000 nodes sharing the ogre's mesh in one .glb
  (124,008 unique triangles, 124M placed), per-vertex bake of one node (``bake="n0"``,
  given to ``load_scene`` too, as ``benchmarks/bench_instances.py`` does: loaded without
  it, the file is flattened to 124M triangles and the case stops at ``--max-mib``) with
  every node occluding: the instancing work's row (Embree instances, ``aobake.instances``;
  its own benchmark measures more).
* ``instances-all-N`` (not run unless named; any N): N nodes sharing the ogre's mesh, every
  one baked (``aobake.bake(path)``), ``--instance-rays`` per vertex (4: the memory does not
  depend on it).  Its row also gives the bytes of the result's own arrays (positions,
  faces, normals, rays, values: the outputs) and the peak less them.
* ``instances-all-N:VARIANT`` (any N): the same bake another way, to see that it stays
  flat too: ``chunk`` (the threads executor with ``--chunk-points`` 100,000: a split run
  here), ``processes`` (``--executor processes``, ``--threads`` workers), ``dask`` (a
  LocalCluster of ``--threads`` workers, 1 thread each), ``tolerance`` (``--tolerance
  0.05``, ``--max-rays 64``), ``alike`` (nodes placed two by two alike: every vertex row
  shared by two instances, so sampled once).  Its row also gives the workers' peak (``children_peak``:
  the largest ``VmHWM`` of any process under the case's, read every 50 ms: a worker's growth
  in its last 50 ms may be missed).
* ``floor``: trimesh's load of the 2M PLY plus a bare Embree scene of it (embreex,
  committed): what any tool holding that mesh and its BVH needs, the issue's 490 MB.
* ``imports``: the interpreter with aobake's imports (numpy, trimesh, embreex, scipy):
  the part of every peak that does not grow with the mesh.

``--before TREE`` runs every case on another checkout too (its C extensions built in
place: ``git archive REV | tar -x -C TREE && (cd TREE && python setup.py build_ext
--inplace)``), alternating the two, and prints the ratios this/before: memory and time
side by side in one run.  The machine is shared: compare CPU seconds and rows of one run.

``--breakdown`` runs the 2M per-vertex bake once more, its stages one after another (the
bake overlaps the Embree build with the vertex sampling; here they are apart), and
prints where the bytes are: each stage's peak (VmHWM reset before it) and the arrays it
leaves, by explicit ``nbytes`` accounting (Embree's BVH: the build's resident growth less
the arrays Python holds and the vertex and index arrays Embree reads in place).  Its child
runs with glibc's mmap threshold fixed (``MALLOC_MMAP_THRESHOLD_``), so that a freed array
leaves the resident set and the growth of a stage is what it keeps; the case rows run with
the allocator's defaults.
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "meshes"
CASES = ("imports", "floor", "vertices-2m", "vertices-8m", "lightmap-2m", "instances")
#: subdivisions of the ogre per case (trimesh's subdivide: 4x the triangles each)
LEVELS = {"2m": 2, "8m": 3}
INSTANCES = 1000
#: ``instances-all-N:VARIANT``: the bake's options for each way of running it
VARIANTS = {"": {}, "chunk": {"chunk_points": 100_000}, "processes": {"executor": "processes"},
            "dask": {"executor": "dask"}, "tolerance": {"tolerance": 0.05, "max_rays": 64},
            "alike": {}}


# ---------------------------------------------------------------- meshes (written once)

def mesh_path(folder: Path, size: str) -> Path:
    """The ogre subdivided LEVELS[size] times, as binary PLY in ``folder`` (made once)."""
    path = folder / f"ogre_subdivided_{LEVELS[size]}.ply"
    if not path.exists():
        import trimesh

        mesh = trimesh.load(SHARED / "ogre.obj", process=False)
        for _ in range(LEVELS[size]):
            mesh = mesh.subdivide()
        folder.mkdir(parents=True, exist_ok=True)
        partial = path.with_suffix(".part.ply")
        mesh.export(partial)
        partial.rename(path)
    return path


def instanced_path(folder: Path, count: int = INSTANCES, alike: bool = False) -> Path:
    """``count`` nodes on a grid sharing the ogre's one mesh, as .glb (made once); ``alike``:
    nodes 2j and 2j + 1 placed alike (every vertex row shared by two instances)."""
    path = folder / (f"ogre_x{count}_alike.glb" if alike else f"ogre_x{count}.glb")
    if path.exists():
        return path
    import numpy as np
    import trimesh

    mesh = trimesh.load(SHARED / "ogre.obj", process=False)
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float32)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.uint32)
    step = 1.2 * float((vertices.max(0) - vertices.min(0)).max())
    side = int(np.ceil(count ** 0.5))
    spot = [i // 2 if alike else i for i in range(count)]
    nodes = [{"name": f"n{i}", "mesh": 0,
              "translation": [step * (spot[i] % side), 0.0, step * (spot[i] // side)]}
             for i in range(count)]
    blob = vertices.tobytes() + faces.tobytes()
    document = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": vertices.nbytes, "target": 34962},
            {"buffer": 0, "byteOffset": vertices.nbytes, "byteLength": faces.nbytes,
             "target": 34963}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": len(vertices), "type": "VEC3",
             "min": vertices.min(0).tolist(), "max": vertices.max(0).tolist()},
            {"bufferView": 1, "componentType": 5125, "count": faces.size, "type": "SCALAR"}],
        "meshes": [{"name": "ogre", "primitives": [{"attributes": {"POSITION": 0},
                                                    "indices": 1}]}],
        "nodes": nodes,
        "scenes": [{"nodes": list(range(count))}],
        "scene": 0,
    }
    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)
    body = (struct.pack("<II", len(text), 0x4E4F534A) + text
            + struct.pack("<II", len(blob), 0x004E4942) + blob)
    folder.mkdir(parents=True, exist_ok=True)
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)
    return path


# ---------------------------------------------------------------- children

def _status(key: str) -> int:
    """/proc/self/status's ``key`` (VmRSS, VmHWM) in bytes."""
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    return 0


def _reset_peak() -> None:
    """Restart VmHWM from the present resident size (Linux: clear_refs 5)."""
    with open("/proc/self/clear_refs", "w") as refs:
        refs.write("5")


def child(case: str, args) -> dict:
    """Run one case in this (fresh) process; returns what the parent prints."""
    import aobake
    from aobake.backends.native import binding

    binding()  # Embree's library loaded, as in every bake
    import trimesh  # noqa: F401  (the loader's)

    out = {"case": case, "aobake": str(Path(aobake.__file__).parent.parent)}
    meshes = Path(args.meshes)
    clock = time.perf_counter()
    if case == "imports":
        out["triangles"] = 0
    elif case == "floor":
        import numpy as np
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        mesh = trimesh.load(mesh_path(meshes, "2m"), process=False)
        scene = rtcore_scene.EmbreeScene(robust=True)
        TriangleMesh(scene, mesh.vertices.astype(np.float32), mesh.faces.astype(np.int32))
        scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32),
                  query="OCCLUDED")
        out["triangles"] = len(mesh.faces)
    elif case.startswith("vertices-"):
        result = aobake.bake(str(mesh_path(meshes, case.split("-")[1])), rays=args.rays,
                             threads=args.threads)
        out.update(triangles=len(result.faces), rays=int(result.report["rays_cast"]),
                   timings=result.report["timings"])
    elif case == "lightmap-2m":
        result = aobake.bake_texels(str(mesh_path(meshes, "2m")), resolution=2048,
                                    rays=args.lightmap_rays, threads=args.threads)
        out.update(triangles=int(result.report["scene"]["triangles"]),
                   rays=int(result.report["rays_cast"]), timings=result.report["timings"])
    elif case == "instances":
        from aobake.scene import load_scene

        # the loader places the instances (one copy of the mesh) when told what is baked
        scene = load_scene(str(instanced_path(meshes)), bake=("n0",))
        result = aobake.bake(scene, rays=args.rays, threads=args.threads, bake=("n0",))
        out.update(triangles=len(result.faces), rays=int(result.report["rays_cast"]),
                   timings=result.report["timings"], outputs=_outputs(result),
                   instances=INSTANCES, baked=1)
    elif case.startswith("instances-all-"):
        name, _, variant = case.partition(":")
        count = int(name.rsplit("-", 1)[1])
        options = dict(VARIANTS[variant])
        if variant in ("processes", "dask"):
            options["workers"] = args.threads
        watch = _Descendants() if variant in ("processes", "dask") else None
        try:
            result = aobake.bake(str(instanced_path(meshes, count, variant == "alike")),
                                 rays=args.instance_rays, threads=args.threads, **options)
        finally:
            if watch is not None:
                out["children_peak"] = watch.stop()
        out.update(triangles=len(result.faces), rays=int(result.report["rays_cast"]),
                   timings=result.report["timings"], outputs=_outputs(result),
                   instances=count, baked=count)
    out["wall_s"] = time.perf_counter() - clock
    out["hwm"] = _status("VmHWM")
    return out


class _Descendants:
    """The largest ``VmHWM`` of any process under this one (a pool's or a LocalCluster's
    workers), read every 50 ms on a thread until :meth:`stop`."""

    def __init__(self):
        import threading

        self.peak, self.done = 0, threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _children(self) -> list:
        parents: dict = {}
        for entry in os.listdir("/proc"):
            if entry.isdigit():
                try:
                    with open(f"/proc/{entry}/stat") as stat:
                        ppid = int(stat.read().rsplit(")", 1)[1].split()[1])
                except (OSError, IndexError, ValueError):
                    continue
                parents.setdefault(ppid, []).append(int(entry))
        out, todo = [], [os.getpid()]
        while todo:
            for pid in parents.get(todo.pop(), []):
                out.append(pid)
                todo.append(pid)
        return out

    def _run(self) -> None:
        while not self.done.wait(0.05):
            for pid in self._children():
                try:
                    with open(f"/proc/{pid}/status") as status:
                        for line in status:
                            if line.startswith("VmHWM:"):
                                self.peak = max(self.peak, int(line.split()[1]) * 1024)
                except OSError:
                    pass

    def stop(self) -> int:
        self.done.set()
        self.thread.join()
        return self.peak


def _outputs(result) -> int:
    """Bytes of a per-vertex result's own arrays: positions, faces, normals, rays and the
    values (what the bake hands back and the writers write)."""
    arrays = [result.positions, result.faces, result.normals, result.rays,
              *result.values.values()]
    seen, total = set(), 0
    for array in arrays:
        if array is not None and id(array) not in seen:
            seen.add(id(array))
            total += int(array.nbytes)
    return total


def breakdown(args) -> dict:
    """The 2M per-vertex bake's stages one after another: each stage's peak and what it
    leaves, and the arrays that make it up (bytes)."""
    import functools
    import gc

    import numpy as np

    import aobake  # noqa: F401
    from aobake import occluders as occluder_stage
    from aobake import report as reports
    from aobake.backends.native import binding
    from aobake.methods.rays import RaysMethod
    from aobake.scene import load_scene
    from aobake.settings import BakeConfig
    from aobake.targets.vertices import VertexTarget
    from aobake.trace import DEFAULT_CHUNK_RAYS

    binding()
    __import__("trimesh")  # the loader's import, before the first stage

    stages, arrays = [], []
    config = BakeConfig(rays=args.rays)

    def stage(name, function):
        gc.collect()
        _reset_peak()
        before = _status("VmRSS")
        clock = time.perf_counter()
        value = function()
        stages.append({"stage": name, "before": before, "peak": _status("VmHWM"),
                       "after": _status("VmRSS"), "s": time.perf_counter() - clock})
        return value

    def held(stage_name, name, array, note=""):
        arrays.append({"stage": stage_name, "array": name,
                       "bytes": 0 if array is None else int(array.nbytes),
                       "dtype": "" if array is None else f"{array.dtype} {array.shape}",
                       "note": note})

    imports = _status("VmRSS")
    scene = stage("load", lambda: load_scene(str(mesh_path(Path(args.meshes), "2m"))))
    for name in ("vertices", "faces", "vertex_normals", "face_normals", "face_areas"):
        held("load", f"scene.{name}", getattr(scene, name))
    for kind, (_, index) in (scene.names or {}).items():
        held("load", f"scene.names[{kind}]", index)
    if hasattr(scene, "lean"):  # as aobake.api.run does for a scene it loaded
        scene = scene.lean()
        arrays.append({"stage": "load", "array": "scene.lean(): face normals and areas let go",
                       "bytes": -32 * len(scene.faces), "dtype": "", "note":
                       "remade from the frame where read (the points' sizes, the report)"})
    built = stage("occluders", lambda: occluder_stage.build(scene, config))
    growth = stages[-1]["after"] - stages[-1]["before"]
    normals = getattr(built.backend, "_face_normals", None)
    kept_used = isinstance(type(scene).__dict__.get("used"), functools.cached_property)
    held("occluders", "scene.used (cached)" if kept_used else "scene.used (not kept)",
         scene.used if kept_used else None)
    if callable(normals):
        normals = None
        arrays.append({"stage": "occluders", "array": "backend._face_normals", "bytes": 0,
                       "dtype": "", "note": "not held: made at the first front-face query"})
    own = normals is None or any(normals is scene.__dict__.get(key)
                                 for key in ("face_normals", "_face_normals"))
    if normals is not None:
        held("occluders", "backend._face_normals", None if own else normals,
             "the scene's own rows, cast per hit (--backfaces ignore): no copy" if own
             else "copy for --backfaces ignore")
    python_held = (scene.used.nbytes if kept_used else 0) + (0 if own or normals is None else normals.nbytes)
    # the float32 vertices (one float of padding) and uint32 faces Embree reads in place
    # (held by the scene's capsule, not by Python)
    buffers = (3 * len(scene.vertices) + 1) * 4 + 12 * len(scene.faces)
    arrays.append({"stage": "occluders", "array": "Embree's vertex and index arrays",
                   "bytes": buffers, "dtype": "float32 (v, 3) + uint32 (f, 3)",
                   "note": "read in place by Embree (shared buffers)"})
    arrays.append({"stage": "occluders", "array": "Embree's BVH",
                   "bytes": max(growth - python_held - buffers, 0), "dtype": "native",
                   "note": "resident growth of the build less the arrays above"})
    target = VertexTarget()
    plan = stage("sample", lambda: target.sample(scene, config, lambda: built, args.threads,
                                                 {}, [], None))
    shared = {id(scene.vertices), id(scene.vertex_normals)}
    for name in ("points", "normals", "ids", "sizes", "state"):
        array = getattr(plan, name)
        if isinstance(array, np.ndarray):
            aliased = id(array) in shared or (name == "state" and array is plan.ids)
            held("sample", f"plan.{name}", None if aliased else array,
                 "the scene's own array / ids: no copy" if aliased else "")
    method = RaysMethod.prepare(scene, config, built, args.rays)
    estimates = stage("estimate", lambda: method.estimate(plan, args.threads,
                                                          DEFAULT_CHUNK_RAYS))
    for name, array in estimates.fields.items():
        held("estimate", f"fields.{name}", array)
    held("estimate", "rays", estimates.rays)
    for name, array in estimates.extras.items():
        held("estimate", f"extras.{name}", array)
    samples = method.tracer.samples
    per_chunk = max(1, DEFAULT_CHUNK_RAYS // samples.rays) * samples.rays
    # origins and directions float32 (12 + 12 bytes a ray), occluded bool (1): at most
    # 2 * threads chunks in flight
    arrays.append({"stage": "estimate", "array": "ray chunks in flight",
                   "bytes": 2 * args.threads * per_chunk * 25,
                   "dtype": f"{2 * args.threads} x {per_chunk} rays", "note": "bounded"})
    done = stage("finish", lambda: target.finish(scene, config, plan, estimates, {}, []))
    fields = {id(a) for a in estimates.fields.values()} | {id(estimates.rays)}
    copied = sum(a.nbytes for a in done.values.values() if id(a) not in fields)
    if done.rays is not None and id(done.rays) not in fields:
        copied += done.rays.nbytes
    arrays.append({"stage": "finish", "array": "result arrays copied from the estimates",
                   "bytes": int(copied), "dtype": "",
                   "note": "" if copied else "the estimates are the result"})
    record = stage("record", lambda: method.record(estimates))
    stage("report", lambda: reports.build(
        "vertices", scene, config, record, method, done, wall=1.0, threads=args.threads,
        chunk_rays=DEFAULT_CHUNK_RAYS, warnings=[], kernels={}, executor={}))
    return {"case": "breakdown", "triangles": len(scene.faces), "imports": imports,
            "stages": stages, "arrays": arrays,
            "aobake": str(Path(aobake.__file__).parent.parent)}


def _rss(pid: int) -> int:
    """The resident bytes of process ``pid`` now (0 once it is gone)."""
    try:
        with open(f"/proc/{pid}/status") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _wait(command, environment, tree, cap: int):
    """Run ``command``; (stdout, stderr, exit code, rusage of that child, killed: it grew
    past ``cap`` bytes and was stopped, so that no case can take the shared machine's
    memory from the processes of others)."""
    import threading

    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               env=environment, cwd=str(tree))
    chunks = {"out": [], "err": []}

    def drain(pipe, key):  # read the pipes on threads: a chatty child cannot block
        chunks[key].append(pipe.read())

    readers = [threading.Thread(target=drain, args=(process.stdout, "out")),
               threading.Thread(target=drain, args=(process.stderr, "err"))]
    for reader in readers:
        reader.start()
    killed = False
    while True:
        pid, status, usage = os.wait4(process.pid, os.WNOHANG)
        if pid:
            break
        if not killed and _rss(process.pid) > cap:
            process.kill()
            killed = True
        time.sleep(0.05)
    for reader in readers:
        reader.join()
    process.returncode = os.waitstatus_to_exitcode(status)
    return b"".join(chunks["out"]), b"".join(chunks["err"]), process.returncode, usage, killed


def measure(tree: Path, case: str, args, env=None) -> dict:
    """``case`` in a fresh interpreter importing aobake from ``tree``: its record plus its
    peak (its own VmHWM) and CPU seconds (``os.wait4``)."""
    command = [sys.executable, __file__, "--child", case, "--meshes", args.meshes,
               "--rays", str(args.rays), "--lightmap-rays", str(args.lightmap_rays),
               "--instance-rays", str(args.instance_rays),
               "--threads", str(args.threads)]
    environment = dict(os.environ, PYTHONPATH=str(tree), **(env or {}))
    clock = time.perf_counter()
    stdout, stderr, code, usage, killed = _wait(command, environment, tree,
                                                args.max_mib << 20)
    if killed:
        return {"case": case, "tree": str(tree),
                "error": f"stopped above --max-mib {args.max_mib} MiB"}
    if code:
        lines = stderr.decode(errors="replace").strip().splitlines()
        return {"case": case, "tree": str(tree), "error": lines[-1] if lines else f"exit {code}"}
    record = json.loads(stdout.decode().strip().splitlines()[-1])
    # The peak is the child's own VmHWM, read as it ends: ru_maxrss also counts the
    # parent's resident size when it forked (Linux carries the old image's high-water mark
    # across exec), which for a parent that has just written a .glb is above a small case's
    # own peak.
    record.update(tree=str(tree), process_wall_s=time.perf_counter() - clock,
                  peak=record.get("hwm", usage.ru_maxrss * 1024), ru_maxrss=usage.ru_maxrss * 1024,
                  cpu_s=usage.ru_utime + usage.ru_stime)
    return record


# ---------------------------------------------------------------- tables

def _mib(n: int) -> str:
    return f"{n / 2**20:.0f}"


def _per(n: int, triangles: int) -> str:
    return f"{n / triangles:.0f}" if triangles else "-"


def print_cases(rows: list, trees: list) -> None:
    print("| case | triangles | tree | peak RSS MiB | bytes / triangle | above imports, "
          "bytes / triangle | wall s | CPU s | Mrays/s (trace) |")
    print("|---|---|---|---|---|---|---|---|---|")
    imports = {r["tree"]: r["peak"] for r in rows if r.get("case") == "imports" and "peak" in r}
    for row in rows:
        if "error" in row:
            print(f"| {row['case']} | | {Path(row['tree']).name} | failed: {row['error']} "
                  "| | | | | |")
            continue
        if row["case"] == "imports":
            continue
        f = row["triangles"]
        base = imports.get(row["tree"], 0)
        trace = row.get("timings", {}).get("trace_s")
        speed = f"{row['rays'] / trace / 1e6:.2f}" if trace and row.get("rays") else "-"
        print(f"| {row['case']} | {f:,} | {Path(row['tree']).name} | {_mib(row['peak'])} | "
              f"{_per(row['peak'], f)} | {_per(row['peak'] - base, f)} | "
              f"{row['wall_s']:.1f} | {row['cpu_s']:.1f} | {speed} |")
    for tree, peak in imports.items():
        print(f"\nimports alone ({Path(tree).name}): {_mib(peak)} MiB")
    placed = [r for r in rows if "outputs" in r and "error" not in r]
    if placed:
        print("\n| case | tree | instances | baked | baked triangles | peak RSS MiB | outputs "
              "MiB | peak less outputs MiB | less imports too MiB | workers' peak MiB | wall s |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for row in placed:
            rest = row["peak"] - row["outputs"]
            print(f"| {row['case']} | {Path(row['tree']).name} | {row['instances']:,} | "
                  f"{row['baked']:,} | {row['triangles']:,} | {_mib(row['peak'])} | "
                  f"{_mib(row['outputs'])} | {_mib(rest)} | "
                  f"{_mib(rest - imports.get(row['tree'], 0))} | "
                  f"{_mib(row['children_peak']) if row.get('children_peak') else '-'} | "
                  f"{row['wall_s']:.1f} |")
    if len(trees) == 2:
        print("\n| case | peak this / before | CPU s this / before | wall s this / before |")
        print("|---|---|---|---|")
        this, before = (str(t) for t in trees)
        for case in dict.fromkeys(r["case"] for r in rows):
            pairs = [(a, b) for a in rows for b in rows
                     if a["case"] == b["case"] == case and a["tree"] == this
                     and b["tree"] == before and "error" not in a and "error" not in b]
            if not pairs:
                continue
            n = len(pairs)
            peak = sum(a["peak"] / b["peak"] for a, b in pairs) / n
            cpu = sum(a["cpu_s"] / b["cpu_s"] for a, b in pairs) / n
            wall = sum(a["wall_s"] / b["wall_s"] for a, b in pairs) / n
            print(f"| {case} | {peak:.3f} | {cpu:.3f} | {wall:.3f} |")


def print_breakdown(record: dict) -> None:
    f = record["triangles"]
    print(f"\nBreakdown, {Path(record['aobake']).name}: {f:,} triangles, imports "
          f"{_mib(record['imports'])} MiB ({_per(record['imports'], f)} B/tri)")
    print("\n| stage | RSS before MiB | peak MiB | after MiB | peak B/tri | grew by B/tri | s |")
    print("|---|---|---|---|---|---|---|")
    for s in record["stages"]:
        print(f"| {s['stage']} | {_mib(s['before'])} | {_mib(s['peak'])} | {_mib(s['after'])} "
              f"| {_per(s['peak'], f)} | {(s['peak'] - s['before']) / f:.0f} | {s['s']:.2f} |")
    print("\n| held from | array | dtype, shape | MiB | B/tri | note |")
    print("|---|---|---|---|---|---|")
    for a in record["arrays"]:
        print(f"| {a['stage']} | {a['array']} | {a['dtype']} | {a['bytes'] / 2**20:.1f} | "
              f"{a['bytes'] / f:.1f} | {a['note']} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", default="imports,floor,vertices-2m,vertices-8m,lightmap-2m",
                        help=f"some of {','.join(CASES)}")
    parser.add_argument("--rays", type=int, default=64)
    parser.add_argument("--lightmap-rays", type=int, default=16)
    parser.add_argument("--instance-rays", type=int, default=4,
                        help="rays per vertex of the instances-all-N cases (memory does not "
                             "depend on it; N ogres all baked are N x 62k vertices)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--before", type=Path, default=None,
                        help="another checkout to run every case on too (alternating)")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--breakdown", action="store_true")
    parser.add_argument("--meshes", default="/tmp/aobake_memory")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--max-mib", type=int, default=8192,
                        help="stop a case whose process grows past this (the machine is shared)")
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        record = breakdown(args) if args.child == "breakdown" else child(args.child, args)
        print(json.dumps(record))
        return 0
    cases = [c for c in args.cases.split(",") if c]
    unknown = {c for c in cases if c not in CASES and not (
        c.startswith("instances-all-") and c.partition(":")[0].rsplit("-", 1)[1].isdigit()
        and c.partition(":")[2] in VARIANTS)}
    if unknown:
        parser.error(f"unknown cases {sorted(unknown)}; choose from {CASES}")
    meshes = Path(args.meshes)
    for case in cases:  # made once, outside the measured processes
        if case in ("floor", "vertices-2m", "lightmap-2m") or args.breakdown:
            mesh_path(meshes, "2m")
        if case == "vertices-8m":
            mesh_path(meshes, "8m")
        if case == "instances":
            instanced_path(meshes)
        if case.startswith("instances-all-"):
            instanced_path(meshes, int(case.partition(":")[0].rsplit("-", 1)[1]),
                           case.partition(":")[2] == "alike")
    trees = [ROOT] + ([args.before.resolve()] if args.before else [])
    print(f"load average {os.getloadavg()[0]:.1f}", flush=True)
    rows = []
    for _ in range(args.repeat):
        for case in cases:
            for tree in (trees if _ % 2 == 0 else trees[::-1]):  # alternate who goes first
                row = measure(tree, case, args)
                rows.append(row)
                print(json.dumps({k: row.get(k) for k in ("case", "tree", "peak", "outputs",
                                                          "children_peak", "cpu_s", "wall_s",
                                                          "error")}), flush=True)
    print(f"load average {os.getloadavg()[0]:.1f}\n")
    print_cases(rows, trees)
    records = []
    if args.breakdown:
        fixed = {"MALLOC_MMAP_THRESHOLD_": str(1 << 17)}
        for tree in trees:
            record = measure(tree, "breakdown", args, env=fixed)
            records.append(record)
            if "error" in record:
                print(f"\nbreakdown failed on {tree}: {record['error']}")
            else:
                print_breakdown(record)
    if args.json:
        args.json.write_text(json.dumps({"cases": rows, "breakdown": records}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
