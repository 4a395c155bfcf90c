"""Bake a fixed set of outputs, or compare two such sets bit for bit.

A refactoring must not change what a user gets.  Run ``bake`` on the tree before
the change and on the tree after it, then ``compare``:

    python benchmarks/golden_outputs.py bake /tmp/before [--shared ../shared/meshes]
    python benchmarks/golden_outputs.py bake /tmp/after  [--shared ../shared/meshes]
    python benchmarks/golden_outputs.py compare /tmp/before /tmp/after

``compare`` checks every array (NPZ arrays, PLY vertex data, EXR/PNG pixels, OBJ
text, GLB binary chunk) for identical bits and prints the metadata keys whose
values differ (timings and versions are expected to; anything else is shown so a
person decides).  Exit status 1 if any array differs.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
ASSETS = ROOT / "assets"

#: (name, mesh (relative to assets/ or shared/), output suffix, CLI options)
CASES = [
    ("still_npz", "assets:still_life.obj", ".npz",
     ["-q", "ao", "-q", "obscurance", "-q", "bent-normal", "--max-distance", "10%", "--rays", "64"]),
    ("still_ply", "assets:still_life.obj", ".ply", ["--rays", "64"]),
    ("still_glb", "assets:still_life.obj", ".glb", ["--rays", "32", "-q", "ao", "-q", "bent-normal"]),
    ("still_random", "assets:still_life.obj", ".npz",
     ["--sampler", "random", "--rays", "50", "--weighting", "uniform", "--ground-plane"]),
    ("still_strat", "assets:still_life.obj", ".npz",
     ["--sampler", "stratified", "--rays", "40", "--backfaces", "ignore", "-q", "obscurance",
      "--tau", "3"]),
    ("torus_exr", "assets:torus_uv.obj", ".exr",
     ["--resolution", "128", "--rays", "32", "-q", "ao", "-q", "obscurance", "-q", "bent-normal"]),
    ("torus_tangent", "assets:torus_uv.obj", ".exr",
     ["--resolution", "96x64", "--rays", "16", "-q", "bent-normal", "--bent-space", "tangent"]),
    ("still_exr", "assets:still_life.obj", ".exr", ["--resolution", "256", "--rays", "16"]),
    ("still_png", "assets:still_life.obj", ".png", ["--resolution", "256", "--padding", "2", "--rays", "16",
                                                  "--bit-depth", "16"]),
    ("torus_glbtex", "assets:torus_uv.obj", ".glb", ["--target", "texels", "--resolution", "64", "--padding", "2",
                                                    "--rays", "16"]),
    ("still_tol", "assets:still_life.obj", ".npz",
     ["--tolerance", "0.05", "--rays", "16", "--max-rays", "256", "-q", "ao", "-q", "obscurance"]),
    ("still_keep", "assets:still_life.obj", ".npz", ["--keep-distances", "--rays", "16",
                                                    "-q", "obscurance"]),
    ("torus_tol", "assets:torus_uv.obj", ".exr", ["--resolution", "64", "--tolerance", "0.1",
                                                 "--rays", "8", "--max-rays", "64"]),
    ("bunny_npz", "shared:stanford-bunny.obj", ".npz",
     ["--rays", "64", "-q", "ao", "-q", "obscurance", "-q", "bent-normal"]),
    ("bunny_exr", "shared:stanford-bunny.obj", ".exr", ["--resolution", "512", "--rays", "16"]),
    ("spot_exr", "shared:spot.obj", ".exr", ["--resolution", "256", "--rays", "32", "-q", "ao",
                                             "-q", "bent-normal"]),
    ("spot_own", "shared:spot.obj", ".exr", ["--resolution", "256", "--rays", "16",
                                             "--no-unwrap"]),
]


def bake(out_dir: Path, shared: Path | None) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    for name, mesh, suffix, options in CASES:
        where, file = mesh.split(":")
        if where == "shared":
            if shared is None:
                continue
            path = shared / file
        else:
            path = ASSETS / file
        out = out_dir / f"{name}{suffix}"
        cmd = [sys.executable, "-m", "aobake", str(path), "--out", str(out), "--quiet",
               "--report", str(out_dir / f"{name}.json"), *options]
        if suffix in (".exr", ".png") or "--target" in options:
            cmd += ["--mesh-out", str(out_dir / f"{name}_mesh.obj")]
        subprocess.run(cmd, check=True, cwd=out_dir)
        print(f"baked {name}")


def _arrays(path: Path) -> dict:
    """Comparable arrays of one output file, and its metadata (dict) under '__metadata__'."""
    suffix = path.suffix.lower()
    if suffix == ".npz":
        with np.load(path) as data:
            out = {k: data[k] for k in data.files if k != "metadata"}
            out["__metadata__"] = json.loads(str(data["metadata"]))
        return out
    if suffix in (".exr", ".png"):
        import OpenImageIO as oiio

        image = oiio.ImageInput.open(str(path))
        spec = image.spec()
        pixels = image.read_image(format=spec.format)
        meta = {a.name: a.value for a in spec.extra_attribs}
        image.close()
        return {"pixels": np.asarray(pixels), "channels": np.array(list(spec.channelnames)),
                "__metadata__": meta}
    raw = path.read_bytes()
    if suffix == ".glb":
        import struct

        json_len = struct.unpack_from("<I", raw, 12)[0]
        gltf = json.loads(raw[20:20 + json_len])
        meta = gltf.get("asset", {}).get("extras", {})
        gltf.get("asset", {}).pop("extras", None)
        return {"binary": np.frombuffer(raw[20 + json_len:], dtype=np.uint8),
                "gltf": np.frombuffer(json.dumps(gltf, sort_keys=True).encode(), dtype=np.uint8),
                "__metadata__": meta}
    if suffix == ".ply":
        end = raw.index(b"end_header\n") + len(b"end_header\n")
        header = [line for line in raw[:end].decode().splitlines() if not line.startswith("comment")]
        comments = [line for line in raw[:end].decode().splitlines() if line.startswith("comment")]
        return {"header": np.array(header), "body": np.frombuffer(raw[end:], dtype=np.uint8),
                "__metadata__": {"comments": comments}}
    if suffix == ".obj":
        lines = raw.decode().splitlines()
        return {"body": np.array([line for line in lines if not line.startswith("#")]),
                "__metadata__": {}}
    return {"raw": np.frombuffer(raw, dtype=np.uint8), "__metadata__": {}}


def _flat(d, prefix=""):
    if isinstance(d, dict):
        out = {}
        for k, v in d.items():
            out.update(_flat(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: d}


def compare(a_dir: Path, b_dir: Path) -> int:
    bad = 0
    for a in sorted(a_dir.iterdir()):
        if a.suffix == ".json":
            continue
        b = b_dir / a.name
        if not b.exists():
            print(f"MISSING {a.name}")
            bad += 1
            continue
        x, y = _arrays(a), _arrays(b)
        mx, my = x.pop("__metadata__"), y.pop("__metadata__")
        for key in sorted(set(x) | set(y)):
            if key not in x or key not in y:
                print(f"DIFF {a.name}: array {key} only in one")
                bad += 1
            elif x[key].dtype != y[key].dtype or x[key].shape != y[key].shape or \
                    x[key].tobytes() != y[key].tobytes():
                print(f"DIFF {a.name}: array {key}")
                bad += 1
        fx, fy = _flat(mx), _flat(my)
        changed = sorted(k for k in set(fx) | set(fy) if fx.get(k) != fy.get(k))
        if changed:
            print(f"meta {a.name}: {', '.join(changed)}")
    for a in sorted(a_dir.glob("*.json")):
        b = b_dir / a.name
        if not b.exists():
            continue
        fx, fy = _flat(json.loads(a.read_text())), _flat(json.loads(b.read_text()))
        changed = sorted(k for k in set(fx) | set(fy) if fx.get(k) != fy.get(k)
                         and "time" not in k and not k.endswith("_s") and "per_second" not in k)
        if changed:
            print(f"report {a.name}: {', '.join(changed)}")
    print("identical arrays" if not bad else f"{bad} differences")
    return 1 if bad else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("bake")
    p.add_argument("out", type=Path)
    p.add_argument("--shared", type=Path, default=ROOT.parent / "shared" / "meshes")
    c = sub.add_parser("compare")
    c.add_argument("a", type=Path)
    c.add_argument("b", type=Path)
    args = parser.parse_args()
    if args.cmd == "bake":
        bake(args.out.resolve(), args.shared if args.shared.is_dir() else None)
        return 0
    return compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
