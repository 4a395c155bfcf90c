"""Screen-space AO: methods that read only a camera's G-buffer, their truths, their scores.

- ``gbuffer``: the G-buffer record (``GBuffer``: depth, hardware depths, view-space normals,
  coverage, the camera) the camera target hands to methods (``SamplePoints.image``), and
  the linearised ``Frame`` every method computes on;
- ``kernels``: sample kernels and the per-pixel rotation pattern;
- ``crytek``, ``shanmugam``, ``gtao``: the methods, each ``ao(frame, pixels, ...)`` of
  pixels (k,) int64 flat indices r * W + c -> (k,) float64 (1 = open, 0 = occluded);
- ``refine``: the rotated kernel's blur (geometry-aware, N x N);
- ``heightfield``: the height-field truth (AO ray-marched against the depth buffer);
- ``options``: the settings records;
- ``score``: RMSE, bias, PSNR, SSIM against a truth, by region, raw and after the best gain.

Conventions: docs/screen-space.md.
"""

from aobake.registry import lazy_attributes

# imported on first use: the settings records (``options``) are read by every bake's
# config, the G-buffer only by views
__getattr__ = lazy_attributes(__name__, {"Frame": "aobake.screen.gbuffer",
                                         "GBuffer": "aobake.screen.gbuffer"})

__all__ = ["Frame", "GBuffer"]
