"""Score your own screen-space AO shader against aobake's per-pixel truths: a recipe.

    python docs/score_my_shader.py [--mesh assets/still_life.obj] [--size 320x240]
                                   [--rays 256] [--radius 5%] [--out-dir ssao_recipe]

1. ``aobake view MESH --out view.exr --truths`` renders the view once: the G-buffer (linear
   ``depth``, hardware depths, view-space ``P``, ``Ng``, ``N``, ids, ``coverage``), the truth
   bounded at the radius (``ao``, ``ao_stderr``) and the unbounded one (``ao_unbounded``,
   ``ao_unbounded_stderr``), and the camera record (``view.camera.json``).
2. "Your shader" reads only what an engine has: the depth buffer, the view-space normals and
   the camera (here a plain normal-oriented hemisphere SSAO in numpy, the kind every engine
   tutorial starts from; replace ``my_shader`` with a call into yours, or render your
   shader's output to a PNG/EXR of the same size and skip to step 3).
3. ``aobake compare view.exr my_shader.png`` scores it per covered pixel: RMSE, bias, PSNR,
   SSIM, z in the truth's stderr units, interior and depth-edge band apart, raw and after
   the best gain; ``--reference-key ao_unbounded`` against the unbounded truth.

Conventions (docs/conventions.md, "Camera views"): pixel (r, c) has its centre at
(c + 0.5, r + 0.5), row 0 at the top; view space is right-handed, looking down -Z; a
pixel's position is P = d (tan_x (2x/W - 1), tan_y (1 - 2y/H), -1) with d the linear depth.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenImageIO as oiio


def read_exr(path: Path) -> dict:
    """Every channel of an EXR as name -> (H, W) float32."""
    image = oiio.ImageBuf(str(path))
    pixels = image.get_pixels(oiio.FLOAT)
    return {name: pixels[:, :, i] for i, name in enumerate(image.spec().channelnames)}


def my_shader(depth, normals, covered, camera: dict, radius: float, samples: int = 16,
              seed: int = 1) -> np.ndarray:
    """A normal-oriented hemisphere SSAO: (H, W) AO in [0, 1] (1 = open) from the linear
    ``depth`` (H, W), view-space unit ``normals`` (H, W, 3), ``covered`` (H, W) bool and the
    camera record.  One kernel of ``samples`` points in the unit hemisphere for every
    pixel (no rotation, no blur), a sample is occluded when the depth buffer at its image
    lies in front of it, within ``radius`` (the range check)."""
    h, w = depth.shape
    tan_y = math.tan(math.radians(camera["fov_y_deg"]) / 2)
    tan_x = tan_y * w / h
    y, x = np.mgrid[0:h, 0:w] + 0.5
    d = np.where(covered, depth, 0.0)
    p = np.stack([d * tan_x * (2 * x / w - 1), d * tan_y * (1 - 2 * y / h), -d], axis=-1)
    rng = np.random.default_rng(seed)
    kernel = rng.normal(size=(samples, 3))
    kernel /= np.linalg.norm(kernel, axis=1, keepdims=True)
    kernel *= (rng.random(samples) ** (1 / 3))[:, None]  # uniform in the ball
    open_count = np.zeros((h, w))
    for k in kernel:
        s = np.where((normals @ k)[..., None] < 0, -k, k) * radius + p  # flip into the hemisphere
        sd = -s[..., 2]
        sx = (s[..., 0] / (sd * tan_x) + 1) * w / 2
        sy = (1 - s[..., 1] / (sd * tan_y)) * h / 2
        inside = (sd > 0) & (sx >= 0) & (sx < w) & (sy >= 0) & (sy < h)
        col = np.clip(sx.astype(int), 0, w - 1)
        row = np.clip(sy.astype(int), 0, h - 1)
        buffer = np.where(covered[row, col], depth[row, col], np.inf)
        in_front = buffer < sd - 1e-4 * sd
        in_range = sd - buffer < radius
        open_count += ~(inside & in_front & in_range)
    return np.where(covered, open_count / samples, 0.0)


def write_png16(path: Path, ao: np.ndarray) -> None:
    """AO (H, W) in [0, 1] as a 16-bit grey PNG."""
    spec = oiio.ImageSpec(ao.shape[1], ao.shape[0], 1, oiio.UINT16)
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), spec)
    # (H, W, 1): OpenImageIO's Python binding misreads a 2-D array's layout
    out.write_image(np.rint(np.clip(ao, 0, 1) * 65535).astype(np.uint16)[:, :, None])
    out.close()


def aobake(*args) -> str:
    """Run the aobake command (the one beside this Python), return its stdout."""
    return subprocess.run([sys.executable, "-m", "aobake", *map(str, args)], check=True,
                          capture_output=True, text=True).stdout


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--mesh", default="assets/still_life.obj")
    parser.add_argument("--size", default="320x240")
    parser.add_argument("--rays", type=int, default=256)
    parser.add_argument("--radius", default="5%", help="the shader's radius = the truth's")
    parser.add_argument("--out-dir", type=Path, default=Path("ssao_recipe"))
    args = parser.parse_args(argv)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    view = args.out_dir / "view.exr"

    # 1. the view: G-buffer, both truths, camera
    aobake("view", args.mesh, "--out", view, "--size", args.size, "--rays", args.rays,
           "--ssao-radius", args.radius, "--truths", "--quiet")
    channels = read_exr(view)
    record = json.loads(view.with_name("view.camera.json").read_text())
    camera = record["camera"]
    radius = json.loads(oiio.ImageBuf(str(view)).spec().getattribute("aobake:truths"))[
        "bounded"]["max_distance"]  # the radius in scene units

    # 2. your shader, on the G-buffer only
    covered = channels["coverage"] > 0
    normals = np.stack([channels[f"Ng.{a}"] for a in "XYZ"], axis=-1)
    ao = my_shader(channels["depth"], normals, covered, camera, radius)
    shader = args.out_dir / "my_shader.png"
    write_png16(shader, ao)

    # 3. the scores
    for key in ("ao", "ao_unbounded"):
        result = json.loads(aobake("compare", view, shader, "--reference-key", key, "--json"))
        screen = result["screen"]
        print(f"against {key} (R = {radius:.4g}): best gain {screen['gain']:.3f}")
        for region, scores in screen["regions"].items():
            raw, gained = scores["raw"], scores["gained"]
            print(f"  {region:<9} {raw['pixels']:>7} px  rmse {raw['rmse']:.4f}  bias "
                  f"{raw['bias']:+.4f}  ssim {raw['ssim']:.3f}  z_rms {raw['z_rms']:.2f}  "
                  f"| gained rmse {gained['rmse']:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
