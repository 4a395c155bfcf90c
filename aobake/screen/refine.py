"""The course's second refinement: an N x N blur that does not cross depth or normal
discontinuities, matched to the rotation pattern (every N x N window holds each of the N^2
kernel rotations once, so the blur averages them).

Window of pixel p: offsets (dy, dx) in [-floor(N/2), N - floor(N/2))^2 (N even: one more
on the negative side, as a 4 x 4 blur over a 4 x 4 noise tile).  A neighbour q counts, with
weight 1, when it is on the image and covered and lies on p's surface:

    |n_p . (P_q - P_p)| <= t_d x pixel_size(d_p)     (within t_d pixel sizes of p's tangent
                                                       plane: a depth edge is never crossed,
                                                       a slope is not an edge)
    n_p . n_q >= cos(t_n)                             (a crease is never crossed)

and the blurred value is the mean of the counted raw values (p itself always counts).
Each blurred value is a pure function of the G-buffer: it reads the raw values of its
window, each a pure function of the G-buffer.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from aobake.screen.gbuffer import Frame
from aobake.vectors import distinct


def window(period: int) -> np.ndarray:
    """(N^2, 2) int64 offsets (dy, dx) of the N x N window."""
    lo = -(period // 2)
    r = np.arange(lo, lo + period)
    dy, dx = np.meshgrid(r, r, indexing="ij")
    return np.stack([dy.ravel(), dx.ravel()], axis=1)


def neighbours(frame: Frame, pixels: np.ndarray, period: int) -> np.ndarray:
    """(k, N^2) int64 flat indices of each pixel's window, -1 off the image or uncovered."""
    r, c = np.divmod(np.asarray(pixels, dtype=np.int64), frame.width)
    offsets = window(period)
    rr = r[:, None] + offsets[None, :, 0]
    cc = c[:, None] + offsets[None, :, 1]
    inside = (rr >= 0) & (rr < frame.height) & (cc >= 0) & (cc < frame.width)
    index = np.where(inside, rr * frame.width + cc, -1)
    covered = frame.covered.reshape(-1)[np.maximum(index, 0)]
    return np.where(inside & covered, index, -1)


def weights(frame: Frame, pixels: np.ndarray, window_pixels: np.ndarray,
            depth_tolerance: float, normal_degrees: float) -> np.ndarray:
    """(k, N^2) bool: which window pixels count for each pixel (module docstring)."""
    ok = window_pixels >= 0
    q = np.maximum(window_pixels, 0)
    p_pos = frame.positions(pixels)
    n_p = frame.normals_at(pixels)
    q_pos = frame.positions(q.ravel()).reshape(q.shape + (3,))
    n_q = frame.normals.reshape(-1, 3)[q]
    with np.errstate(invalid="ignore"):
        off_plane = np.abs(np.einsum("kj,ksj->ks", n_p, q_pos - p_pos[:, None, :]))
    size = frame.pixel_size(-p_pos[:, 2])[:, None]
    ok &= off_plane <= depth_tolerance * size
    ok &= np.einsum("kj,ksj->ks", n_p, n_q) >= math.cos(math.radians(normal_degrees))
    ok |= window_pixels == pixels[:, None]  # p itself always counts
    return ok


def blurred(frame: Frame, pixels: np.ndarray, raw: Callable[[np.ndarray], np.ndarray],
            period: int, depth_tolerance: float = 1.0, normal_degrees: float = 30.0,
            block: int = 65536) -> np.ndarray:
    """The blurred values (k,) float64 at flat ``pixels`` (k,): ``raw(pixels) -> values`` is
    evaluated once at every pixel some window reads (the union of the windows), then each
    pixel averages the counted ones of its window."""
    pixels = np.asarray(pixels, dtype=np.int64)
    out = np.empty(len(pixels))
    for start in range(0, len(pixels), block):
        part = pixels[start:start + block]
        win = neighbours(frame, part, period)
        # (a mask, not np.unique: numpy 2 hashes integers, slow when most are distinct)
        support = distinct(win[win >= 0], frame.height * frame.width)
        values = raw(support)
        slot = np.searchsorted(support, np.maximum(win, 0))
        slot = np.minimum(slot, len(support) - 1)
        counted = weights(frame, part, win, depth_tolerance, normal_degrees)
        counted &= win >= 0
        sums = np.where(counted, values[slot], 0.0).sum(axis=1)
        out[start:start + len(part)] = sums / counted.sum(axis=1)
    return out
