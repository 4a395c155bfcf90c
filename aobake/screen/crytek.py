"""Crytek's screen-space AO (Mittring, "Finding next gen: CryEngine 2", SIGGRAPH 2007 course).

For a pixel p at view-space position P (reconstructed from its depth), N samples are taken
in the ball of radius R around P (``kernels.sphere_kernel``: equal-volume, in antipodal
pairs; rotated per pixel when the pattern is on).  Each sample s is projected into the
image and compared with the depth buffer at the pixel it falls in (depth d_buf under the
sample: see below; Q = d_buf ray(s's image) the surface point in front of which s may lie):

    occluded(s)  iff  1/d_s < 1/d_buf - e          (s lies behind the visible surface;
                                                    e the buffer's float32 step)

and the range check, ``range_check``:

- ``plane`` (default): the solid behind a surface is taken to be R thick, measured along
  the surface's normal: s counts as occluded when it lies less than R below the plane of
  the pixel it was compared with (n_q . (Q - s) < R, n_q that pixel's normal, Q the point
  of its facet under s: ``Frame.facet_depth``); one farther below (behind a foreground
  object) says nothing about p's neighbourhood and counts 1/2, as in CryEngine 2's shader
  ("use default value of 0.5 if right computations are not possible").  Measured across
  the surface, the check does not depend on the viewing angle;
- ``depth``: the check of most later SSAO code: a sample behind the surface by R or more
  in depth (d_s - d_buf >= R) counts as open.  Measured along the view, it rejects the
  samples below a floor seen at a grazing angle (their depth difference exceeds R while
  they are within R of it): at the bottom of a crease seen at 56 degrees from the floor's
  normal (256 samples) it gave 0.69 where the ball's solid share (3/4) gives 0.5 and the
  ray-traced truth 0.53; the plane check gave 0.53.

The whole ball is sampled, not a hemisphere, and the normal is not used for the samples:
that is Crytek's method, and the reason an open flat wall reads grey: half of any ball
centred on a plane lies behind it.

**Normalisation.**  A = the mean over the samples of 1 (open), 0 (occluded) or 1/2 (out of
range); AO = min(1, 2 A) (``normalise="double"``, the default): the visible fraction of an
open flat wall, 1/2, is made 1, a concave corner darkens, and a convex edge (more than
half the ball free) saturates at 1 like the true AO.  ``"crytek"``: min(1, A + A^2), the
CryEngine 2 shader's own amplification (a flat wall 3/4); ``"none"``: A itself (a flat
wall 1/2).

**The depth under a sample.**  A renderer's point-sampled fetch reads the depth at the
centre of the pixel a sample falls in, not under the sample: on a slope that is off by up to
half a pixel's depth span, enough to count samples just in front of a plane as behind it
(the self-occlusion greying of tilted walls), which engines hide with a slope-scaled bias
that in turn hides samples just behind.  Here the sample is compared with the pixel's
*facet*, the plane through its depth sample with its G-buffer normal, under the sample's
exact image point (``Frame.facet_depth``): exact on a planar surface, so no bias is needed
beyond the buffer's own float32 step (``gbuffer.depth_step``), and a flat wall gets exactly
its flat value: A = 1/2 (one sample of each antipodal pair behind the plane, all within R
of it for the plane check), at any viewing angle, wherever the ball's image lies on the
image (a sample off the image counts as open).
"""

from __future__ import annotations

import numpy as np

from aobake.screen import kernels
from aobake.screen.gbuffer import Frame, depth_step
# the normalisations of the visible fraction A and the range checks (module docstring) are
# the settings' choices, stated in ``aobake.settings.screen``
from aobake.settings.screen import NORMALISATIONS, RANGE_CHECKS  # noqa: F401

#: the value an open flat wall gets under each normalisation (docs/screen-space.md), where the
#: ball's image lies on the image (off it, samples count as open): with the plane check
#: exactly one sample of each antipodal pair is occluded (the facet keeps those in front
#: open, those behind are less than R below the plane), so A = 1/2 exactly at any viewing
#: angle; with the depth check A >= 1/2 (so "double" still gives 1)
FLAT_VALUE = {"double": 1.0, "crytek": 0.75, "none": 0.5}
#: pixels per block (pixels x samples arrays)
BLOCK = 16384


def ao(frame: Frame, pixels: np.ndarray, radius: float, samples: int = 16,
       rotate: bool = True, period: int = 4, normalise: str = "double",
       seed: int = 0, range_check: str = "plane") -> np.ndarray:
    """Crytek SSAO at flat ``pixels`` (k,) int64 (covered) -> (k,) float64 in [0, 1]
    (1 = open, 0 = every sample occluded); ``radius`` in scene units (> 0), ``samples``
    in the ball, ``rotate``: the kernel turned by the pixel's cell of the ``period`` x
    ``period`` pattern (``kernels.rotations``, keyed by ``seed``), ``normalise`` and
    ``range_check`` as in the module docstring."""
    pixels = np.asarray(pixels, dtype=np.int64)
    kernel = kernels.sphere_kernel(samples) * radius
    turns = kernels.rotations(period, seed) if rotate else None
    out = np.empty(len(pixels))
    for part in kernels.blocks(len(pixels), BLOCK):
        out[part] = _block(frame, pixels[part], radius, kernel, turns, period, normalise,
                           range_check)
    return out


def _block(frame, pixels, radius, kernel, turns, period, normalise, range_check):
    p = frame.positions(pixels)
    if turns is None:
        offsets = np.broadcast_to(kernel, (len(pixels),) + kernel.shape)
    else:
        cell = kernels.pattern_index(pixels, frame.width, period)
        offsets = np.einsum("kij,sj->ksi", turns[cell], kernel)
    s = p[:, None, :] + offsets  # (k, N, 3)
    x, y, d_s = frame.project(s)
    index = frame.lookup(x, y)
    d_buf = frame.depth_at(index)
    facet = frame.facet_depth(index, x, y)  # the depth under the sample (inf: nothing)
    with np.errstate(divide="ignore", invalid="ignore"):
        finite = np.isfinite(facet)
        safe = np.where(finite, facet, 1.0)
        tol = 2.0 * depth_step(frame, np.where(finite, d_buf, 1.0)) / (safe * safe)
        behind = finite & (d_s > 0) & (1.0 / d_s < 1.0 / safe - tol)
    if range_check == "depth":
        value = np.where(behind & (d_s - safe < radius), 0.0, 1.0)
    else:
        # Q: the point of the fetched pixel's facet under the sample; the sample's distance
        # below that plane is exact on a planar surface
        q = frame.rays(np.where(finite, x, 0.0), np.where(finite, y, 0.0)) * safe[..., None]
        n_q = frame.normals.reshape(-1, 3)[np.maximum(index, 0)]
        below = np.einsum("ksj,ksj->ks", n_q, q - s)
        value = np.where(behind, np.where(below < radius, 0.0, 0.5), 1.0)
    visible = value.mean(axis=1)
    if normalise == "double":
        return np.minimum(1.0, 2.0 * visible)
    if normalise == "crytek":
        return np.minimum(1.0, visible + visible * visible)
    return visible
