"""--denoise against the truth: RMSE and bias of the raw and the denoised AO against a
high-ray reference of another seed, over all covered texels and on creases, at 64 and 256
rays.

    python benchmarks/bench_denoise.py [--resolution 512] [--rays 64 256]
                                       [--reference-rays 4096] [--threads 2] [--figures DIR]

Cases: assets/still_life.obj (boxes, a sphere and a torus knot on a floor: sharp edges and
contact shadows, a new atlas) and ../shared/meshes/stanford-bunny.obj (a new atlas).  The
reference is baked with --reference-rays per texel over 16 texel samples at seed 1; it has
no denoising.  Every bake shares the atlas (xatlas charting does not depend on the seed).

- rmse: root mean square of (value - reference) over the texels, and ``excess``, the part
  the reference's own noise does not explain: sqrt(max(0, rmse^2 - mean se_ref^2));
- bias: the mean of (value - reference);
- creases: texels within 2 sigma of the filter (4 texels, on the surface) of a texel whose
  normal differs by more than 30 degrees: sharp edges, and where objects meet the floor.
With --figures, writes DIR/denoise_<mesh>.png: raw | denoised | reference at the lowest
ray count, on the crop of the map with the most crease texels.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from aobake.api import bake_texels  # noqa: E402
from aobake.scene import load_scene  # noqa: E402
from aobake.targets.texels.raster import rasterize  # noqa: E402
from aobake.targets.texels.surface import surface_points  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "meshes"


def crease_mask(path, result, spacing: float) -> np.ndarray:
    """(H, W) bool covered texels near a normal discontinuity (see the module docstring)."""
    from scipy.spatial import cKDTree

    scene = load_scene(path)
    atlas = result.atlas
    height, width = result.covered.shape
    samples = rasterize(atlas.uv, atlas.faces, width, height, 1, 0)
    points, normals, _ = surface_points(scene.vertices, scene.vertex_normals, scene.faces,
                                        samples)
    tree = cKDTree(points)
    pairs = tree.query_pairs(4.0 * spacing, output_type="ndarray")
    sharp = np.einsum("nd,nd->n", normals[pairs[:, 0]], normals[pairs[:, 1]]) < np.cos(
        np.radians(30.0))
    near = np.zeros(len(points), bool)
    near[pairs[sharp].ravel()] = True
    mask = np.zeros(width * height, bool)
    mask[samples.texel[near]] = True
    return mask.reshape(height, width) & result.covered


def errors(value, reference, ref_se, mask) -> dict:
    d = value[mask].astype(np.float64) - reference[mask]
    rmse = float(np.sqrt(np.mean(d * d)))
    noise = float(np.mean(ref_se[mask].astype(np.float64) ** 2))
    return {"n": int(mask.sum()), "rmse": rmse, "excess": float(np.sqrt(max(0.0, rmse ** 2 - noise))),
            "bias": float(d.mean())}


def crop(mask, size: int) -> tuple[slice, slice]:
    """The size x size window (on a size/4 grid) holding the most True texels of mask."""
    height, width = mask.shape
    step = max(size // 4, 1)
    best, where = -1, (0, 0)
    for r in range(0, max(height - size, 0) + 1, step):
        for c in range(0, max(width - size, 0) + 1, step):
            count = int(mask[r:r + size, c:c + size].sum())
            if count > best:
                best, where = count, (r, c)
    return slice(where[0], where[0] + size), slice(where[1], where[1] + size)


def figure(out: Path, name: str, rays: int, raw, denoised, reference, window) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 4.3))
    for ax, image, title in zip(axes, (raw, denoised, reference),
                                (f"raw, {rays} rays", f"--denoise, {rays} rays",
                                 "reference")):
        ax.imshow(image[window], cmap="gray", vmin=0, vmax=1, interpolation="nearest")
        ax.set_title(title)
        ax.axis("off")
    fig.suptitle(f"{name}: AO lightmap crop")
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / f"denoise_{Path(name).stem}.png", dpi=80)
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--resolution", type=int, default=512)
    parser.add_argument("--rays", type=int, nargs="+", default=[64, 256])
    parser.add_argument("--reference-rays", type=int, default=4096)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--figures", type=Path, default=None)
    parser.add_argument("--mesh", nargs="+", default=None)
    args = parser.parse_args()
    meshes = [Path(m) for m in args.mesh] if args.mesh else [
        ROOT / "assets" / "still_life.obj", SHARED / "stanford-bunny.obj"]
    meshes = [m for m in meshes if m.is_file()]
    common = dict(resolution=args.resolution, threads=args.threads, unwrap="always")
    print(f"resolution {args.resolution}^2, padding 2, 4 texel samples; reference "
          f"{args.reference_rays} rays over 16 samples, seed 1\n")
    print("| mesh | rays | texels | rmse raw | rmse denoised | excess raw | excess denoised | "
          "bias raw | bias denoised | crease texels | crease rmse raw | crease rmse denoised | "
          "crease bias raw | crease bias denoised | denoise s | trace s |")
    print("|" + "---|" * 16)
    for path in meshes:
        ref = bake_texels(path, rays=args.reference_rays, texel_samples=16, seed=1, **common)
        r_ao, r_se = ref.channels["ao"], ref.channels["ao_stderr"]
        spacing = 1.0 / ref.report["texture"]["texel_density"]
        creases = crease_mask(path, ref, spacing)
        for i, rays in enumerate(args.rays):
            res = bake_texels(path, rays=rays, seed=0, denoise=True, **common)
            # the same texels as the reference's (xatlas charting does not use the seed)
            assert np.array_equal(res.atlas.uv, ref.atlas.uv), "the atlases differ"
            mask = res.covered & ref.covered
            out = []
            for region in (mask, mask & creases):
                out.append((errors(res.channels["ao"], r_ao, r_se, region),
                            errors(res.channels["ao_denoised"], r_ao, r_se, region)))
            (a_raw, a_den), (c_raw, c_den) = out
            t = res.report["timings"]
            print(f"| {path.name} | {rays} | {a_raw['n']} | {a_raw['rmse']:.4f} | "
                  f"{a_den['rmse']:.4f} | {a_raw['excess']:.4f} | {a_den['excess']:.4f} | "
                  f"{a_raw['bias']:+.4f} | {a_den['bias']:+.4f} | {c_raw['n']} | "
                  f"{c_raw['rmse']:.4f} | {c_den['rmse']:.4f} | {c_raw['bias']:+.4f} | "
                  f"{c_den['bias']:+.4f} | {t['denoise_s']:.2f} | {t['trace_s']:.2f} |",
                  flush=True)
            if args.figures and i == 0:
                window = crop(creases, min(160, args.resolution))
                figure(args.figures, path.name, rays, res.channels["ao"],
                       res.channels["ao_denoised"], r_ao, window)


if __name__ == "__main__":
    main()
