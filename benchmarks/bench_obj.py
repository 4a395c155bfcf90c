"""OBJ reading: aobake's reader against trimesh's loader on the meshes in ../shared/meshes.

    python benchmarks/bench_obj.py [--repeat 5] [MESH.obj ...]

Prints a markdown table of seconds per read, the minimum of ``--repeat`` runs (another
process may share the machine; the minimum is the least disturbed run):

* ``read_obj``: what ``load_scene`` calls (the vectorised path when the file is in its
  forms, else the line-by-line one); the "path" column says which one ran;
* ``line by line``: the line-by-line reader alone (``aobake.obj._read_slow``, the reader
  before the vectorised path existed), on the already decoded text plus the file read;
* ``trimesh``: ``trimesh.load(path, process=False)``, a peer figure (its results differ on
  the files it gets wrong, see aobake/obj.py).

Before timing, each mesh is read both ways and the two ObjData compared array by array,
bit for bit (the run stops if they differ).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import fields
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from aobake import obj  # noqa: E402

MESHES = Path(__file__).resolve().parents[2] / "shared" / "meshes"
DEFAULT = [MESHES / name for name in ("stanford-bunny.obj", "spot.obj", "ogre.obj")]


def best_of(repeat: int, function) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def identical(a, b) -> bool:
    for f in fields(obj.ObjData):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if not (isinstance(x, np.ndarray) and isinstance(y, np.ndarray)
                    and x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()):
                return False
        elif x != y:
            return False
    return True


def slow(path):
    data, text, _ = obj._read_text(path)
    return obj._read_slow(path, text)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("meshes", nargs="*", type=Path, default=DEFAULT)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    import trimesh

    print(f"Seconds per read, minimum of {args.repeat} runs.\n")
    print("| mesh | vertices | triangles | read_obj | path | line by line | trimesh "
          "| read_obj / trimesh |")
    print("|---|---|---|---|---|---|---|---|")
    for path in args.meshes:
        if not path.is_file():
            sys.exit(f"{path}: not found (benchmarks use ../shared/meshes)")
        data, text, encoding = obj._read_text(path)
        fast = obj._read_fast(path, data, text, encoding)
        reference = obj._read_slow(path, text)
        if fast is not None and not identical(fast, reference):
            sys.exit(f"{path}: the vectorised and line-by-line readers differ")
        t_read = best_of(args.repeat, lambda: obj.read_obj(path))
        t_slow = best_of(args.repeat, lambda: slow(path))
        t_trimesh = best_of(args.repeat, lambda: trimesh.load(path, process=False))
        print(f"| {path.name} | {len(reference.vertices):,} | {len(reference.faces):,} "
              f"| {t_read:.3f} | {'vectorised' if fast is not None else 'line by line'} "
              f"| {t_slow:.3f} | {t_trimesh:.3f} | {t_read / t_trimesh:.2f} |")


if __name__ == "__main__":
    main()
