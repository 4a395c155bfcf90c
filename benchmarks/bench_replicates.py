"""--replicates: what fewer or more replicates per point do to the error of the value, the
steadiness of its stderr and the width of its interval, on real meshes.

    python benchmarks/bench_replicates.py [--mesh ../shared/meshes/stanford-bunny.obj ...]
                                          [--rays 64 128 256] [--replicates 2 4 8 16]
                                          [--reference-rays 4096] [--threads 2]

Per mesh, one reference (sobol, --reference-rays, 8 replicates, seed 1) and, per ray count
and replicate count, one bake (sobol, seed 0), over the vertices with a normal:

- excess: the RMS error the reference's own noise does not explain,
  sqrt(max(0, RMSE^2 - mean se_ref^2));
- rms stderr: what the bake says about itself (RMS-calibrated when it is close to excess);
- stderr CV: how unsteady one point's stderr is, the coefficient of variation that R - 1
  degrees of freedom give it, about sqrt(1 / (2 (R - 1)));
- half-width: the mean half-width of the 95% interval (t quantile on R - 1 dof);
- coverage: the share of vertices whose interval holds the reference value (the reference
  has its own noise, so this is a lower bound on coverage of the truth for tight bakes).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import aobake  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "meshes"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mesh", nargs="+", type=Path,
                        default=[SHARED / "stanford-bunny.obj", SHARED / "ogre.obj"])
    parser.add_argument("--rays", type=int, nargs="+", default=[64, 128, 256])
    parser.add_argument("--replicates", type=int, nargs="+", default=[2, 4, 8, 16])
    parser.add_argument("--reference-rays", type=int, default=4096)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    print("| mesh | rays | R | excess RMSE | rms stderr | stderr CV (t) | mean 95% half-width | "
          "coverage of the reference |")
    print("|---|---|---|---|---|---|---|---|")
    for path in args.mesh:
        ref = aobake.bake(path, rays=args.reference_rays, seed=1, threads=args.threads)
        ok = ref.rays > 0
        noise = float(np.mean(ref.ao_stderr[ok].astype(np.float64) ** 2))
        for rays in args.rays:
            for r in args.replicates:
                res = aobake.bake(path, rays=rays, replicates=r, seed=0, threads=args.threads)
                m = ok & (res.rays > 0)
                d = res.ao[m].astype(np.float64) - ref.ao[m]
                excess = float(np.sqrt(max(0.0, np.mean(d * d) - noise)))
                se = float(np.sqrt(np.mean(res.ao_stderr[m].astype(np.float64) ** 2)))
                half = float(np.mean(res.ao_ci_high[m] - res.ao_ci_low[m]) / 2)
                cover = float(np.mean((res.ao_ci_low[m] <= ref.ao[m])
                                      & (ref.ao[m] <= res.ao_ci_high[m])))
                cv = (1.0 / (2.0 * (r - 1))) ** 0.5
                print(f"| {path.name} | {int(res.rays[m].max())} | {r} | "
                      f"{excess:.5f} | {se:.5f} | {cv:.2f} | {half:.4f} | {cover:.3f} |",
                      flush=True)


if __name__ == "__main__":
    main()
