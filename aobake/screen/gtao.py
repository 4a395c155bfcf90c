"""Ground-truth-based AO (Jimenez, Wu, Pesce & Jarabo, "Practical real-time strategies for
accurate indirect occlusion", SIGGRAPH 2016 course), as Intel's XeGTAO implements it.

For a pixel p (position P, unit normal n, view vector v = -P / |P|), S slices: the planes
containing v at screen angles phi = pi (s + o) / S (o the slice offset: 1/2, or the
pixel's cell of the rotation pattern).  In each slice:

- the normal projected on the slice plane, n_s (length |n_s|), makes the angle
  gamma = sign(n_s . t) acos(clamp(n_s . v / |n_s|, 0, 1)) with v (t the slice's direction
  orthogonal to v);
- a horizon search on each side: T steps at screen distances (((j + u) / T)^2 + 1.3 /
  R_pix) R_pix pixels, j = 0..T-1 (the squared distribution and the 1.3-pixel minimum of
  XeGTAO; u the step offset), R_pix = R / pixel size at p's depth; a sample reads the pixel
  it falls in and its position is the point of that pixel's facet (its depth and normal,
  ``Frame.facet_depth``) under the sample's exact image point, so it lies in the slice
  (XeGTAO snaps samples to pixel centres, which pushes them off the slice: on an open plane
  facing the camera that darkened off-centre pixels by up to 0.008 here);
  each sample's view-space position P_q gives cos h_q = v . (P_q - P) / |P_q - P|, pulled
  toward the side's lowest horizon cos(gamma -+ pi/2) by the falloff weight
  w = clamp((R - |P_q - P|) / (f R), 0, 1) (f the falloff range; w = 0 past R), and the
  side's horizon is the largest;
- h_1 = -acos(cos h_left), h_2 = acos(cos h_right), clamped to gamma -+ pi/2 (the
  normal's hemisphere), and the slice's visibility is the analytic cosine-weighted integral

      a(h_1, h_2) = |n_s| sum_{i=1,2} (cos gamma + 2 h_i sin gamma - cos(2 h_i - gamma)) / 4
                  = |n_s| int_{h_1}^{h_2} cos(theta - gamma) |sin theta| d theta.

AO = (1/S) sum_s a_s (1 = open).  R here is the search radius: ``--method gtao`` passes the
radius times ``gtao_multiplier`` (XeGTAO's 1.457: with its falloff of 0.615 R the weight is
1/2 at 1.457 (1 - 0.615 / 2) = 1.009 times the radius, so the fade straddles the bounded
truth's cut; with a hard cut and multiplier 1, GTAO with dense slices and steps is that
truth wherever the slices' visible sets are single intervals: tested at a crease).  A
sample off the image or on a pixel that sees nothing is skipped (XeGTAO clamps to the
edge).  Not copied from XeGTAO: its 5% blend of |n_s| toward 1 (an empirical fudge), its
fade for small screen radii, its depth MIP chain (every sample here reads the
full-resolution depth) and its final power.

**Flat value.**  On an open plane every horizon is the plane's, h_i = gamma -+ pi/2, and
a slice gives |n_s| (cos gamma + gamma sin gamma): AO = (1/S) sum_s |n_s|(cos gamma_s +
gamma_s sin gamma_s) (``flat_value``), exactly 1 for a plane facing the eye and 1 in the
limit of many slices for any plane (the integral over phi of the cosine lobe); with
S = 4 it is within 0.3% of 1 for a normal 60 degrees off the view and within 2.1% at 80
degrees (S = 2: 4.7% and 14%); AO is clipped to [0, 1], so above 1 it reads 1.
"""

from __future__ import annotations

import math

import numpy as np

from aobake.screen import kernels
from aobake.screen.gbuffer import Frame

#: XeGTAO's minimum sample distance in pixels (``pixelTooCloseThreshold``): the first step
#: lands past the pixel's own neighbours' rounding
MIN_PIXELS = 1.3
#: XeGTAO's sample distribution power (``XE_GTAO_DEFAULT_SAMPLE_DISTRIBUTION_POWER``)
DISTRIBUTION_POWER = 2.0
#: pixels per block (pixels x slices x steps arrays)
BLOCK = 8192


def slice_integral(h1, h2, gamma, length):
    """|n_s| (a(h1) + a(h2)) with a(h) = (cos g + 2 h sin g - cos(2 h - g)) / 4 (arrays
    broadcast): the slice's cosine-weighted visibility between horizons h1 <= 0 <= h2
    (angles from the view vector, radians) about a projected normal at angle g of length
    ``length``."""
    cos_g, sin_g = np.cos(gamma), np.sin(gamma)
    a1 = (cos_g + 2.0 * h1 * sin_g - np.cos(2.0 * h1 - gamma)) / 4.0
    a2 = (cos_g + 2.0 * h2 * sin_g - np.cos(2.0 * h2 - gamma)) / 4.0
    return length * (a1 + a2)


def slice_frames(frame: Frame, positions: np.ndarray, normals: np.ndarray, phi: np.ndarray):
    """For pixels (k,) and slice angles phi (k, S): (v (k, 3), gamma (k, S), |n_s| (k, S),
    screen direction (k, S, 2) in pixels (x right, y down))."""
    v = -positions / np.linalg.norm(positions, axis=1, keepdims=True)
    cos_p, sin_p = np.cos(phi), np.sin(phi)
    direction = np.stack([cos_p, sin_p, np.zeros_like(phi)], axis=-1)  # view space, y up
    t = direction - np.einsum("ksj,kj->ks", direction, v)[..., None] * v[:, None, :]
    axis = np.cross(t, v[:, None, :])
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    n_s = normals[:, None, :] - np.einsum("ksj,kj->ks", axis, normals)[..., None] * axis
    length = np.linalg.norm(n_s, axis=-1)
    safe = np.where(length > 0, length, 1.0)
    cos_n = np.clip(np.einsum("ksj,kj->ks", n_s, v) / safe, 0.0, 1.0)
    sign = np.where(np.einsum("ksj,ksj->ks", t, n_s) < 0, -1.0, 1.0)
    gamma = sign * np.arccos(cos_n)
    return v, gamma, length, np.stack([cos_p, -sin_p], axis=-1)


def flat_value(frame: Frame, pixel: int, slices: int, offset: float = 0.5) -> float:
    """The value of an open plane through ``pixel`` (its position and normal) with slices at
    pi (s + offset) / S: (1/S) sum_s |n_s| (cos g_s + g_s sin g_s)."""
    p = frame.positions(np.array([pixel]))
    n = frame.normals_at(np.array([pixel]))
    phi = math.pi * (np.arange(slices) + offset)[None, :] / slices
    _, gamma, length, _ = slice_frames(frame, p, n, phi)
    return float(np.mean(length * (np.cos(gamma) + gamma * np.sin(gamma))))


def offsets(pixels: np.ndarray, width: int, rotate: bool, period: int):
    """(slice offset, step offset), each (k,) float64 in (0, 1), of flat ``pixels``: 1/2
    without rotation, else the pixel's cell of the pattern (``kernels.fractions``), the step's
    from the cells scattered once more (so it is not the slice's)."""
    pixels = np.asarray(pixels, dtype=np.int64)
    if not rotate:
        half = np.full(len(pixels), 0.5)
        return half, half.copy()
    cells = period * period
    cell = kernels.pattern_index(pixels, width, period)
    jitter = kernels.fractions(period)
    return jitter[cell], jitter[(cell * kernels.scatter_step(cells)) % cells]


def ao(frame: Frame, pixels: np.ndarray, radius: float, slices: int = 4, steps: int = 4,
       falloff: float = 0.615, rotate: bool = True, period: int = 4) -> np.ndarray:
    """GTAO at flat ``pixels`` (k,) int64 (covered) -> (k,) float64 in [0, 1] (1 = open);
    ``radius`` in scene units, ``slices`` per pixel, ``steps`` per side of a slice,
    ``falloff`` the fraction of the radius over which a sample's weight fades to 0 (0: a
    hard cut at R; XeGTAO's default 0.615), ``rotate``: slice and step offsets from the
    pixel's cell of the ``period`` x ``period`` pattern (else 1/2)."""
    pixels = np.asarray(pixels, dtype=np.int64)
    out = np.empty(len(pixels))
    for part in kernels.blocks(len(pixels), BLOCK):
        out[part] = _block(frame, pixels[part], radius, slices, steps, falloff, rotate, period)
    return out


def _block(frame, pixels, radius, slices, steps, falloff, rotate, period):
    p = frame.positions(pixels)
    n = frame.normals_at(pixels)
    slice_offset, step_offset = offsets(pixels, frame.width, rotate, period)
    phi = math.pi * (np.arange(slices)[None, :] + slice_offset[:, None]) / slices
    v, gamma, length, screen = slice_frames(frame, p, n, phi)
    x, y = frame.centres(pixels)
    r_pix = radius / frame.pixel_size(-p[:, 2])  # (k,)
    # step distances in pixels (k, T): XeGTAO's (((j + u) / T)^2 + 1.3 / R_pix) R_pix
    u = (np.arange(steps)[None, :] + step_offset[:, None]) / steps
    dist = (u ** DISTRIBUTION_POWER + MIN_PIXELS / r_pix[:, None]) * r_pix[:, None]
    fall = max(falloff, 1e-12) * radius
    horizons = []
    for side, low in ((1.0, gamma + math.pi / 2), (-1.0, gamma - math.pi / 2)):
        # side +1: along the slice's screen direction (h_2 > 0), -1: the opposite (h_1 < 0)
        sx = x[:, None, None] + side * screen[:, :, None, 0] * dist[:, None, :]  # (k, S, T)
        sy = y[:, None, None] + side * screen[:, :, None, 1] * dist[:, None, :]
        q = frame.lookup(sx, sy)
        d_s = frame.facet_depth(q, sx, sy)
        ok = np.isfinite(d_s)
        pos = frame.rays(sx, sy) * np.where(ok, d_s, 0.0)[..., None]
        delta = pos - p[:, None, None, :]
        span = np.linalg.norm(delta, axis=-1)
        ok &= span > 0
        safe = np.where(ok, span, 1.0)
        cos_h = np.einsum("kstj,kj->kst", delta, v) / safe
        weight = np.where(ok, np.clip((radius - span) / fall, 0.0, 1.0), 0.0)
        if falloff <= 0:
            weight = np.where(ok & (span <= radius), 1.0, 0.0)
        low_cos = np.cos(low)[..., None]
        cos_h = low_cos + weight * (cos_h - low_cos)
        best = np.maximum(np.cos(low), cos_h.max(axis=2))
        horizons.append(np.arccos(np.clip(best, -1.0, 1.0)))
    h2 = np.minimum(horizons[0], gamma + math.pi / 2)
    h1 = np.maximum(-horizons[1], gamma - math.pi / 2)
    visibility = slice_integral(h1, h2, gamma, length).mean(axis=1)
    return np.clip(visibility, 0.0, 1.0)
