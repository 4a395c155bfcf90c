"""One aobake lightmap bake in a process of its own, for bench_renderers_lightmap.py.

    python benchmarks/_aobake_lightmap.py MESH.obj --out OUT.npz --resolution 1024
        --rays N [--texel-samples K] [--seed S] [--threads T] [--padding P] [--warmup]

The mesh is baked into its own UVs (``unwrap='never'``: the atlas the caller made, the
same file Blender bakes), ``seams='off'`` (seam erasure changes texels near UV seams so
that bilinear lookups agree across them: a texel would no longer estimate its own AO, and
Cycles has no such step), gutters as the library's default (``padding`` rings and
push-pull fill: in the timed call, though no texel of the gutter is scored), max
distance unbounded, cosine weighting, the default sampler (Sobol, 4 replicates).

What is timed is the library call ``aobake.bake_texels(scene, ...)`` on the mesh read
beforehand (``aobake.load_scene``: the file read is reported as ``read_s``, as Blender's
OBJ import is left out of its bake call), aobake's modules imported before the clock
starts.  ``--warmup``: first an untimed bake of 1 ray per texel at 64 x 64 (``warmup_s``),
so the timed call does not pay one-time set-up (loading the Embree library, first-use
imports).

OUT.npz: ``ao``, ``ao_stderr``, ``coverage`` (H, W) float32 (rows top first), scalars
``seconds`` (wall of the call), ``cpu_s`` (this process's CPU seconds over it, all
threads), ``read_s``, ``warmup_s``, ``rays_cast``, and ``info`` (a JSON string: the
report's timings, the Embree binding and packet width, the sampler's replicates).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def bake(mesh: str, resolution: int, rays: int, texel_samples: int, seed: int, threads: int,
         padding: int | None, warmup: bool) -> dict:
    import aobake
    import aobake.api  # noqa: F401  (the modules bake_texels resolves, before the clock)
    from aobake.scene import load_scene

    clock = time.perf_counter()
    scene = load_scene(mesh)
    read_s = time.perf_counter() - clock
    options = {"seams": "off", "unwrap": "never"}
    # sobol's budgets are R 2^k: a budget with another odd factor runs as that many
    # replicates (384 = 3 x 128), so every row casts the rays it names
    odd = rays // (rays & -rays)
    if odd > 1:
        options["replicates"] = odd
    if padding is not None:
        options["padding"] = padding
    warmup_s = 0.0
    if warmup:
        clock = time.perf_counter()
        aobake.bake_texels(scene, rays=1, texel_samples=1, resolution=64, threads=threads,
                           seed=seed + 7919, **options)
        warmup_s = time.perf_counter() - clock
    clock, used = time.perf_counter(), time.process_time()
    result = aobake.bake_texels(scene, rays=rays, texel_samples=texel_samples,
                                resolution=resolution, threads=threads, seed=seed, **options)
    seconds, cpu_s = time.perf_counter() - clock, time.process_time() - used
    report = result.report
    params = report.get("parameters", {})
    info = {"timings": report.get("timings", {}),
            "embree_binding": params.get("embree_binding"),
            "replicates": params.get("replicates"), "sampler": params.get("sampler"),
            "texels_covered": report.get("texture", {}).get("texels_covered"),
            "atlas": report.get("texture", {}).get("atlas")}
    return {"ao": np.asarray(result.channels["ao"], dtype=np.float32),
            "ao_stderr": np.asarray(result.channels["ao_stderr"], dtype=np.float32),
            "coverage": np.asarray(result.channels["coverage"], dtype=np.float32),
            "seconds": seconds, "cpu_s": cpu_s, "read_s": read_s, "warmup_s": warmup_s,
            "rays_cast": int(report["rays_cast"]), "info": json.dumps(info, default=str)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("mesh")
    parser.add_argument("--out", required=True)
    parser.add_argument("--resolution", type=int, default=1024)
    parser.add_argument("--rays", type=int, required=True)
    parser.add_argument("--texel-samples", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--padding", type=int)
    parser.add_argument("--warmup", action="store_true")
    args = parser.parse_args(argv)
    out = bake(args.mesh, args.resolution, args.rays, args.texel_samples, args.seed,
               args.threads, args.padding, args.warmup)
    np.savez(args.out, **out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
