"""--fix-normals on a real mesh: what the detector flags, and per-vertex AO against a
reference before and after the repair.

    python benchmarks/bench_repair.py [--mesh ../shared/meshes/ogre.obj] [--rays 256]
                                      [--reference-rays 16384] [--flip 0.02] [--threads 2]

Cases, each baked at --rays (seed 0) with --fix-normals warn (as given: nothing changes)
and fix, and compared per vertex with one reference of the mesh *as published* at
--reference-rays (seed 1, so its errors are independent of the candidates'):

* ``as given``: the file itself;
* ``F% flipped``: a seeded random fraction F of its faces wound the other way (corners 1
  and 2 swapped), the damage an exporter or a hand edit does;
* ``reversed``: every face wound the other way (a mesh turned inside out).

The mesh has no ``vn``: vertex normals are angle-weighted from the winding, so a flipped
face bends its corners' normals and an inward shell turns them round.  RMSE is over the
vertices both bakes traced; ``ref. noise`` is the reference's RMS stderr (its share of the
RMSE: sqrt(RMSE^2 - noise^2) is the candidate's own error).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import aobake  # noqa: E402
from aobake import repair  # noqa: E402
from aobake.scene import load_scene, make_scene  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "meshes"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mesh", type=Path, default=SHARED / "ogre.obj")
    parser.add_argument("--rays", type=int, default=256)
    parser.add_argument("--reference-rays", type=int, default=16384)
    parser.add_argument("--flip", type=float, default=0.02, help="fraction of faces flipped")
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args(argv)

    given = load_scene(args.mesh, fix_normals="off")
    faces = given.faces
    rng = np.random.default_rng(2024)
    flipped = rng.random(len(faces)) < args.flip
    cases = {
        "as given": faces,
        f"{100 * args.flip:g}% flipped": repair.flip_faces(faces, flipped),
        "reversed": repair.flip_faces(faces, np.ones(len(faces), dtype=bool)),
    }

    print(f"{args.mesh.name}: {len(given.vertices)} vertices, {len(faces)} faces; "
          f"reference {args.reference_rays} rays (seed 1), candidates {args.rays} rays (seed 0)")
    reference = aobake.bake(given, rays=args.reference_rays, seed=1, threads=args.threads)
    noise = reference.ao_stderr

    print("\n| case | faces flagged (against neighbours) | components flagged | "
          "inward components | faces flipped by fix | RMSE warn | RMSE fix | ref. noise |")
    print("|---|---|---|---|---|---|---|---|")
    for name, case_faces in cases.items():
        rmse, record = {}, None
        for mode in ("warn", "fix"):
            scene = make_scene(given.vertices, case_faces, source=name, fix_normals=mode)
            result = aobake.bake(scene, rays=args.rays, seed=0, threads=args.threads)
            both = (result.rays > 0) & (reference.rays > 0)
            rmse[mode] = float(np.sqrt(np.mean((result.ao[both] - reference.ao[both]) ** 2)))
            if mode == "fix":
                record = scene.repair
                ref_noise = float(np.sqrt(np.mean(noise[both] ** 2)))
        print(f"| {name} | {record['faces_against_neighbours']} | "
              f"{record['components_with_faces_against']} of {record['components']} "
              f"({record['closed_components']} closed, {record['nearly_closed_components']} "
              f"nearly) | {record['inward_components']} | "
              f"{record['faces_flipped']} | {rmse['warn']:.4f} | {rmse['fix']:.4f} | "
              f"{ref_noise:.4f} |")
    print(f"\n(flipped case: {int(flipped.sum())} faces were wound the other way)")


if __name__ == "__main__":
    main()
