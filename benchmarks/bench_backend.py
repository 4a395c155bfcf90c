"""The compiled Embree binding (``aobake._embree``: occlusion in packets of 8) against
embreex (one ray at a time): speed, and whether any output differs.

    python benchmarks/bench_backend.py [--rays 128] [--repeats 5] [--threads 2]
                                       [--meshes still_life bunny ogre]
                                       [--quantities ao obscurance] [--widths 8]

Per mesh and quantity, per-vertex bakes with the same seed through each binding
(``aobake._native.embreex_only`` forces embreex), alternated, ``--repeats`` times each:
per packet width of ``--widths`` (``aobake.backends.native.PACKET_WIDTH``, default the width
aobake chooses here; 1 = one ray at a
time through aobake._embree), the median trace seconds (the report's ``trace_s``: ray generation, tracing, estimation)
and of the whole in-process bake (``total_s``: loading, the scene's build, sampling,
tracing), their ratios, and whether every output array is bit-identical.  Obscurance
asks for distances (closest hits, one ray at a time in both bindings): its row shows
the binding's fixed costs only.  Timings mean something only on a quiet machine.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import aobake  # noqa: E402
from aobake import _native  # noqa: E402
from aobake.backends import native  # noqa: E402

SHARED = ROOT.parent / "shared" / "meshes"
MESHES = {"still_life": ROOT / "assets" / "still_life.obj",
          "bunny": SHARED / "stanford-bunny.obj", "ogre": SHARED / "ogre.obj"}


def bake(mesh, rays, threads, quantities, embreex, width):
    native.PACKET_WIDTH = width
    if embreex:
        with _native.embreex_only():
            result = aobake.bake(str(mesh), rays=rays, threads=threads, quantities=quantities)
    else:
        result = aobake.bake(str(mesh), rays=rays, threads=threads, quantities=quantities)
    timings = result.report["timings"]
    return result, timings["trace_s"], timings["total_s"]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rays", type=int, default=128)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--meshes", nargs="+", default=list(MESHES), choices=list(MESHES))
    parser.add_argument("--quantities", nargs="+", default=["ao", "obscurance"])
    parser.add_argument("--widths", nargs="+", type=int, choices=[1, 4, 8, 16],
                        help="packet widths (default: the one aobake chooses on this CPU)")
    args = parser.parse_args(argv)
    found = native.binding()
    if found is None:
        sys.exit("aobake._embree is not available here: nothing to compare")
    args.widths = args.widths or [native.packet_width(found[1])[0]]
    print(f"rays per vertex {args.rays}, threads {args.threads}, median of {args.repeats}, "
          f"widest packet here {found[1]}")
    print("| mesh | quantity | width | rays cast | embreex trace s | compiled trace s | trace ratio | "
          "compiled Mrays/s | embreex bake s | compiled bake s | bake ratio | identical |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name in args.meshes:
        for quantity, width in [(q, w) for q in args.quantities for w in args.widths]:
            if width > found[1]:
                continue
            times = {False: [], True: []}
            results = {}
            bake(MESHES[name], args.rays, args.threads, [quantity], False, width)  # warm up
            for _ in range(args.repeats):
                for embreex in (True, False):
                    result, trace, total = bake(MESHES[name], args.rays, args.threads,
                                                [quantity], embreex, width)
                    times[embreex].append((trace, total))
                    results[embreex] = result
            fields = [results[e].fields() for e in (False, True)]
            same = set(fields[0]) == set(fields[1]) and all(
                np.array_equal(fields[0][k], fields[1][k], equal_nan=True) for k in fields[0])
            med = {e: [statistics.median(t[i] for t in times[e]) for i in (0, 1)]
                   for e in times}
            cast = int(results[False].report["rays_cast"])
            print(f"| {name} | {quantity} | {width} | {cast:,} | {med[True][0]:.3f} | {med[False][0]:.3f} "
                  f"| {med[False][0] / med[True][0]:.2f} | {cast / med[False][0] / 1e6:.1f} | "
                  f"{med[True][1]:.3f} | {med[False][1]:.3f} | "
                  f"{med[False][1] / med[True][1]:.2f} | {'yes' if same else 'NO'} |",
                  flush=True)


if __name__ == "__main__":
    main()
