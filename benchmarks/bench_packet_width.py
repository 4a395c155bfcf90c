"""Occlusion packet widths on this CPU: aobake's own rays, traced through ``aobake._embree``
at each width, alternated, with the load from other work recorded per repeat.

    python benchmarks/bench_packet_width.py [--meshes bunny ogre] [--rays 128] [--threads 2]
        [--widths 8 16] [--repeats 7] [--wait 120] [--json widths.json]

The rays are the very ones a bake casts: one per-vertex AO bake (``--rays`` per vertex,
seed 0, robust traversal) is run with its backend's ``occluded`` recorded (float32 origins,
directions and segment ends, chunk by chunk, as the tracer hands them over); the
recording is then replayed through ``aobake._embree.occluded`` at each ``--widths``, its
chunks on ``--threads`` threads as the tracer runs them, the widths alternated within
each of ``--repeats`` rounds.  Only the queries are timed (no ray generation, no Python
estimation), so the table is the tracing itself.  Every width's answers are compared with
the first's, bit for bit.

A round is "comparable" when other work used at most benchmarks/_machine.py's
LOAD_THRESHOLD cores, sampled for 0.5 s before it and measured over it (from /proc/stat,
less this process's own CPU time); before each round the script waits up to ``--wait``
seconds for that.  The medians are over comparable rounds only (all rounds if none was).
Printed: the CPU model, its vector extensions, Embree's native packet width here, the
width aobake chooses (``aobake.backends.native.packet_width``), and per mesh and width
the median seconds, Mrays/s and the ratio to the chosen width.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

import aobake  # noqa: E402
from aobake.backends import native  # noqa: E402
from aobake.backends.embree import EmbreeBackend  # noqa: E402

import _machine  # noqa: E402

MESHES = {"bunny": HERE.parents[1] / "shared" / "meshes" / "stanford-bunny.obj",
          "ogre": HERE.parents[1] / "shared" / "meshes" / "ogre.obj"}


def record_rays(path: Path, rays: int, threads: int):
    """(the bake's EmbreeBackend, [(origins, directions, tfar)] per occluded() call)."""
    calls, backends = [], []
    original = EmbreeBackend.occluded
    original_init = EmbreeBackend.__init__

    def init(self, *args, **kwargs):
        original_init(self, *args, **kwargs)
        backends.append(self)

    def occluded(self, origins, directions, tmax):
        o = np.ascontiguousarray(origins, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        calls.append((o, d, self._tfar(tmax, len(o))))
        return original(self, origins, directions, tmax)

    EmbreeBackend.occluded, EmbreeBackend.__init__ = occluded, init
    try:
        aobake.bake(str(path), rays=rays, threads=threads, seed=0)
    finally:
        EmbreeBackend.occluded, EmbreeBackend.__init__ = original, original_init
    if len(backends) != 1 or backends[0].native_scene() is None:
        raise RuntimeError("the bake did not trace through one aobake._embree scene")
    return backends[0], calls


def replay(module, handle, calls, width: int, threads: int):
    """(seconds, answers (n,) bool) of every recorded call at ``width`` on ``threads``."""
    outs = [np.empty(len(o), dtype=bool) for o, _, _ in calls]

    def one(i):
        o, d, t = calls[i]
        module.occluded(handle, o, d, t, outs[i], width)

    with ThreadPoolExecutor(threads) as pool:
        start = time.perf_counter()
        list(pool.map(one, range(len(calls))))
        seconds = time.perf_counter() - start
    return seconds, np.concatenate(outs)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--meshes", nargs="+", default=list(MESHES), choices=list(MESHES))
    parser.add_argument("--rays", type=int, default=128)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--widths", nargs="+", type=int, default=[8, 16], choices=[1, 4, 8, 16])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--wait", type=float, default=120.0,
                        help="seconds to wait for a quiet machine before each round")
    parser.add_argument("--threshold", type=float, default=_machine.LOAD_THRESHOLD)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)

    found = native.binding()
    if found is None:
        sys.exit("aobake._embree is not available here: nothing to measure")
    module, widest = found
    chosen, source = native.packet_width(widest)
    cpu = _machine.cpu()
    print(f"CPU: {cpu['model']} ({cpu['logical_cpus']} logical), vector: "
          f"{' '.join(cpu['vector'])}; Embree's native packet width {native.native_width()}, "
          f"widest answered {widest}; aobake chooses {chosen} ({source})")
    print(f"{args.rays} rays/vertex, {args.threads} threads, {args.repeats} rounds, "
          f"load threshold {args.threshold} cores\n", flush=True)
    widths = [w for w in args.widths if w <= widest]
    results = []
    for name in args.meshes:
        backend, calls = record_rays(MESHES[name], args.rays, args.threads)
        n = sum(len(o) for o, _, _ in calls)
        _, handle = backend.native_scene()
        first = None
        for w in widths:  # warm up every width once; check the answers
            _, hits = replay(module, handle, calls, w, args.threads)
            first = hits if first is None else first
            if not np.array_equal(hits, first):
                sys.exit(f"{name}: width {w} answers differently from width {widths[0]}")
        rounds = []
        for r in range(args.repeats):
            before = _machine.wait_for_quiet(args.wait, args.threshold, log=print)
            row = {"before": before, "seconds": {}}
            with _machine.Load() as load:
                order = widths if r % 2 == 0 else widths[::-1]
                for w in order:
                    row["seconds"][w] = replay(module, handle, calls, w, args.threads)[0]
            row["during"] = load.record()
            row["comparable"] = max(before["others_cores"], load.others) <= args.threshold
            rounds.append(row)
            print(f"  {name} round {r + 1}: " + ", ".join(
                f"{w}: {row['seconds'][w]:.3f} s" for w in widths)
                + f"  (others {before['others_cores']:.2f} / {load.others:.2f} cores"
                + ("" if row["comparable"] else ": not comparable (load)") + ")", flush=True)
        used = [r for r in rounds if r["comparable"]] or rounds
        med = {w: statistics.median(r["seconds"][w] for r in used) for w in widths}
        # per round, the ratio of each width to the chosen one (paired: the same round)
        paired = {w: statistics.median(r["seconds"][w] / r["seconds"][chosen] for r in used)
                  for w in widths} if chosen in widths else {}
        results.append({"mesh": name, "rays_cast": n, "rounds": rounds,
                        "comparable_rounds": sum(r["comparable"] for r in rounds),
                        "median_s": med, "paired_ratio_to_chosen": paired})
        del calls, backend

    print(f"\n| mesh | width | rays cast | median s | Mrays/s | x chosen ({chosen}) | rounds |")
    print("|---|---|---|---|---|---|---|")
    for res in results:
        for w in widths:
            ratio = res["paired_ratio_to_chosen"].get(w)
            print(f"| {res['mesh']} | {w} | {res['rays_cast']:,} | {res['median_s'][w]:.3f} | "
                  f"{res['rays_cast'] / res['median_s'][w] / 1e6:.1f} | "
                  f"{'—' if ratio is None else f'{ratio:.3f}'} | "
                  f"{res['comparable_rounds']} of {len(res['rounds'])} comparable |")
    if args.json:
        args.json.write_text(json.dumps({
            "cpu": cpu, "embree_native_width": native.native_width(), "widest": widest,
            "chosen": chosen, "chosen_by": source, "rays": args.rays, "threads": args.threads,
            "threshold_cores": args.threshold, "meshes": results}, indent=1))
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
