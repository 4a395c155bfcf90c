"""New-atlas quality and cost: coverage, charts, texel density spread, unwrap seconds.

    python benchmarks/bench_atlas.py [--resolutions 1024,512x1024] [--paddings 8,2]
                                     [--meshes spot,stanford-bunny,ogre] [--repeat 3]
                                     [--old REV] [--baseline]

Cases: ../shared/meshes/spot.obj (the UVs it ships, and a new atlas), stanford-bunny.obj
and ogre.obj (no UVs: new atlases).  For each padding:

- coverage: texels the surface covers (rasterised, any overlap) / all texels;
- charts: UV islands; density: per chart sqrt(UV area in texels / surface area), texels
  per scene unit, 5th and 95th percentile over the charts and their ratio (1 = uniform);
- unwrap s: ``unwrap(..., isolate=False)`` in a fresh child process, minimum over
  ``--repeat`` runs (the machine is shared: take minimums).  A bake adds ~0.3 s for its
  isolating child process (``timings.unwrap_s`` in the report).

``--old REV`` adds the same rows for the unwrapper of git revision REV (its
aobake/targets/texels/unwrap.py, loaded on its own).  ``--baseline`` adds xatlas's own
default charting (uncapped: ~20 s for the bunny), its charts repacked by xatlas (default
PackOptions but the padding) at the largest texels_per_unit whose one atlas fits in
W x H (bisection to 0.3%); its charts are made once per mesh (cached in the system's
temporary directory) and packed for every resolution and padding.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "meshes"

# Runs in a child: unwraps (or reads the mesh's own UVs) and measures; prints one JSON line.
CHILD = textwrap.dedent("""
    import importlib.util, json, sys, time
    import numpy as np
    sys.path.insert(0, sys.argv[1])
    from aobake.scene import load_scene
    from aobake.targets.texels.raster import rasterize
    from aobake.targets.texels.charts import chart_texel_density
    mesh, resolution, padding, how, old = sys.argv[2], sys.argv[3], int(sys.argv[4]), sys.argv[5], sys.argv[6]
    scene = load_scene(mesh)
    W, H = (int(x) for x in (resolution.split("x") * 2)[:2])
    seconds = None
    if how == "own":
        uv, faces_uv = scene.uv, scene.faces_uv
    elif how == "baseline":
        import os, tempfile, xatlas
        cache = os.path.join(tempfile.gettempdir(), "aobake-bench-atlas-" + os.path.basename(mesh)
                             + "-%d.npz" % os.stat(mesh).st_size)
        clock = time.perf_counter()
        if os.path.exists(cache):  # xatlas's default charts of this mesh, made before
            with np.load(cache) as d:
                f0, uv0 = d["f"], d["uv"]
        else:
            # normalised as the unwrapper does (mean triangle area 1): xatlas's tolerances are
            # absolute, and the raw bunny (metres) or ogre charts into many more charts
            v = scene.vertices - 0.5 * (scene.vertices.min(axis=0) + scene.vertices.max(axis=0))
            v = v / np.sqrt(scene.areas().sum() / len(scene.faces))
            first = xatlas.Atlas()
            first.add_mesh(v.astype(np.float32), scene.faces.astype(np.uint32))
            o = xatlas.PackOptions()  # default charts; a fine first pack (4096 across)
            o.texels_per_unit = 4 * 1024 / float(np.sqrt(len(scene.faces)))
            first.generate(pack_options=o)
            _, f0, uv0 = first[0]
            uv0 = np.ascontiguousarray(uv0 * [first.width, first.height], np.float32)
            np.savez(cache, f=f0, uv=uv0)
        def pack(tpu):  # xatlas repacks its charts (the UV islands)
            global atlas
            o = xatlas.PackOptions(); o.padding, o.texels_per_unit = padding, tpu
            atlas = xatlas.Atlas(); atlas.add_uv_mesh(uv0, f0); atlas.generate(pack_options=o)
            return atlas.atlas_count == 1 and atlas.width <= W and atlas.height <= H
        lo, hi = 1e-4, 1e2
        for _ in range(40):
            mid = (lo * hi) ** 0.5
            lo, hi = (mid, hi) if pack(mid) else (lo, mid)
            if hi / lo < 1.003:
                break
        if not pack(lo):  # even the smallest scale tried makes xatlas's atlas larger
            sys.exit(f"xatlas: the charts cannot fit in {W}x{H} with {padding} texels of "
                     f"padding (its atlas at the smallest scale: {atlas.width}x{atlas.height})")
        seconds = time.perf_counter() - clock
        vm, faces_uv, uv = atlas[0]
        uv = uv.astype(np.float64) * [atlas.width / W, atlas.height / H]
        uv[:, 1] = 1.0 - uv[:, 1]
        faces_uv = faces_uv.astype(np.int64)
    else:
        if old != "-":
            spec = importlib.util.spec_from_file_location("unwrap_old", old)
            module = importlib.util.module_from_spec(spec); spec.loader.exec_module(module)
            unwrap = module.unwrap
        else:
            from aobake.targets.texels.unwrap import unwrap
        import xatlas  # noqa: F401  (its import is not the unwrap's time)
        clock = time.perf_counter()
        un = unwrap(scene.vertices, scene.faces, (W, H), padding, isolate=False)
        seconds = time.perf_counter() - clock
        uv, faces_uv = un.uv, un.faces
    s = rasterize(uv, faces_uv, W, H, 1, 0)
    density = chart_texel_density(uv, faces_uv, scene.vertices, scene.faces, W, H)
    p5, p95 = np.percentile(density, [5, 95])
    print(json.dumps({"coverage": np.unique(s.texel).size / (W * H), "charts": len(density),
                      "p5": p5, "p95": p95, "seconds": seconds}))
""")


def measure(mesh: Path, resolution: str, padding: int, how: str, old: str = "-") -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(ROOT), str(mesh), str(resolution),
                          str(padding), how, old], capture_output=True, text=True, timeout=3600)
    if out.returncode != 0:  # e.g. charts that cannot fit at that padding: a row saying so
        last = (out.stderr.strip().splitlines() or ["failed"])[-1]
        return {"error": last.split(": ", 1)[-1][:60], "seconds": None}
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolutions", default="1024",
                        help="comma-separated N or WxH (e.g. 256,512,1024,512x1024)")
    parser.add_argument("--paddings", default="8,2", help="comma-separated (8 was the default, 2 is)")
    parser.add_argument("--meshes", default="spot,stanford-bunny,ogre")
    parser.add_argument("--repeat", type=int, default=3, help="unwrap runs; the minimum is shown")
    parser.add_argument("--old", metavar="REV", help="also the unwrapper of this git revision")
    parser.add_argument("--baseline", action="store_true",
                        help="also xatlas's default charting packed by xatlas (slow)")
    args = parser.parse_args()
    meshes = {name: SHARED / f"{name}.obj" for name in args.meshes.split(",")}
    if not all(m.is_file() for m in meshes.values()):
        sys.exit(f"benchmarks need ../shared/meshes ({', '.join(p.name for p in meshes.values())})")
    paddings = [int(p) for p in args.paddings.split(",")]
    old_file = None
    if args.old:
        text = subprocess.run(["git", "-C", str(ROOT), "show",
                               f"{args.old}:aobake/targets/texels/unwrap.py"],
                              capture_output=True, text=True, check=True).stdout
        old_file = Path(tempfile.mkdtemp(prefix="aobake-bench-")) / "unwrap_old.py"
        old_file.write_text(text)
    print(f"unwrap seconds: minimum of {args.repeat} runs (in-process, without the bake's "
          "~0.3 s child process); xatlas default: its packs only (charts cached)\n")
    print("| mesh | resolution | atlas | padding | charts | coverage | density p5 | density p95 "
          "| p95/p5 | unwrap s |")
    print("|" + "---|" * 10, flush=True)
    for resolution in args.resolutions.split(","):
        for name, path in meshes.items():
            if name == "spot":
                row(name, resolution, "own UVs", "-", measure(path, resolution, 0, "own"))
            for padding in paddings:
                kinds = [("new atlas", "new", "-")]
                if old_file:
                    kinds.append((f"atlas of {args.old}", "new", str(old_file)))
                if args.baseline:
                    kinds.append(("xatlas default", "baseline", "-"))
                for label, how, old in kinds:
                    runs = [measure(path, resolution, padding, how, old)
                            for _ in range(args.repeat if how == "new" else 1)]
                    best = dict(runs[0], seconds=min((r["seconds"] or 0) for r in runs))
                    row(name, resolution, label, padding, best)


def row(name, resolution, label, padding, r):
    """One table row, printed as soon as it is measured."""
    seconds = "-" if not r["seconds"] else f"{r['seconds']:.2f}"
    if "error" in r:
        print(f"| {name} | {resolution} | {label} | {padding} | {r['error']} |||||", flush=True)
        return
    print(f"| {name} | {resolution} | {label} | {padding} | {r['charts']} | "
          f"{r['coverage']:.1%} | {r['p5']:.4g} | {r['p95']:.4g} | {r['p95'] / r['p5']:.3f} "
          f"| {seconds} |", flush=True)

if __name__ == "__main__":
    main()
