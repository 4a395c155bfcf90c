"""High-to-low on a scan: the Stanford bunny decimated to ~2k triangles, baked from the
original (69k triangles) through a cage.  Prints the misses of a sweep of cage offsets and
the time of each step of one bake; with --figures DIR writes docs/studio.md's pictures.

    pip install fast-simplification      # the decimator (benchmarks only)
    python benchmarks/bench_studio.py --figures docs/img

Needs ../shared/meshes beside the checkout.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

import aobake
from aobake.settings import BakeConfig
from aobake.occluders import build
from aobake.scene import load_scene, make_scene
from aobake.api import bake_projected

MESHES = Path(__file__).resolve().parents[2] / "shared" / "meshes"
#: cage offsets swept, in percent of the low mesh's diagonal
SWEEP = ("0.1%", "0.25%", "0.5%", "1%", "2%", "4%")


def decimate(path: Path, triangles: int, out: Path) -> tuple[Path, float]:
    """``path`` decimated to about ``triangles`` (fast-simplification's quadric decimation),
    written as OBJ (no UVs: the bake makes an atlas); returns (path, seconds)."""
    import fast_simplification
    import trimesh

    mesh = trimesh.load(path, process=False)
    clock = time.perf_counter()
    vertices, faces = fast_simplification.simplify(mesh.vertices, mesh.faces,
                                                   target_count=triangles)
    seconds = time.perf_counter() - clock
    trimesh.Trimesh(vertices, faces, process=False).export(out)
    return out, seconds


def sweep(low, high, threads: int) -> list:
    """Misses and back hits of every cage offset of SWEEP (512², 4 rays: the projection is
    what is measured)."""
    rows = []
    for offset in SWEEP:
        res = bake_projected(low, high, cage_offset=offset, resolution=512, rays=4,
                             threads=threads)
        p = res.report["projection"]
        rows.append({"offset": offset, "offset_units": p["cage"]["offset"],
                     "samples": p["points"], "missed": p["missed"], "back": p["back"],
                     "texels": p["texels"]["charted"],
                     "texels_missed_any": p["texels"]["missed_any"],
                     "texels_missed_all": p["texels"]["missed_all"],
                     "projection_s": res.report["timings"]["projection_s"],
                     "result": res})
    return rows


def render(scene, shade, size=(480, 480), up_axis="y"):
    """(H, W, 3) float image of ``scene`` from the default three-quarter camera, white where
    no surface: ``shade(prim (k,), bary (k, 3), normal (k, 3)) -> (k, 3)`` colours the hits."""
    from aobake.hits import on_triangle

    lo, hi = scene.bounds
    from aobake import camera as cameras

    cam = cameras.default_camera(lo, hi, size, 30.0, up_axis=up_axis)
    origins, directions = cam.pixel_rays()
    occluders = build(scene, BakeConfig())
    t, prim, _ = occluders.first_hits(origins, directions)
    hit = prim >= 0
    image = np.ones((len(t), 3))
    points = origins[hit] + t[hit, None] * directions[hit]
    _, bary = on_triangle(scene, prim[hit], points)
    normal = scene.face_normals[prim[hit]]
    image[hit] = shade(prim[hit], bary, normal)
    return image.reshape(cam.height, cam.width, 3)


def lookup(image, uv):
    """Bilinear lookup of ``image`` (H, W) at ``uv`` (k, 2) (texel centres at (c + 0.5) / W,
    v = 1 - (r + 0.5) / H; clamped)."""
    h, w = image.shape
    x = np.clip(uv[:, 0] * w - 0.5, 0, w - 1)
    y = np.clip((1 - uv[:, 1]) * h - 0.5, 0, h - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = x - x0, y - y0
    return ((image[y0, x0] * (1 - fx) + image[y0, x1] * fx) * (1 - fy)
            + (image[y1, x0] * (1 - fx) + image[y1, x1] * fx) * fy)


def textured(result, channel: str, colour=None):
    """A shade function of the atlas mesh of ``result`` reading ``channel``."""
    atlas = result.atlas
    image = result.channels[channel].astype(np.float64)

    def shade(prim, bary, normal):
        uv = np.einsum("kc,kcd->kd", bary, atlas.uv[atlas.faces[prim]])
        value = lookup(image, uv)
        if colour is None:
            return np.repeat(value[:, None], 3, axis=1)
        grey = np.full((len(value), 3), 0.8)
        return grey * (1 - value[:, None]) + np.asarray(colour) * value[:, None]
    return shade


def atlas_scene(result):
    atlas = result.atlas
    return make_scene(atlas.positions, atlas.faces, normals_mode="angle")


def figures(out: Path, low, high, rows, result, threads: int):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # 1. the source, the low mesh, the low mesh with its map
    source = aobake.bake(high, rays=256, threads=threads)
    high_scene = load_scene(high)
    low_scene = atlas_scene(result)
    light = np.array([0.4, 0.8, 0.6]) / np.linalg.norm([0.4, 0.8, 0.6])

    def vertex_ao(prim, bary, normal):
        value = np.einsum("kc,kc->k", bary, source.ao[high_scene.faces[prim]])
        return np.repeat(value[:, None], 3, axis=1)

    def flat(prim, bary, normal):
        value = 0.25 + 0.75 * np.clip(normal @ light, 0, 1)
        return np.repeat(value[:, None], 3, axis=1)
    panels = [(render(high_scene, vertex_ao), f"source: {len(high_scene.faces)} triangles, "
               "AO per vertex"),
              (render(low_scene, flat), f"low: {len(low_scene.faces)} triangles"),
              (render(low_scene, textured(result, "ao")),
               f"low + baked map ({result.channels['ao'].shape[1]}²)")]
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.3))
    for ax, (image, title) in zip(axes, panels):
        ax.imshow(np.clip(image, 0, 1))
        ax.set_title(title, fontsize=10)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(out / "studio_bunny.png", dpi=100)
    plt.close(fig)

    # 2. the missed-ray masks: a cage too tight and one about right, on the model and the map
    tight, right = rows[0], next(r for r in rows if r["offset"] == "1%")
    fig, axes = plt.subplots(2, 2, figsize=(9, 9))
    for col, row in enumerate((tight, right)):
        res = row["result"]
        mesh = atlas_scene(res)
        axes[0, col].imshow(np.clip(render(mesh, textured(res, "missed", (0.9, 0.1, 0.1))),
                                    0, 1))
        axes[0, col].set_title(f"cage offset {row['offset']} of the diagonal: "
                               f"{row['texels_missed_any']} texels missed", fontsize=10)
        mask = np.stack([res.channels["coverage"] > 0] * 3, axis=-1) * 0.35
        mask[res.channels["missed"] > 0] = (1.0, 0.1, 0.1)
        axes[1, col].imshow(mask)
        axes[1, col].set_title("the map: `missed` (red) on the charts (grey)", fontsize=10)
        for ax in axes[:, col]:
            ax.axis("off")
    fig.tight_layout()
    fig.savefig(out / "studio_masks.png", dpi=100)
    plt.close(fig)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mesh", default=str(MESHES / "stanford-bunny.obj"))
    parser.add_argument("--triangles", type=int, default=2000)
    parser.add_argument("--resolution", type=int, default=1024)
    parser.add_argument("--rays", type=int, default=256)
    parser.add_argument("--offset", default="1%")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--figures", default=None, help="write the docs' PNGs here")
    args = parser.parse_args(argv)
    high = Path(args.mesh)
    with tempfile.TemporaryDirectory() as tmp:
        low, decimate_s = decimate(high, args.triangles, Path(tmp) / "low.obj")
        print(f"decimated {high.name} to {len(load_scene(low).faces)} triangles in "
              f"{decimate_s:.2f} s")
        rows = sweep(low, high, args.threads)
        print("| cage offset | scene units | samples missed | back hits | texels with a miss "
              "| texels all missed | projection s |")
        print("|---|---|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['offset']} | {r['offset_units']:.5f} | {r['missed']} of "
                  f"{r['samples']} | {r['back']} | {r['texels_missed_any']} of {r['texels']} "
                  f"| {r['texels_missed_all']} | {r['projection_s']:.2f} |")
        clock = time.perf_counter()
        result = bake_projected(low, high, cage_offset=args.offset,
                                resolution=args.resolution, rays=args.rays,
                                threads=args.threads)
        wall = time.perf_counter() - clock
        clock = time.perf_counter()
        aobake.write(result, Path(tmp) / "ao.exr")
        write_s = time.perf_counter() - clock
        t = result.report["timings"]
        steps = ["load_s", "load_low_s", "uv_check_s", "unwrap_s", "rasterize_s", "cage_s",
                 "projection_s", "occluders_s", "trace_s", "seams_s", "splat_dilate_s"]
        print(f"\none bake at {args.resolution}², {args.rays} rays, cage {args.offset}, "
              f"{args.threads} threads:")
        print("| " + " | ".join(s[:-2] for s in steps) + " | write | wall |")
        print("|" + "---|" * (len(steps) + 2))
        print("| " + " | ".join(f"{t.get(s, 0.0):.2f}" for s in steps)
              + f" | {write_s:.2f} | {wall:.2f} |")
        p = result.report["projection"]
        print(json.dumps({k: p[k] for k in ("points", "hit", "missed", "back", "distance",
                                            "texels")}))
        if args.figures:
            figures(Path(args.figures), low, high, rows, result, args.threads)


if __name__ == "__main__":
    main()
