"""What ``--alpha-cutout`` costs: the Stanford bunny under a canopy of leaf cards (glTF,
alphaMode MASK, a blotchy alpha texture about half opaque), baked per vertex with the cards
opaque (the option off) and cut out (on), for AO (occlusion queries: the cards are asked only
about rays the bunny left open) and obscurance (distance queries: every ray).  Prints a table
of trace seconds, rays per second and how many rays the cut-out pass cast (first casts plus
recasts past cut-out texels).

    python benchmarks/bench_cutout.py [--cards 256] [--rays 64] [--threads 2] [--meshes DIR]

Needs ../shared/meshes beside the checkout (or --meshes).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # the tests' glTF scene writer

import aobake  # noqa: E402
from gltf_scenes import png, write_gltf  # noqa: E402

MESHES = ROOT.parent / "shared" / "meshes"


def leaf_alpha(size: int = 64, seed: int = 0) -> bytes:
    """RGBA PNG bytes: white, alpha 255 inside ~12 random discs (about half the texels)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size] / size
    inside = np.zeros((size, size), dtype=bool)
    for cx, cy, r in zip(rng.random(12), rng.random(12), 0.1 + 0.1 * rng.random(12)):
        inside |= (x - cx) ** 2 + (y - cy) ** 2 < r * r
    return png(np.where(inside, 255, 0).astype(np.uint8))


def cards(mesh, count: int, seed: int = 1):
    """(vertices, faces, uv) of ``count`` square cards on a dome over the mesh, facing it."""
    rng = np.random.default_rng(seed)
    lo, hi = mesh.bounds
    center, diagonal = (lo + hi) / 2, float(np.linalg.norm(hi - lo))
    up = np.array([0.0, 1.0, 0.0])
    vertices, faces, uv = [], [], []
    for i in range(count):
        d = rng.normal(size=3)
        d[1] = abs(d[1]) + 0.3
        d /= np.linalg.norm(d)
        p = center + d * diagonal * rng.uniform(0.45, 0.75)
        a = np.cross(d, up if abs(d @ up) < 0.9 else np.array([1.0, 0.0, 0.0]))
        a /= np.linalg.norm(a)
        b = np.cross(d, a)
        h = 0.12 * diagonal
        vertices.append([p - h * a - h * b, p + h * a - h * b, p + h * a + h * b,
                         p - h * a + h * b])
        faces.append(np.array([[0, 2, 1], [0, 3, 2]]) + 4 * i)  # facing the mesh
        uv.append([[0, 1], [1, 1], [1, 0], [0, 0]])
    return (np.concatenate(vertices), np.concatenate(faces), np.concatenate(uv).astype(float))


def write_scene(path: Path, mesh, card_mesh) -> Path:
    """A .gltf: the mesh (OPAQUE) and the cards (MASK, cutoff 0.5, the leaf texture)."""
    v, f, uv = card_mesh
    write_gltf(path, [
        {"vertices": np.asarray(mesh.vertices), "faces": np.asarray(mesh.faces),
         "uv": np.zeros((len(mesh.vertices), 2)), "material": {"alphaMode": "OPAQUE"}},
        {"vertices": v, "faces": f, "uv": uv,
         "material": {"alphaMode": "MASK", "alphaCutoff": 0.5, "png": leaf_alpha()}}])
    return path


class Counting:
    """Counts the rays the closest-hit queries cast (recasts included): in a bake of
    occlusion or distance queries (``--backfaces count``) only the cut-out member asks them."""

    def __init__(self):
        import threading

        from aobake.backends import native
        from aobake.backends.embree import EmbreeBackend

        self.rays, self._lock, self._cls = 0, threading.Lock(), EmbreeBackend
        self._intersect = inner = EmbreeBackend.intersect
        counter = self

        def counted(backend, origins, directions, tmax):
            with counter._lock:
                counter.rays += len(origins)
            return inner(backend, origins, directions, tmax)
        EmbreeBackend.intersect = counted
        # the compiled cut-out march (aobake._embree) returns the rays it cast
        self._module = (native.binding() or (None,))[0]
        if self._module is not None:
            self._march = march = self._module.march

            def counted_march(*args):
                cast = march(*args)
                with counter._lock:
                    counter.rays += cast
                return cast
            self._module.march = counted_march

    def close(self):
        self._cls.intersect = self._intersect
        if self._module is not None:
            self._module.march = self._march


def main(argv=None) -> list:
    import trimesh

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cards", type=int, default=256)
    parser.add_argument("--rays", type=int, default=64)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=2, help="best of this many bakes")
    parser.add_argument("--meshes", type=Path, default=MESHES, help="where stanford-bunny.obj is")
    args = parser.parse_args(argv)
    mesh = trimesh.load(args.meshes / "stanford-bunny.obj", process=False)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        path = write_scene(Path(tmp) / "canopy.gltf", mesh, cards(mesh, args.cards))
        for quantity in ("ao", "obscurance"):
            for on in (False, True):
                best, counter = None, Counting()
                try:
                    for _ in range(args.repeat):
                        counter.rays = 0
                        result = aobake.bake(path, quantities=(quantity,), rays=args.rays,
                                             alpha_cutout=on, threads=args.threads)
                        seconds = result.report["timings"]["trace_s"]
                        best = seconds if best is None else min(best, seconds)
                finally:
                    counter.close()
                cast = int(result.rays.astype(np.int64).sum())
                rows.append({"quantity": quantity, "alpha_cutout": on, "trace_s": best,
                             "mrays_s": cast / best / 1e6, "rays": cast,
                             "cutout_rays": counter.rays,
                             "mean": float(getattr(result, quantity).mean())})
    print(f"bunny {len(mesh.faces)} triangles + {args.cards} leaf cards, {args.rays} rays per "
          f"vertex, {args.threads} threads (best of {args.repeat})\n")
    print("| quantity | --alpha-cutout | trace s | Mrays/s | cost | cut-out pass rays "
          "(per ray) | mean value |")
    print("|---|---|---|---|---|---|---|")
    for row in rows:
        base = next(r for r in rows if r["quantity"] == row["quantity"]
                    and not r["alpha_cutout"])
        print(f"| {row['quantity']} | {'on' if row['alpha_cutout'] else 'off'} | "
              f"{row['trace_s']:.2f} | {row['mrays_s']:.2f} | "
              f"{row['trace_s'] / base['trace_s']:.2f}x | {row['cutout_rays']} "
              f"({row['cutout_rays'] / row['rays']:.2f}) | {row['mean']:.4f} |")
    return rows


if __name__ == "__main__":
    main()
