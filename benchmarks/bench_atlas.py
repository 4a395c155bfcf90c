"""New-atlas quality and cost: coverage, charts, texel density spread, unwrap seconds.

    python benchmarks/bench_atlas.py [--resolution 1024] [--paddings 8,2] [--repeat 3]
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
PackOptions but the padding) at the largest texels_per_unit whose one atlas fits
(bisection to 0.3%).
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
    from aobake.targets.texels.unwrap import chart_texel_density
    mesh, resolution, padding, how, old = sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5], sys.argv[6]
    scene = load_scene(mesh)
    R = resolution
    seconds = None
    if how == "own":
        uv, faces_uv = scene.uv, scene.faces_uv
    elif how == "baseline":
        import xatlas
        # normalised as the unwrapper does (mean triangle area 1): xatlas's tolerances are
        # absolute, and the raw bunny (metres) or ogre charts into many more charts
        v = scene.vertices - 0.5 * (scene.vertices.min(axis=0) + scene.vertices.max(axis=0))
        v = v / np.sqrt(scene.areas().sum() / len(scene.faces))
        first = xatlas.Atlas()
        first.add_mesh(v.astype(np.float32), scene.faces.astype(np.uint32))
        clock = time.perf_counter()
        o = xatlas.PackOptions()  # default charts; a fine first pack (4 R across)
        o.texels_per_unit = 4 * R / float(np.sqrt(len(scene.faces)))
        first.generate(pack_options=o)
        _, f0, uv0 = first[0]
        uv0 = np.ascontiguousarray(uv0 * [first.width, first.height], np.float32)
        def pack(tpu):  # xatlas repacks its charts (the UV islands)
            global atlas
            o = xatlas.PackOptions(); o.padding, o.texels_per_unit = padding, tpu
            atlas = xatlas.Atlas(); atlas.add_uv_mesh(uv0, f0); atlas.generate(pack_options=o)
            return atlas.atlas_count == 1 and max(atlas.width, atlas.height) <= R
        lo, hi = 1e-4, 1e2
        for _ in range(40):
            mid = (lo * hi) ** 0.5
            lo, hi = (mid, hi) if pack(mid) else (lo, mid)
            if hi / lo < 1.003:
                break
        pack(lo)
        seconds = time.perf_counter() - clock
        vm, faces_uv, uv = atlas[0]
        uv = uv.astype(np.float64) * [atlas.width / R, atlas.height / R]
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
        un = unwrap(scene.vertices, scene.faces, R, padding, isolate=False)
        seconds = time.perf_counter() - clock
        uv, faces_uv = un.uv, un.faces
    s = rasterize(uv, faces_uv, R, R, 1, 0)
    density = chart_texel_density(uv, faces_uv, scene.vertices, scene.faces, R, R)
    p5, p95 = np.percentile(density, [5, 95])
    print(json.dumps({"coverage": np.unique(s.texel).size / R**2, "charts": len(density),
                      "p5": p5, "p95": p95, "seconds": seconds}))
""")


def measure(mesh: Path, resolution: int, padding: int, how: str, old: str = "-") -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(ROOT), str(mesh), str(resolution),
                          str(padding), how, old], capture_output=True, text=True, timeout=3600)
    if out.returncode != 0:
        raise RuntimeError(f"{mesh.name} {how}: {out.stderr.strip().splitlines()[-1:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=1024)
    parser.add_argument("--paddings", default="8,2", help="comma-separated (8 was the default, 2 is)")
    parser.add_argument("--repeat", type=int, default=3, help="unwrap runs; the minimum is shown")
    parser.add_argument("--old", metavar="REV", help="also the unwrapper of this git revision")
    parser.add_argument("--baseline", action="store_true",
                        help="also xatlas's default charting packed by xatlas (slow)")
    args = parser.parse_args()
    meshes = {name: SHARED / f"{name}.obj" for name in ("spot", "stanford-bunny", "ogre")}
    if not all(m.is_file() for m in meshes.values()):
        sys.exit("benchmarks need ../shared/meshes (spot.obj, stanford-bunny.obj, ogre.obj)")
    paddings = [int(p) for p in args.paddings.split(",")]
    old_file = None
    if args.old:
        text = subprocess.run(["git", "-C", str(ROOT), "show",
                               f"{args.old}:aobake/targets/texels/unwrap.py"],
                              capture_output=True, text=True, check=True).stdout
        old_file = Path(tempfile.mkdtemp(prefix="aobake-bench-")) / "unwrap_old.py"
        old_file.write_text(text)
    rows = []
    for name, path in meshes.items():
        if name == "spot":
            rows.append((name, "own UVs", "-", measure(path, args.resolution, 0, "own")))
        for padding in paddings:
            kinds = [("new atlas", "new", "-")]
            if old_file:
                kinds.append((f"atlas of {args.old}", "new", str(old_file)))
            if args.baseline:
                kinds.append(("xatlas default", "baseline", "-"))
            for label, how, old in kinds:
                runs = [measure(path, args.resolution, padding, how, old)
                        for _ in range(args.repeat if how == "new" else 1)]
                best = dict(runs[0], seconds=min(r["seconds"] for r in runs))
                rows.append((name, label, padding, best))
    print(f"{args.resolution}^2; unwrap seconds: minimum of {args.repeat} runs "
          "(in-process, without the bake's ~0.3 s child process)\n")
    print("| mesh | atlas | padding | charts | coverage | density p5 | density p95 | p95/p5 "
          "| unwrap s |")
    print("|" + "---|" * 9)
    for name, label, padding, r in rows:
        seconds = "-" if r["seconds"] is None else f"{r['seconds']:.2f}"
        print(f"| {name} | {label} | {padding} | {r['charts']} | {r['coverage']:.1%} | "
              f"{r['p5']:.4g} | {r['p95']:.4g} | {r['p95'] / r['p5']:.3f} | {seconds} |")


if __name__ == "__main__":
    main()
