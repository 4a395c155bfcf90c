"""From per-sample estimates back to texels: splatting, texel errors, gutters, channels.

A texel's value is the mean of its s sample estimates (K surface positions, each
with its own rays); its standard error is sqrt(sum se^2) / s.  Directions (bent
normals) are averaged and normalised, optionally in tangent space.  Channels are
(H, W) images in the texel convention of ``aobake.targets.texels.raster`` (row 0
at the top, v near 1), dilated ``padding`` texels into the gutters and push-pull
filled beyond (``aobake.post``), except ``rays`` and ``coverage`` (0 outside the charts).
Before the gutters, the texels that UV seams read may be adjusted so that bilinear lookups
agree across the seams (``aobake.targets.texels.seams``).
"""

from __future__ import annotations

import time

import numpy as np

from aobake import stats
from aobake.post import dilate, push_pull
from aobake.targets.texels.denoise import denoise as filter_texels
from aobake.targets.texels.denoise import make_guide
from aobake.targets.texels.raster import TexelSamples
from aobake.targets.texels.seams import Pending, SeamChannel, erase_seams
from aobake.targets.texels.splat import splat, subset, texel_counts
from aobake.vectors import normalize


def channels(quantities, samples: TexelSamples, values: dict, rays: np.ndarray, padding: int,
             to_tangent=None, dof: int = 0, confidence: float = 0.95, seams=None,
             timings: dict | None = None, seam_info: dict | None = None, denoise=None,
             compiled: bool | None = None, threads: int = 1
             ) -> tuple[dict, np.ndarray, np.ndarray]:
    """Texel channels of a bake.

    quantities : the Quantity objects baked, samples : s sample points,
    values : field name -> (s,) / (s, 3) float64 estimates, rays : (s,) int32,
    to_tangent : None, or a function (traced samples, traced (s,) bool, bent (t, 3) float64)
    -> bent in tangent space, dof : degrees of freedom of one sample's stderr (R - 1 or
    n - 1), confidence : the interval level.
    Returns (channels: name -> (H, W) float32 in output order, covered (H, W) bool,
    filled (H, W) bool covered or padded).  ``filled`` marks the covered texels and the
    ``padding`` rings of exact dilation; every other texel of the value, error and interval
    channels holds the push-pull fill (``aobake.post.push_pull``), of ``rays`` and
    ``coverage`` 0.
    seams : None (no seam erasure) or the ``aobake.targets.texels.seams.SeamMesh`` baked:
    before the gutters are filled, the value channels are adjusted so that bilinear lookups
    agree across its UV seams (``seams.erase_seams``; the time goes to ``timings["seams_s"]``
    and its counts to ``seam_info``; ``compiled`` as in ``seams.solve``).  An adjusted
    texel keeps its stderr (an upper bound on the adjusted value's: see ``seams``) and its
    interval becomes the hull of the baked one and the one around the adjusted value.  The
    seam system needs the covered texels only: it is made on its own thread
    (``seams.Pending``, ``timings["seam_system_s"]``) while this one splats the values and
    their intervals, and the erasure waits for it (the wait counts in ``seams_s``).
    threads : the seam solve's.
    denoise : None, or (points (s, 3), normals (s, 3) float64 of all samples, uv (t, 2),
    faces_uv (f, 3) the bake UVs, face areas (f,) float64): adds ``<q>_denoised`` and
    ``<q>_denoised_stderr`` for each scalar quantity, filtered from the baked texels
    (``aobake.targets.texels.denoise``), then seam-erased and gutter-filled like the rest
    (time in ``timings["denoise_s"]``).
    """
    width, height = samples.width, samples.height
    traced = rays > 0  # samples on zero-area faces have no normal: left out of the texel means
    sub = samples if traced.all() else subset(samples, traced)
    count = texel_counts(sub)
    covered = count > 0
    pending_system = None
    if seams is not None:
        # the pattern, its last step, on the bake's threads: the splatting is over by then
        pending_system = Pending(seams, covered, padding, threads)
    rays_img = np.bincount(sub.texel, weights=rays[traced].astype(np.float64),
                           minlength=width * height).reshape(height, width)
    out = {}
    order = []  # channel names in output order (value, stderr, interval, per quantity)
    intervals = []  # (quantity, rays, degrees of freedom per texel) of the interval channels
    for q in quantities:
        value, error = values[q.value.name][traced], values[q.error.name][traced]
        if q.texel == "direction":
            if to_tangent is not None:
                value = to_tangent(sub, traced, value)
            mean = splat(sub, value)
            mean = normalize(mean)[0]
            for axis, label in enumerate(q.value.exr):
                out[label] = mean[..., axis]
        else:
            out[q.value.exr[0]] = splat(sub, value)[..., 0]
        # The texel averages its s independent samples: stderr sqrt(sum se^2) / s (an angle
        # for directions).
        variance = error ** 2
        mean_variance = splat(sub, variance)[..., 0]
        out[q.error.exr[0]] = stats.texel_stderr(mean_variance, count)
        if q.texel == "direction":
            # A sample with no information (its angle error is the pi/2 sentinel) leaves the
            # texel's direction without a measurable error too: pi/2, not an average of it.
            from aobake.quantities.bent_normal import NO_INFORMATION_ANGLE

            blind = splat(sub, (error >= NO_INFORMATION_ANGLE).astype(np.float64))[..., 0] > 0
            out[q.error.exr[0]] = np.where(blind, NO_INFORMATION_ANGLE, out[q.error.exr[0]])
        order += list(q.value.exr if q.texel == "direction" else q.value.exr[:1])
        order.append(q.error.exr[0])
        if q.interval:  # from the baked values, widened below where the erasure moves them
            order += [q.interval[0].exr[0], q.interval[1].exr[0]]
            low, high, n, dof_t = _texel_interval(out[q.value.exr[0]], out[q.error.exr[0]],
                                                  mean_variance, variance, sub, rays_img,
                                                  count, dof, confidence)
            out[q.interval[0].exr[0]], out[q.interval[1].exr[0]] = low, high
            intervals.append((q, n, dof_t))
    erase = [SeamChannel.of(q) for q in quantities]
    if denoise is not None:
        clock = time.perf_counter()
        names = _denoised(out, quantities, sub, traced, covered, rays_img, denoise)
        order += names
        # derived channels: erased like the rest, but not counted in the seams' report
        erase += [SeamChannel((value,), error, counted=False)
                  for value, error in zip(names[0::2], names[1::2])]
        if timings is not None:
            timings["denoise_s"] = time.perf_counter() - clock
    erased = None
    if seams is not None:
        clock = time.perf_counter()
        prepared = pending_system.take()
        erased = erase_seams(out, erase, seams, covered, padding,
                             directions=to_tangent is None, compiled=compiled,
                             prepared=prepared, threads=threads)
        if timings is not None:
            timings["seams_s"] = time.perf_counter() - clock
            if prepared is not None:  # made on its thread while the values were splatted
                timings["seam_system_s"] = prepared.seconds
        del prepared  # its memory is the gutters' next
        if seam_info is not None and erased is not None:
            seam_info.update(erased.info)
    # The intervals (from the baked values, bit for bit as without erasure) at adjusted
    # texels widened to hold the interval around the adjusted value too.
    if erased is not None:
        for q, n, dof_t in intervals:
            _widen_interval(out[q.interval[0].exr[0]], out[q.interval[1].exr[0]],
                            erased.adjusted, out[q.value.exr[0]], out[q.error.exr[0]], n,
                            dof_t, confidence)
    out = {name: out[name] for name in order}
    names = list(out)
    stack = np.stack([out[n] for n in names], axis=-1)
    # Gutters: `padding` rings of exact nearest-texel dilation, then push-pull fills every
    # texel beyond them, so no box-filtered mip level mixes an empty texel into a chart.
    # In float32, what is written: the covered and dilated texels round exactly as before.
    stack, filled = dilate(stack, covered, padding, compiled=compiled)
    stack = push_pull(stack, filled, np.float32)
    for i, name in enumerate(names):
        out[name] = stack[..., i]
    for q in quantities:
        if q.texel == "direction":  # a mean of unit vectors is shorter: renormalised
            _renormalise([out[label] for label in q.value.exr], ~filled)
    # `rays` and `coverage` are not filled: 0 outside the charts tells real texels from fill.
    out["rays"] = rays_img
    out["coverage"] = samples.coverage.astype(np.float64) * covered
    return ({name: np.ascontiguousarray(image, dtype=np.float32) for name, image in out.items()},
            covered, filled)


def plain_channels(samples: TexelSamples, values: dict, sampled: np.ndarray, padding: int,
                   seams=None, timings: dict | None = None, seam_info: dict | None = None,
                   compiled: bool | None = None, threads: int = 1, to_tangent=None
                   ) -> tuple[dict, np.ndarray, np.ndarray]:
    """Texel channels of a method that casts no rays and has no stderr (an approximation,
    a file's values): each scalar field's texel mean, and each direction's (a (s, 3) field,
    the bent normal: channels NAME.X, NAME.Y, NAME.Z) normalised mean, in tangent space with
    ``to_tangent`` (as ``channels``), seam-erased with equal weights (no error to weigh the
    texels by) and gutter-filled like ``channels``, plus ``coverage``.

    values : field name -> (s,) or (s, 3) float64 per sample, sampled : (s,) bool the
    samples with a normal (the rest are left out of the texel means).  Returns as
    ``channels``.
    """
    width, height = samples.width, samples.height
    sub = samples if sampled.all() else subset(samples, sampled)
    count = texel_counts(sub)
    covered = count > 0
    out, erase, directions = {}, [], []
    for name, value in values.items():
        if value.ndim == 1:
            out[name] = splat(sub, value[sampled])[..., 0]
            erase.append(SeamChannel((name,), "_weight"))
        elif value.ndim == 2 and value.shape[1] == 3:
            value = value[sampled]
            if to_tangent is not None:
                value = to_tangent(sub, sampled, value)
            mean = normalize(splat(sub, value))[0]
            labels = tuple(f"{name}.{axis}" for axis in "XYZ")
            for axis, label in enumerate(labels):
                out[label] = mean[..., axis]
            erase.append(SeamChannel(labels, "_weight", direction=True))
            directions.append(labels)
    names = list(out)
    if seams is not None and names:
        clock = time.perf_counter()
        # the data term's weight: one for every texel (the same error everywhere)
        out["_weight"] = np.ones((height, width))
        erased = erase_seams(out, erase, seams, covered, padding,
                             directions=to_tangent is None, compiled=compiled,
                             threads=threads)
        del out["_weight"]
        if timings is not None:
            timings["seams_s"] = time.perf_counter() - clock
        if seam_info is not None and erased is not None:
            seam_info.update(erased.info)
    stack = np.stack([out[n] for n in names], axis=-1)
    stack, filled = dilate(stack, covered, padding, compiled=compiled)
    stack = push_pull(stack, filled, np.float32)
    out = {name: stack[..., i] for i, name in enumerate(names)}
    for labels in directions:  # a mean of unit vectors is shorter: renormalised
        _renormalise([out[label] for label in labels], ~filled)
    out["coverage"] = samples.coverage.astype(np.float64) * covered
    return ({name: np.ascontiguousarray(image, dtype=np.float32) for name, image in out.items()},
            covered, filled)


def _denoised(out, quantities, sub, traced, covered, rays_img, denoise) -> list:
    """Add the denoised channels of the scalar quantities to ``out``; their names, value
    then stderr for each quantity."""
    points, normals, uv, faces_uv, face_area = denoise
    guide = make_guide(sub, points[traced], normals[traced], uv, faces_uv, face_area, covered,
                       rays_img)
    names = []
    for q in quantities:
        if q.texel == "direction":
            continue
        name = q.value.exr[0]
        value, error = filter_texels(out[name], out[q.error.exr[0]], guide)
        out[name + "_denoised"], out[name + "_denoised_stderr"] = value, error
        names += [name + "_denoised", name + "_denoised_stderr"]
    return names


def _renormalise(axes, where) -> None:
    """Unit directions, in place, where ``where`` (H, W) bool: axes are the three (H, W)
    float component planes.  A zero mean (opposite directions cancelling) stays zero, the
    no-direction convention of ``aobake.vectors.normalize``."""
    length = np.sqrt(sum(a * a for a in axes))
    scale = np.ones_like(length)
    scale = np.divide(scale, length, out=scale, where=where & (length > 0))
    for a in axes:
        a *= scale  # 1 elsewhere: those texels keep their bits


def _texel_interval(value, stderr, mean_variance, variance, sub, texel_rays, count, dof,
                    confidence):
    """The interval of a texel that averages its s samples' estimates.

    value, stderr, mean_variance (the mean of the samples' variances), texel_rays, count :
    (H, W) per texel; variance : (s,) per sample of ``sub``; dof : a sample's degrees of
    freedom.  t quantile with the Welch-Satterthwaite degrees of freedom of the sum of the
    samples' variances, (sum v)^2 / sum(v^2 / dof), rounded down (conservative), and the
    rule-of-three floor of all the texel's rays (see ``aobake.stats.error_bars``).
    Returns (low, high, rays, degrees of freedom), each (H, W) float64.
    """
    total = mean_variance * count  # sum of v
    squares = splat(sub, variance ** 2)[..., 0] * count  # sum of v^2
    with np.errstate(divide="ignore", invalid="ignore"):
        welch = np.where(squares > 0, dof * total ** 2 / squares, dof)
    covered = count > 0
    n, dof = np.where(covered, texel_rays, 1.0), np.where(covered, welch, 0.0)
    # Covered texels only (the rest, [0, 1]: nothing measured, and the gutter fill replaces
    # them): spot's 1024^2 map is half empty, and the t quantiles cost 0.13 s over all of it.
    low, high = np.zeros(value.shape), np.ones(value.shape)
    _, low[covered], high[covered] = stats.error_bars(value[covered], stderr[covered],
                                                      n[covered], dof[covered], confidence)
    return low, high, n, dof


def _widen_interval(low, high, where, new, stderr, n, dof, confidence) -> None:
    """The intervals ``low``, ``high`` (H, W) of the texels ``where`` (H, W) bool, whose value
    the seam erasure changed to ``new`` (H, W), made (in place) the hull of the baked one
    and the one (same stderr, rays ``n`` and degrees of freedom ``dof``) around the new
    value: it holds the value and covers the baked texel's mean as often as before."""
    _, new_low, new_high = stats.error_bars(new[where], stderr[where], n[where], dof[where],
                                            confidence)
    low[where] = np.minimum(low[where], new_low)
    high[where] = np.maximum(high[where], new_high)
