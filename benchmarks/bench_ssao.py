"""Screen-space AO scored against its truths: Crytek, Shanmugam-Arikan and GTAO on views of the
still life, the Stanford bunny and the ogre (named views), per setting, with pictures (docs/screen-space.md).

    python benchmarks/bench_ssao.py [--quick] [--size 320x240] [--truth-rays 256]
                                    [--hf-rays 64] [--json PATH] [--img-dir docs/img]

Per view: one view with ``--truth-rays`` rays at max distance R (the
methods' radius: 5% of the scene's diagonal) gives the G-buffer and the bounded truth;
the unbounded AO comes in the same run (``aobake.bake_view_truths``, ``aobake view --truths``); the height-field truth (``aobake.screen.heightfield``,
``--hf-rays`` rays) is computed twice from the same G-buffer, infinitely thick ("hf") and
R thick ("hfR", the height field the methods' range checks assume).  Every method reads
only the G-buffer; each setting is timed on one thread (``method.image``: the whole image,
refinements included) and scored with ``aobake.screen.score`` against the bounded truth
(raw and after the best gain of the occlusion; all, interior and the 3-pixel band around
depth edges; z in units of the truth's stderr) and against hfR; each method at its defaults
with R / 2 and 2 R too, against the truth bounded at that radius.  Pictures:
docs/img/ssao_<view>.png, the truth, the methods and their signed errors side by side.
Numbers from a shared, loaded machine are slower than a quiet one.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import aobake  # noqa: E402
from aobake.methods.ssao import (CrytekMethod, GtaoMethod, HeightfieldMethod,  # noqa: E402
                                 ShanmugamMethod)
from aobake.scene import load_scene  # noqa: E402
from aobake.screen import score  # noqa: E402
from aobake.screen.gbuffer import GBuffer  # noqa: E402
from aobake.settings.screen import CrytekOptions, GtaoOptions, SsaoOptions  # noqa: E402

STILL_LIFE = ROOT / "assets" / "still_life.obj"
BUNNY = ROOT.parent / "shared" / "meshes" / "stanford-bunny.obj"
OGRE = ROOT.parent / "shared" / "meshes" / "ogre.obj"
RADIUS_PERCENT = 5.0
#: the other radii scored (x R), each against the truth bounded at its own radius
RADIUS_FACTORS = (0.5, 2.0)

#: name -> (mesh, look (None: the default three-quarter view), ground plane, what it shows);
#: the named views of docs/screen-space.md
VIEWS = {
    "overview": (STILL_LIFE, None, False, "the still life, default camera"),
    "crease": (STILL_LIFE, dict(look_from=(0.55, 1.05, 0.25), look_at=(0.5, 0.05, -0.5)),
               False, "into the open box: deep creases"),
    "thin": (STILL_LIFE, dict(look_from=(-0.2, 0.3, 1.45), look_at=(-0.45, 0.12, 0.45)),
             False, "the torus knot from low down: thin occluders"),
    "screen-edge": (STILL_LIFE, dict(look_from=(-0.05, 0.55, 0.55),
                                     look_at=(-0.05, 0.2, -0.45)),
                    False, "the sphere cut by the image's left edge: off-screen occluders"),
    "grazing": (STILL_LIFE, dict(look_from=(-0.98, 0.06, 0.95), look_at=(0.6, 0.02, -0.5)),
                False, "the floor seen at 2-4 degrees past the knot: a grazing view"),
    "bunny": (BUNNY, None, True, "the Stanford bunny on a ground plane"),
    "ogre": (OGRE, dict(look_from=(10.0, 26.0, 34.0), look_at=(0.0, 19.0, 0.0)), False,
             "the ogre's upper body: a scanned character's folds"),
}


def settings():
    """(label, method class, SsaoOptions, method options) of every scored setting."""
    rows = []
    for cls, own in ((CrytekMethod, CrytekOptions()), (ShanmugamMethod, None),
                     (GtaoMethod, GtaoOptions())):
        name = cls.name
        rows.append((f"{name}", cls, SsaoOptions(), own))
        rows.append((f"{name} no blur", cls, SsaoOptions(ssao_blur=False), own))
        rows.append((f"{name} no rotate, no blur", cls,
                     SsaoOptions(ssao_rotate=False, ssao_blur=False), own))
        if name == "gtao":
            for slices in (2, 8):
                rows.append((f"gtao {slices} slices", cls, SsaoOptions(),
                             GtaoOptions(gtao_slices=slices)))
            for steps in (8, 16):
                rows.append((f"gtao {steps} steps", cls, SsaoOptions(),
                             GtaoOptions(gtao_steps=steps)))
            rows.append(("gtao hard cut", cls, SsaoOptions(), GtaoOptions(gtao_falloff=0.0)))
            rows.append(("gtao hard cut at R", cls, SsaoOptions(),
                         GtaoOptions(gtao_falloff=0.0, gtao_multiplier=1.0)))
            rows.append(("gtao hard cut at R, 16 steps", cls, SsaoOptions(),
                         GtaoOptions(gtao_falloff=0.0, gtao_multiplier=1.0, gtao_steps=16)))
        else:
            for samples in (8, 32):
                rows.append((f"{name} {samples} samples", cls,
                             SsaoOptions(ssao_samples=samples), own))
        rows.append((f"{name} opengl depth", cls, SsaoOptions(ssao_depth="opengl"), own))
        if name == "crytek":
            rows.append(("crytek A + A^2", cls, SsaoOptions(),
                         CrytekOptions(crytek_normalise="crytek")))
            rows.append(("crytek depth range check", cls, SsaoOptions(),
                         CrytekOptions(crytek_range="depth")))
    return rows


def make(cls, radius, ssao, own):
    if cls is CrytekMethod:
        return cls(radius, ssao, own)
    if cls is GtaoMethod:
        return cls(radius, ssao, own)
    return cls(radius, ssao)


def grey(image, covered):
    out = np.where(covered, np.clip(image, 0, 1), 0.0)
    return np.repeat((out * 255 + 0.5).astype(np.uint8)[..., None], 3, axis=2)


def signed(error, covered, scale=0.25):
    """Blue (method too dark) - white - red (too light), saturating at +-scale."""
    e = np.clip(np.where(covered, error, 0.0) / scale, -1, 1)
    rgb = np.ones(error.shape + (3,))
    rgb[..., 1] -= np.abs(e)
    rgb[..., 0] -= np.clip(-e, 0, 1)
    rgb[..., 2] -= np.clip(e, 0, 1)
    rgb[~covered] = 0.0
    return (rgb * 255 + 0.5).astype(np.uint8)


def picture(path, tiles, labels):
    """Tiles (H, W, 3) uint8 in rows of four, each labelled."""
    from PIL import Image, ImageDraw

    h, w = tiles[0].shape[:2]
    cols = 4
    rows = -(-len(tiles) // cols)
    canvas = Image.new("RGB", (cols * w, rows * (h + 14)), (40, 40, 40))
    draw = ImageDraw.Draw(canvas)
    for k, (tile, label) in enumerate(zip(tiles, labels)):
        x, y = (k % cols) * w, (k // cols) * (h + 14)
        canvas.paste(Image.fromarray(tile), (x, y + 14))
        draw.text((x + 3, y + 1), label, fill=(230, 230, 230))
    canvas.save(path)


def fmt(value, digits=4):
    if value is None:
        return "-"
    if isinstance(value, float) and math.isinf(value):
        return "inf"
    return f"{value:.{digits}f}"


def run_view(name, size, truth_rays, hf_rays, img_dir, quick):
    mesh, look, ground, what = VIEWS[name]
    scene = load_scene(mesh)
    radius = RADIUS_PERCENT / 100 * scene.diagonal
    clock = time.perf_counter()
    # both truths and the G-buffer in one run (aobake view --truths)
    bounded = aobake.bake_view_truths(mesh, size=size, look=look, ground_plane=ground,
                                      rays=truth_rays, ssao_radius=radius)
    truth_s = time.perf_counter() - clock
    unbounded_ao = bounded.channels["ao_unbounded"]
    image = GBuffer.from_view(bounded)
    frame = image.frame()
    covered = bounded.covered
    edges = score.depth_edges(frame)
    truth, truth_se = bounded.channels["ao"], bounded.channels["ao_stderr"]
    clock = time.perf_counter()
    hf = HeightfieldMethod(hf_rays, radius).image(image, threads=2)
    hf_s = time.perf_counter() - clock
    hf_r = HeightfieldMethod(hf_rays, radius, thickness=radius).image(image, threads=2)
    out = {"view": name, "what": what, "mesh": Path(mesh).name, "radius": radius,
           "size": list(size), "pixels": int(covered.sum()), "truth_rays": truth_rays,
           "hf_rays": hf_rays, "truth_s": truth_s, "hf_s": hf_s,
           "mean_ao": {"bounded": float(truth[covered].mean()),
                       "unbounded": float(unbounded_ao[covered].mean()),
                       "hf": float(hf["ao"][covered].mean()),
                       "hfR": float(hf_r["ao"][covered].mean())},
           "truths": {}, "rows": []}
    for label, other, se in (("hf", hf, hf["ao_stderr"]), ("hfR", hf_r, hf_r["ao_stderr"]),
                             ("unbounded", unbounded_ao, None)):
        values = other["ao"] if isinstance(other, dict) else other
        out["truths"][label] = score.score(truth, values, covered, edges, truth_se)
    images = {}
    rows = settings()
    if quick:
        rows = [r for r in rows if " " not in r[0]]
    for label, cls, ssao, own in rows:
        method = make(cls, radius, ssao, own)
        clock = time.perf_counter()
        ao = method.image(image, threads=1)
        seconds = time.perf_counter() - clock
        images[label] = ao
        out["rows"].append({
            "setting": label, "method": cls.name, "seconds": seconds,
            "parameters": method.parameters(),
            "vs_truth": score.score(truth, ao, covered, edges, truth_se),
            "vs_hfR": score.score(hf_r["ao"], ao, covered, edges, hf_r["ao_stderr"]),
            "vs_hf": score.score(hf["ao"], ao, covered, edges, hf["ao_stderr"])})
    if not quick:
        # the radius: each method at its defaults with R x factor, against the truth bounded
        # at that radius (a screen method is scored against what it can see)
        for factor in RADIUS_FACTORS:
            r = radius * factor
            other = aobake.bake_view(mesh, camera=bounded.camera, size=size,
                                     ground_plane=ground, rays=truth_rays, max_distance=r)
            other_truth, other_se = other.channels["ao"], other.channels["ao_stderr"]
            for cls, own in ((CrytekMethod, CrytekOptions()), (ShanmugamMethod, None),
                             (GtaoMethod, GtaoOptions())):
                method = make(cls, r, SsaoOptions(), own)
                clock = time.perf_counter()
                ao = method.image(image, threads=1)
                seconds = time.perf_counter() - clock
                out["rows"].append({
                    "setting": f"{cls.name} R x {factor:g}", "method": cls.name,
                    "seconds": seconds, "parameters": method.parameters(),
                    "vs_truth": score.score(other_truth, ao, covered, edges, other_se),
                    "vs_hfR": None, "vs_hf": None})
    if img_dir is not None:
        tiles = [grey(truth, covered), grey(images["crytek"], covered),
                 grey(images["shanmugam"], covered), grey(images["gtao"], covered),
                 grey(hf_r["ao"], covered), signed(images["crytek"] - truth, covered),
                 signed(images["shanmugam"] - truth, covered),
                 signed(images["gtao"] - truth, covered)]
        labels = [f"truth, max distance R = {radius:.3g}", "crytek", "shanmugam", "gtao",
                  "height field, R thick", "crytek - truth", "shanmugam - truth",
                  "gtao - truth"]
        picture(Path(img_dir) / f"ssao_{name}.png", tiles, labels)
    return out


def print_view(result):
    print(f"\n## {result['view']}: {result['what']} ({result['mesh']}, R = "
          f"{result['radius']:.4g}, {result['pixels']} pixels; mean AO: bounded "
          f"{result['mean_ao']['bounded']:.3f}, unbounded {result['mean_ao']['unbounded']:.3f}, "
          f"hf {result['mean_ao']['hf']:.3f}, hfR {result['mean_ao']['hfR']:.3f})")
    print("| vs bounded truth | RMSE | bias | PSNR | SSIM | gain | RMSE gained | SSIM gained | "
          "RMSE interior | RMSE edges | z rms | RMSE vs hfR | ms |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for label, sc in result["truths"].items():
        a = sc["regions"]
        print(f"| {label} (truth) | {fmt(a['all']['raw']['rmse'])} | "
              f"{fmt(a['all']['raw']['bias'], 4)} | {fmt(a['all']['raw']['psnr'], 1)} | "
              f"{fmt(a['all']['raw']['ssim'], 3)} | {fmt(sc['gain'], 2)} | "
              f"{fmt(a['all']['gained']['rmse'])} | {fmt(a['all']['gained']['ssim'], 3)} | "
              f"{fmt(a['interior']['raw']['rmse'])} | {fmt(a['edges']['raw']['rmse'])} | "
              f"{fmt(a['all']['raw']['z_rms'], 1)} | - | - |")
    for row in result["rows"]:
        sc, a = row["vs_truth"], row["vs_truth"]["regions"]
        h = (row["vs_hfR"] or {"regions": {"all": {"raw": {"rmse": None}}}})["regions"]["all"]["raw"]
        print(f"| {row['setting']} | {fmt(a['all']['raw']['rmse'])} | "
              f"{fmt(a['all']['raw']['bias'], 4)} | {fmt(a['all']['raw']['psnr'], 1)} | "
              f"{fmt(a['all']['raw']['ssim'], 3)} | {fmt(sc['gain'], 2)} | "
              f"{fmt(a['all']['gained']['rmse'])} | {fmt(a['all']['gained']['ssim'], 3)} | "
              f"{fmt(a['interior']['raw']['rmse'])} | {fmt(a['edges']['raw']['rmse'])} | "
              f"{fmt(a['all']['raw']['z_rms'], 1)} | {fmt(h['rmse'])} | "
              f"{row['seconds'] * 1000:.0f} |")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="default settings only, 160x120")
    parser.add_argument("--size", default="320x240")
    parser.add_argument("--truth-rays", type=int, default=256)
    parser.add_argument("--hf-rays", type=int, default=64)
    parser.add_argument("--views", default=",".join(VIEWS))
    parser.add_argument("--json", default=None)
    parser.add_argument("--img-dir", default=None, help="write docs/img-style pictures here")
    args = parser.parse_args(argv)
    size = tuple(int(v) for v in args.size.lower().split("x"))
    if args.quick:
        size = (160, 120)
    results = []
    for name in args.views.split(","):
        result = run_view(name, size, args.truth_rays, args.hf_rays, args.img_dir, args.quick)
        print_view(result)
        results.append(result)
        sys.stdout.flush()
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=str))


if __name__ == "__main__":
    main()
