"""The pictures of docs/lightmaps.md: atlases before/after, a seam close-up before/after,
a mip level, the ogre before/after normal repair (the denoising figure comes from
benchmarks/bench_denoise.py --figures).

    python benchmarks/fig_lightmaps.py [--out docs/img] [--threads 2] [--only NAME ...]

Needs matplotlib and ../shared/meshes.  Figures (PNG):

- ``atlas_<mesh>.png``: the bunny's and the ogre's new atlas at 1024^2, charts in colours,
  as aobake made it before the dense atlases (git revision ``BEFORE``, its default padding
  8) and now (padding 2), with the covered share of the texels;
- ``seam_bunny.png``: the bunny rendered with its lightmap (bilinear lookups, no shading),
  close up where the two sides of a UV seam differed most, ``--seams off`` and ``erase``
  (the same rays); and the two sides' lookups at every seam point against each other;
- ``mip_bunny.png``: the 64^2 level of a box-filtered mip chain of the bunny's AO map with
  the gutters dilated ``--padding`` texels and black beyond (before) and push-pull filled
  (now);
- ``repair_ogre.png``: the ogre's per-vertex AO (256 rays) with 2% of its faces wound the
  other way, baked ``--fix-normals warn`` (as given) and ``fix``, and a 16384-ray
  reference of the mesh as published.
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import aobake  # noqa: E402
from aobake.post import dilate  # noqa: E402
from aobake.scene import load_scene, make_scene  # noqa: E402
from aobake.targets.texels.raster import rasterize  # noqa: E402
from aobake.targets.texels.seams import bilinear  # noqa: E402
from aobake.targets.texels.charts import connected_labels  # noqa: E402
from aobake.targets.texels.unwrap import unwrap  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "meshes"
#: the last revision before the dense atlases (its default --padding was 8)
BEFORE = "7ab8a73"


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _old_unwrap():
    """unwrap() of revision BEFORE, loaded on its own from git."""
    source = subprocess.run(["git", "-C", str(ROOT), "show",
                             f"{BEFORE}:aobake/targets/texels/unwrap.py"],
                            capture_output=True, text=True, check=True).stdout
    path = Path(tempfile.mkdtemp()) / "unwrap_before.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("unwrap_before", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.unwrap


def chart_image(uv, faces_uv, size: int) -> tuple[np.ndarray, float]:
    """(size, size, 3) float image of the charts in random colours on black, and the
    covered share of the texels."""
    samples = rasterize(uv, faces_uv, size, size, 1, 0)
    labels = connected_labels(int(faces_uv.max()) + 1, faces_uv)
    colours = np.random.default_rng(0).uniform(0.25, 1.0, (labels.max() + 1, 3))
    image = np.zeros((size * size, 3))
    image[samples.texel] = colours[labels[samples.face]]
    return image.reshape(size, size, 3), np.unique(samples.texel).size / size ** 2


def atlas_figure(out: Path, mesh: str) -> None:
    scene = load_scene(SHARED / mesh)
    size = 1024
    old = _old_unwrap()(scene.vertices, scene.faces, size, 8, isolate=False)
    new = unwrap(scene.vertices, scene.faces, size, aobake.settings.DEFAULTS["padding"],
                 isolate=False)
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(12, 6.3))
    for ax, un, title in zip(axes, (old, new), (f"before ({BEFORE}, padding 8)",
                                                 "now (padding 2)")):
        image, covered = chart_image(un.uv, un.faces, size)
        ax.imshow(image, interpolation="nearest")
        ax.set_title(f"{title}: {covered:.1%} of the texels")
        ax.axis("off")
    fig.suptitle(f"{mesh}: new atlas at 1024x1024")
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(out / f"atlas_{Path(mesh).stem}.png", dpi=80)
    plt.close(fig)


class Camera:
    """An orthographic view of a triangle mesh through Embree: the face and barycentrics
    seen at each of px x px pixels of a square of side ``extent`` around ``centre``,
    looking along ``-normal``."""

    def __init__(self, positions, faces, centre, normal, extent, px=400):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        scene = rtcore_scene.EmbreeScene()
        shift = np.asarray(centre, np.float64)
        TriangleMesh(scene, (positions - shift).astype(np.float32),
                     np.ascontiguousarray(faces, np.int32))
        n = np.asarray(normal, np.float64) / np.linalg.norm(normal)
        up = np.array([0.0, 1.0, 0.0] if abs(n[1]) < 0.9 else [0.0, 0.0, -1.0])
        e2 = up - (up @ n) * n  # image up: the scene's +y as seen from +n
        e2 /= np.linalg.norm(e2)
        e1 = np.cross(e2, n)  # image right
        t = (np.arange(px) + 0.5) / px - 0.5
        y, x = np.meshgrid(-t * extent, t * extent, indexing="ij")
        span = float(np.linalg.norm(positions.max(0) - positions.min(0)))
        origins = x[..., None] * e1 + y[..., None] * e2 + n * span
        dirs = np.broadcast_to(-n, origins.shape)
        hit = scene.run(origins.reshape(-1, 3).astype(np.float32),
                        np.ascontiguousarray(dirs.reshape(-1, 3), np.float32),
                        query="INTERSECT", output=True)
        self.prim = hit["primID"].reshape(px, px)
        u, v = hit["u"].reshape(px, px), hit["v"].reshape(px, px)
        self.bary = np.stack([1 - u - v, u, v], -1)
        self.faces = np.asarray(faces)

    def per_vertex(self, values) -> np.ndarray:
        """(px, px) the per-vertex values interpolated; nan off the mesh."""
        seen = self.prim >= 0
        out = np.full(self.prim.shape, np.nan)
        corners = self.faces[self.prim[seen]]
        out[seen] = np.einsum("nc,nc->n", self.bary[seen], values[corners])
        return out

    def lookup(self, image, uv, wrap="clamp") -> np.ndarray:
        """(px, px) bilinear lookups of a lightmap at the seen points' UVs; nan off it."""
        seen = self.prim >= 0
        out = np.full(self.prim.shape, np.nan)
        corners = self.faces[self.prim[seen]]
        at = np.einsum("nc,ncd->nd", self.bary[seen], uv[corners])
        out[seen] = bilinear(image, at, wrap)
        return out


def _seam_edges_3d(atlas):
    """Seam edges of an atlas mesh: (e, 2) uv endpoints of side A and B, (e, 3) midpoint
    and normal, as arrays (uv_a (e, 2, 2), uv_b (e, 2, 2), mid (e, 3), normal (e, 3))."""
    _, weld = np.unique(atlas.positions, axis=0, return_inverse=True)
    weld = weld.ravel()
    f = atlas.faces
    a = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    b = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    wa, wb = weld[a], weld[b]
    key = np.minimum(wa, wb) * (weld.max() + 1) + np.maximum(wa, wb)
    order = np.argsort(key, kind="stable")
    key, a, b, wa = key[order], a[order], b[order], wa[order]
    pair = np.nonzero(key[1:] == key[:-1])[0]
    i, j = pair, pair + 1
    # orient side B like side A (same welded start vertex)
    same = weld[a[j]] == wa[i]
    bj0, bj1 = np.where(same, a[j], b[j]), np.where(same, b[j], a[j])
    seam = ~((atlas.uv[a[i]] == atlas.uv[bj0]).all(1) & (atlas.uv[b[i]] == atlas.uv[bj1]).all(1))
    i, bj0, bj1 = i[seam], bj0[seam], bj1[seam]
    uv_a = np.stack([atlas.uv[a[i]], atlas.uv[b[i]]], 1)
    uv_b = np.stack([atlas.uv[bj0], atlas.uv[bj1]], 1)
    mid = 0.5 * (atlas.positions[a[i]] + atlas.positions[b[i]])
    normal = atlas.normals[a[i]] + atlas.normals[b[i]]
    return uv_a, uv_b, mid, normal


def seam_figure(out: Path, threads: int) -> None:
    path = SHARED / "stanford-bunny.obj"
    options = dict(resolution=512, rays=256, threads=threads, unwrap="always")
    off = aobake.bake_texels(path, seams="off", **options)
    on = aobake.bake_texels(path, seams="erase", **options)
    atlas = off.atlas
    uv_a, uv_b, mid, normal = _seam_edges_3d(atlas)
    ao_off, ao_on = off.channels["ao"], on.channels["ao"]
    d = bilinear(ao_off, uv_a.mean(1)) - bilinear(ao_off, uv_b.mean(1))
    worst = int(np.argmax(np.abs(d)))
    spacing = 1.0 / off.report["texture"]["texel_density"]
    camera = Camera(atlas.positions, atlas.faces, mid[worst], normal[worst], 40 * spacing)
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(15, 5.2))
    for ax, image, title in zip(axes, (ao_off, ao_on), ("--seams off", "--seams erase")):
        ax.imshow(camera.lookup(image, atlas.uv), cmap="gray", vmin=0, vmax=1,
                  interpolation="nearest")
        ax.set_title(f"{title} (40 texels across)")
        ax.axis("off")
    t = np.linspace(0.05, 0.95, 5)[:, None, None]
    pa = ((1 - t) * uv_a[None, :, 0] + t * uv_a[None, :, 1]).reshape(-1, 2)
    pb = ((1 - t) * uv_b[None, :, 0] + t * uv_b[None, :, 1]).reshape(-1, 2)
    for image, label in ((ao_off, "off"), (ao_on, "erase")):
        da = bilinear(image, pa) - bilinear(image, pb)
        axes[2].hist(da, bins=np.linspace(-0.1, 0.1, 101), histtype="step",
                     label=f"{label}: rms {np.sqrt(np.mean(da ** 2)):.4f}")
    axes[2].set_xlabel("side A - side B lookup, at 5 points of every seam edge")
    axes[2].set_yscale("log")
    axes[2].legend()
    fig.suptitle("stanford-bunny, 512x512, 256 rays: the same rays with and without seam "
                 "erasure")
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(out / "seam_bunny.png", dpi=80)
    plt.close(fig)


def _mip(image, levels):
    for _ in range(levels):
        image = 0.25 * (image[0::2, 0::2] + image[1::2, 0::2] + image[0::2, 1::2]
                        + image[1::2, 1::2])
    return image


def mip_figure(out: Path, threads: int) -> None:
    path = SHARED / "stanford-bunny.obj"
    padding = aobake.settings.DEFAULTS["padding"]
    result = aobake.bake_texels(path, resolution=1024, rays=64, threads=threads,
                                unwrap="always")
    now = result.channels["ao"].astype(np.float64)
    covered = result.covered
    black, filled = dilate(now[..., None] * covered[..., None], covered, padding)
    black = np.where(filled, black[..., 0], 0.0)
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(10, 5.4))
    for ax, image, title in zip(axes, (black, now),
                                (f"dilated {padding} texels, black beyond", "push-pull")):
        ax.imshow(_mip(image, 4), cmap="gray", vmin=0, vmax=1, interpolation="nearest")
        ax.set_title(f"{title}: mip level 4 (64x64)")
        ax.axis("off")
    fig.suptitle("stanford-bunny AO map, box-filtered mip chain")
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(out / "mip_bunny.png", dpi=80)
    plt.close(fig)


def repair_figure(out: Path, threads: int) -> None:
    path = SHARED / "ogre.obj"
    scene = load_scene(path)
    faces = scene.faces.copy()
    flip = np.random.default_rng(0).random(len(faces)) < 0.02
    faces[flip] = faces[flip][:, [0, 2, 1]]
    # as benchmarks/bench_repair.py: the policy applies where the scene is made
    bakes = [aobake.bake(make_scene(scene.vertices, faces, source=path.name, fix_normals=mode),
                         rays=256, threads=threads) for mode in ("warn", "fix")]
    reference = aobake.bake(scene, rays=16384, seed=1, threads=threads)
    centre = 0.5 * (scene.vertices.min(0) + scene.vertices.max(0))
    extent = 1.1 * float(np.ptp(scene.vertices, axis=0).max())
    camera = Camera(scene.vertices, scene.faces, centre, [0.0, 0.0, 1.0], extent, px=500)
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(15, 5.6))
    for ax, result, title in zip(axes, bakes, ("2% of faces flipped, --fix-normals warn",
                                               "2% flipped, --fix-normals fix")):
        error = np.abs(result.ao - reference.ao)
        rmse = float(np.sqrt(np.nanmean(error ** 2)))
        shown = ax.imshow(camera.per_vertex(error), cmap="inferno", vmin=0, vmax=0.1)
        ax.set_title(f"{title}\n|AO - reference|, RMSE {rmse:.4f}")
        ax.axis("off")
    fig.colorbar(shown, ax=axes[:2], shrink=0.7)
    axes[2].imshow(camera.per_vertex(reference.ao), cmap="gray", vmin=0, vmax=1)
    axes[2].set_title("reference AO (as published, 16384 rays)")
    axes[2].axis("off")
    fig.suptitle("ogre, per-vertex AO, 256 rays")
    fig.savefig(out / "repair_ogre.png", dpi=80)
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "img")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--only", nargs="+", default=None,
                        choices=["atlas", "seam", "mip", "repair"])
    args = parser.parse_args()
    if not SHARED.is_dir():
        sys.exit("the figures need ../shared/meshes")
    args.out.mkdir(parents=True, exist_ok=True)
    todo = args.only or ["atlas", "seam", "mip", "repair"]
    if "atlas" in todo:
        for mesh in ("stanford-bunny.obj", "ogre.obj"):
            atlas_figure(args.out, mesh)
    if "seam" in todo:
        seam_figure(args.out, args.threads)
    if "mip" in todo:
        mip_figure(args.out, args.threads)
    if "repair" in todo:
        repair_figure(args.out, args.threads)


if __name__ == "__main__":
    main()
