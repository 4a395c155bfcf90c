"""Optional lightmap denoising that keeps the truth beside it (``--denoise``).

The raw channels (``ao``, ``ao_stderr``, the interval) are never changed: denoising adds
``<q>_denoised`` and ``<q>_denoised_stderr`` for each scalar quantity (AO, obscurance).

The filter is a joint bilateral filter on the surface, evaluated over each texel's
(2 R + 1)^2 image neighbourhood.  Neighbour j of texel i has weight

    w_ij = rays_j                                   (a texel's inverse variance, up to a
                                                     factor: fixed by the bake, not by the
                                                     noisy estimate, so it cannot bias)
         * [chart_i == chart_j]                     (never across charts, so never across
                                                     a seam or to a surface packed nearby)
         * exp(-|x_i - x_j|^2 / (2 (sigma h_i)^2))  (world distance, h_i = the texel
                                                     spacing of i's chart)
         * max(0, (n_i.n_j - c) / (1 - c))^2        (c = cos CREASE_ANGLE: 0 across a crease)
         * exp(-max(0, d2 - 1) / (2 k^2))           (d2 = (a_i - a_j)^2 / (s_i^2 + s_j^2):
                                                     the value step in units of its noise; a
                                                     step the noise does not explain, a
                                                     contact shadow, is kept)

and the denoised value is sum_j w_ij a_j / sum_j w_ij.  Its ``_denoised_stderr`` is
sqrt(sum_j w_ij^2 s_j^2) / sum_j w_ij: the noise left, with the weights taken as given
(texels are independent, so the variances add).  It does not count the filter's bias (a
blurred gradient), which is why the denoised value has no interval and why the raw value
stays: the bias is measured against a high-ray reference in ``benchmarks/bench_denoise.py``
(docs/lightmaps.md).  After filtering, the denoised channels go through the same seam
erasure and gutters as the raw ones (``aobake.targets.texels.gather``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aobake.targets.texels.charts import uv_islands
from aobake.targets.texels.splat import splat
from aobake.vectors import normalize

#: spatial kernel sigma in texels (the window reaches 2 sigma)
SIGMA_TEXELS = 2.0
#: normals further apart than this (degrees) never mix: the crease a filter must not cross
CREASE_ANGLE = 30.0
#: range kernel width in noise units of the prefilter: weight exp(-(d2 - 1) / (2 k^2)).
#: k = 4 keeps the noise channel honest (spread over 1000 seeds / predicted, in variance:
#: 1.00 +- 0.02; 1.10 at k = 2, whose weights follow the data too closely) and still drops
#: a step of 0.6 at noise 0.02 to weight ~1e-5
RANGE_K = 4.0


@dataclass(frozen=True)
class Guide:
    """What the filter is guided by, per texel.

    position : (H, W, 3) float64 mean surface position of the texel's samples,
    normal : (H, W, 3) float64 unit mean shading normal, chart : (H, W) int64 UV island
    (-1 outside the charts), rays : (H, W) float64 rays of the texel, covered : (H, W) bool,
    spacing : (H, W) float64 (or a float for all), scene units between texel centres on the
    surface in the texel's chart: sqrt(chart surface area / its covered texels).
    """

    position: np.ndarray
    normal: np.ndarray
    chart: np.ndarray
    rays: np.ndarray
    covered: np.ndarray
    spacing: float


def denoise(value: np.ndarray, stderr: np.ndarray, guide: Guide, sigma: float = SIGMA_TEXELS,
            crease_angle: float = CREASE_ANGLE, k: float = RANGE_K
            ) -> tuple[np.ndarray, np.ndarray]:
    """Denoise one scalar channel.

    value, stderr : (H, W) float the texels' estimates and standard errors (only covered
    texels are read).  Returns (denoised, denoised_stderr), (H, W) float64, 0 outside the
    covered texels; AO and obscurance stay in [0, 1] (a weighted mean of values in it).

    The range kernel compares a 3 x 3 prefilter of the values (same weights, no range
    term), not the raw values: a weight that depended on the texel's own noisy value would
    pull the result towards it, and the noise left would be larger than the weights
    predict (measured 1.36x in variance with raw values at k = 2; 1.10 with the prefilter).
    """
    covered = guide.covered
    a = np.where(covered, np.asarray(value, np.float64), 0.0)
    s2 = np.where(covered, np.asarray(stderr, np.float64), 0.0) ** 2
    cos_crease = math.cos(math.radians(crease_angle))
    pre, pre_s2 = _filter(a, s2, guide, 1, math.inf, cos_crease, None)
    spacing = np.broadcast_to(np.asarray(guide.spacing, np.float64), covered.shape)
    out, out_s2 = _filter(a, s2, guide, int(math.ceil(2.0 * sigma)),
                          np.where(covered, sigma * spacing, 1.0), cos_crease, (pre, pre_s2, k))
    return np.where(covered, out, 0.0), np.where(covered, np.sqrt(out_s2), 0.0)


def _filter(a, s2, guide, reach, sigma_world, cos_crease, rank):
    """One weighted pass: the weighted mean of a (H, W) and its variance from s2 (H, W),
    (H, W) float64 each (meaningful at covered texels).  Weights: rays, same chart,
    the crease term, the spatial kernel of sigma_world ((H, W) per centre texel, or inf:
    flat), and when rank = (g (H, W), g_var (H, W), k) the range kernel on the prefilter g.
    Neighbours are read as shifted views of padded images: no gathers."""
    height, width = guide.covered.shape
    chart = np.where(guide.covered, guide.chart, -1)

    def padded(x, fill):
        width_ = ((reach, reach), (reach, reach)) + ((0, 0),) * (x.ndim - 2)
        return np.pad(x, width_, constant_values=fill)

    # (3, H, W) component planes: three multiply-adds beat an einsum over a last axis of 3
    pos_c, nor_c = np.moveaxis(guide.position, -1, 0), np.moveaxis(guide.normal, -1, 0)
    pos = [padded(x, 0.0) for x in pos_c]
    nor = [padded(x, 0.0) for x in nor_c]
    chart_p = padded(chart, -2)
    rays, a_p, s2_p = padded(guide.rays, 0.0), padded(a, 0.0), padded(s2, 0.0)
    spatial = not np.isscalar(sigma_world) or math.isfinite(sigma_world)
    if spatial:
        inverse = -0.5 / np.square(sigma_world)
    if rank is not None:
        g, g_var, k = rank
        g_p, gv_p = padded(g, 0.0), padded(g_var, 0.0)
    total = np.zeros((height, width))
    weighted = np.zeros((height, width))
    noise = np.zeros((height, width))
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            if reach > 1 and dx * dx + dy * dy > reach * reach:
                continue
            at = (slice(reach + dy, reach + dy + height), slice(reach + dx, reach + dx + width))
            cos = nor[0][at] * nor_c[0] + nor[1][at] * nor_c[1] + nor[2][at] * nor_c[2]
            w = np.clip((cos - cos_crease) / (1.0 - cos_crease), 0.0, None)
            w *= w
            if spatial:
                d2 = sum((p[at] - q) ** 2 for p, q in zip(pos, pos_c))
                w *= np.exp(d2 * inverse)
            if rank is not None:
                d2 = (g_p[at] - g) ** 2 / (gv_p[at] + g_var + 1e-300)
                w *= np.exp(np.maximum(d2 - 1.0, 0.0) * (-0.5 / (k * k)))
            w *= np.where(chart_p[at] == chart, rays[at], 0.0)
            total += w
            weighted += w * a_p[at]
            noise += w * w * s2_p[at]
    # A covered texel has its own weight rays_i > 0 (covered texels were traced).
    where = total > 0
    mean = np.divide(weighted, total, out=np.zeros_like(total), where=where)
    return mean, np.divide(noise, total * total, out=np.zeros_like(total), where=where)


def texel_charts(samples, face_chart) -> np.ndarray:
    """(H, W) int64 UV island of each covered texel (the smallest among its samples' faces;
    -1 elsewhere).  samples : ``TexelSamples``, face_chart : (f,) int64 (``charts.uv_islands``)."""
    n = samples.width * samples.height
    chart = np.full(n, np.iinfo(np.int64).max, dtype=np.int64)
    np.minimum.at(chart, samples.texel, face_chart[samples.face])
    chart[chart == np.iinfo(np.int64).max] = -1
    return chart.reshape(samples.height, samples.width)


def make_guide(samples, points, normals, uv, faces_uv, face_area, covered, rays) -> Guide:
    """The guide of a bake: samples (``TexelSamples``, traced ones), points (s, 3) and
    normals (s, 3) float64 their positions and unit shading normals, uv (t, 2) and
    faces_uv (f, 3) the bake UVs, face_area (f,) float64 surface areas, covered (H, W)
    bool, rays (H, W) float64."""
    position = splat(samples, points)
    normal = normalize(splat(samples, normals))[0]
    face_chart = uv_islands(uv, faces_uv)
    chart = texel_charts(samples, face_chart)
    # Each chart's own texel spacing, so that sigma is SIGMA_TEXELS of its texels even
    # where own UVs give charts different densities.
    k = int(face_chart.max()) + 1 if len(face_chart) else 0
    area = np.bincount(face_chart, weights=face_area, minlength=k)
    texels = np.bincount(chart[covered], minlength=k)
    per_chart = np.sqrt(np.divide(area, texels, out=np.ones(k), where=texels > 0))
    spacing = np.where(covered, per_chart[np.maximum(chart, 0)], 1.0) if k else \
        np.ones(covered.shape)
    return Guide(position, normal, chart, rays, covered, spacing)
