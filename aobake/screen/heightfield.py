"""The height-field truth: AO ray-traced against the depth buffer itself.

Everything a screen-space method can know is the G-buffer; the height field is the solid
that G-buffer describes: each covered pixel q is a facet, the plane through its
reconstructed position P_q with its normal n_q, over the pixel's square; everything behind
the facets (farther from the eye) is solid, infinitely thick; a pixel that sees nothing,
and everything off the image, is empty.  A point X = P + t w of a ray is inside when, at
the pixel its image falls in,

    1/d(X) < 1/d_facet(x, y) - tol,    d_facet = (n_q . P_q) / (n_q . ray(x, y))

(the facet's depth under the image point; the pixel's own depth where the facet is seen
edge-on; tol the buffer's float32 step, ``gbuffer.depth_step``).  A planar scene is
reproduced exactly, so an open plane is open (AO 1).  Rays are cosine-distributed about
the pixel's G-buffer normal, as the ray-traced truth's (``aobake.samplers``, ``aobake.warp``:
the same sampler, replicates and error bars, from a stream of their own keyed by the pixel
index), start at P (no offset: nothing lies in front of a facet) and are marched on their
image: a ray segment projects to a segment of the image, along which 1/d is affine, and is
tested every ``STEP`` pixels until it is inside (occluded), leaves the image (open: what lies
off screen is unknown to a screen-space method too), gets nearer than every covered depth
or farther than all of them (open: nothing can be in front of it there), or reaches the
max distance (open).

**Thickness.**  The height field proper is infinitely thick: a ray that passes behind a
foreground object, however far in front, is blocked (the floor behind a torus knot reads
black).  The screen-space methods all refuse such occluders (Crytek's range check,
Shanmugam's and GTAO's distance limits), so ``thickness`` t makes the solid reach only t
behind each facet (``1/(1/d) - d_facet < t``); t = the radius is the height field those
methods assume, t = inf the one the depth buffer alone implies.

The error then splits: method vs height-field truth is the estimator's part; height-field
vs ray-traced truth is what seeing only a depth buffer loses (thin occluders made
infinitely thick, hidden and off-screen geometry), both at the same max distance.
"""

from __future__ import annotations

import numpy as np

from aobake import stats
from aobake.rng import hash_key
from aobake.samplers import replicate_keys, sample_set
from aobake.screen.gbuffer import Frame, depth_step
from aobake.warp import frames, warp

#: hash stream of the height-field truth's rays (distinct from every other stream)
STREAM_HEIGHTFIELD = 0x5EED_0024
#: the march's step along a ray's image, in pixels: each pixel a ray's image crosses is
#: visited unless the image only clips its corner by less than this
STEP = 0.5
#: rays marched at once (memory: a few dozen float64 per ray)
BLOCK_RAYS = 1 << 18


def occluded(frame: Frame, origins: np.ndarray, directions: np.ndarray,
             max_distance: float, thickness: float = np.inf) -> np.ndarray:
    """(n,) bool: whether each ray (origins (n, 3), unit directions (n, 3), view space) meets
    the height field within ``max_distance`` (inf: unbounded); ``thickness``: how far behind
    a facet (in view depth) the solid reaches (inf: the height field proper)."""
    n = len(origins)
    hit = np.zeros(n, dtype=bool)
    if n == 0:
        return hit
    flat_d = frame.depth.reshape(-1)
    covered = np.isfinite(flat_d)
    d_lo, d_hi = float(flat_d[covered].min()), float(flat_d[covered].max())
    d0 = -origins[:, 2]
    wz = directions[:, 2]  # depth changes by -wz per unit t
    # The farthest t that can matter: the max distance; nearer than every covered depth or
    # farther than all of them nothing can be in front of the ray; and a cap that takes
    # a ray of constant depth off the image.
    with np.errstate(divide="ignore", invalid="ignore"):
        t_end = np.full(n, min(max_distance, 4.0 * d_hi * (frame.half_width + frame.half_height)
                               + 4.0 * d_hi))
        toward = wz > 0
        t_end = np.where(toward, np.minimum(t_end, (d0 - d_lo) / wz), t_end)
        away = wz < 0
        t_end = np.where(away, np.minimum(t_end, (d_hi - d0) / -wz), t_end)
    t_end = np.maximum(t_end, 0.0)
    ends = origins + t_end[:, None] * directions
    x0, y0, _ = frame.project(origins)
    x1, y1, d1 = frame.project(ends)
    # clip the image segment to the image (Liang-Barsky; the start is inside)
    dx, dy = x1 - x0, y1 - y0
    s_max = np.ones(n)
    with np.errstate(divide="ignore", invalid="ignore"):
        for delta, start, size in ((dx, x0, frame.width), (dy, y0, frame.height)):
            s_max = np.where(delta > 0, np.minimum(s_max, (size - start) / delta), s_max)
            s_max = np.where(delta < 0, np.minimum(s_max, -start / delta), s_max)
    s_max = np.clip(np.nan_to_num(s_max, nan=0.0), 0.0, 1.0)
    length = np.hypot(dx, dy) * s_max
    steps = np.ceil(length / STEP).astype(np.int64)
    inv0, inv1 = 1.0 / d0, 1.0 / d1
    live = np.flatnonzero(steps > 0)
    j = 0
    while len(live):
        j += 1
        keep = steps[live] >= j
        live = live[keep]
        if not len(live):
            break
        s = s_max[live] * (j / steps[live])
        x = x0[live] + s * dx[live]
        y = y0[live] + s * dy[live]
        inv = (1.0 - s) * inv0[live] + s * inv1[live]  # 1/d is affine along the image
        q = frame.lookup(x, y)
        d_q = frame.depth_at(q)
        inside = np.isfinite(d_q)
        d_facet = frame.facet_depth(q, x, y)
        with np.errstate(divide="ignore", invalid="ignore"):
            safe = np.where(inside, d_facet, 1.0)
            tol = 2.0 * depth_step(frame, np.where(inside, d_q, 1.0)) / (safe * safe)
            behind = inside & (inv < 1.0 / safe - tol)
            if np.isfinite(thickness):
                behind &= 1.0 / inv - d_facet < thickness
        hit[live[behind]] = True
        live = live[~behind]
    return hit


def estimate(frame: Frame, pixels: np.ndarray, rays: int, max_distance: float,
             sampler: str = "sobol", replicates: int = 8, seed: int = 0,
             weighting: str = "cosine", confidence: float = 0.95,
             thickness: float = np.inf):
    """The height-field truth at flat ``pixels`` (k,) int64 (covered): (ao, stderr, ci_low,
    ci_high) each (k,) float64, rays cast (k,) int32 and the stderr's degrees of freedom.
    ``rays`` per pixel drawn by ``sampler`` in ``replicates`` (their spread is the stderr,
    as the ray-traced truth's), keyed by (seed, pixel index); AO = the fraction of rays
    that escape (1 = open); ``thickness`` as in ``occluded``."""
    pixels = np.asarray(pixels, dtype=np.int64)
    sample = sample_set(sampler, rays, replicates)
    groups, m = sample.groups, sample.m
    key = hash_key(seed, STREAM_HEIGHTFIELD)
    per_block = max(1, BLOCK_RAYS // (groups * m))
    counts = np.empty((len(pixels), groups))
    for start in range(0, len(pixels), per_block):
        part = pixels[start:start + per_block]
        p = frame.positions(part)
        n = frame.normals_at(part)
        u = sample.values(replicate_keys(key, part, groups), 0, m)  # (k, R, m, 2)
        local = warp(u, weighting)
        tangent, bitangent = frames(n)
        w = (local[..., 0:1] * tangent[:, None, None, :] + local[..., 1:2]
             * bitangent[:, None, None, :] + local[..., 2:3] * n[:, None, None, :])
        w /= np.linalg.norm(w, axis=-1, keepdims=True)
        origins = np.broadcast_to(p[:, None, None, :], w.shape).reshape(-1, 3)
        blocked = occluded(frame, origins, w.reshape(-1, 3), max_distance, thickness)
        counts[start:start + len(part)] = (~blocked).reshape(len(part), groups, m).sum(axis=2)
    mean, se, dof = stats.binary_spread(counts, m, sample.iid)
    total = groups * m
    stderr, low, high = stats.error_bars(mean, se, total, dof, confidence)
    return mean, stderr, low, high, np.full(len(pixels), total, dtype=np.int32), dof

