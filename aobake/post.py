"""Image-space post-processing of baked texel maps.

Images follow the texel convention of ``aobake.targets.texels``: arrays
``(H, W, C)`` with row 0 at the top of the image (v near 1).

Gutters are filled in two steps: ``dilate`` fills ``padding`` rings around the charts
exactly (each texel the mean of its filled 8-neighbours), then ``push_pull`` fills every
texel beyond them from a pyramid of masked means, so that no level of a box-filtered mip
chain mixes an empty (black) texel into a chart.
"""

from __future__ import annotations

import numpy as np

from aobake import _native

# The 8 neighbours of a texel as (row, col) offsets.
_NEIGHBOURS = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)]


def _checked(image, mask) -> tuple[np.ndarray, np.ndarray]:
    """(image (H, W, C), mask (H, W) bool) as arrays, or ValueError naming the bad shape."""
    image = np.asarray(image)
    mask = np.asarray(mask, dtype=bool)
    if image.ndim != 3:
        raise ValueError(f"image must be (H, W, C), got {image.shape}")
    if mask.shape != image.shape[:2]:
        raise ValueError(f"mask must be {image.shape[:2]}, got {mask.shape}")
    return image, mask


def dilate(image, mask, padding: int, compiled: bool | None = None
           ) -> tuple[np.ndarray, np.ndarray]:
    """Fill the gutter around covered texels, ring by ring.

    image : (H, W, C) float; mask : (H, W) bool, True where the texel holds a
    baked value.  padding : number of rings (texels) to fill; 0 returns the
    inputs unchanged.

    Each ring fills every uncovered texel that has at least one filled
    8-neighbour with the mean of those neighbours (as filled before this ring),
    so after P rings every texel within Chebyshev distance P of the mask holds a
    value and bilinear or mip-mapped lookups near chart borders do not pull in
    the background.  Texels inside ``mask`` are never changed.

    Returns (image (H, W, C) float64, mask (H, W) bool): the new image and the
    mask of texels that now hold a value (input mask plus filled rings).
    compiled : the rings in the compiled kernel (``dilate_rings``; default: when it was
    built and not forced off, see ``aobake._native``) or in numpy; the same bits.
    """
    image, mask = _checked(image, mask)
    if int(padding) != padding or padding < 0:
        raise ValueError(f"padding must be a non-negative integer, got {padding}")
    if padding == 0:
        return image, mask
    # Background values never enter a mean: they are zeroed and not counted.  (copyto with
    # a mask broadcast over the channels: one pass, where boolean indexing took three.)
    out = np.zeros(image.shape, dtype=np.float64)
    np.copyto(out, image, where=mask[..., None])
    filled = mask.copy()
    h, w = filled.shape
    kernels = _native.kernels() if compiled in (None, True) else None
    if compiled and kernels is None:
        raise RuntimeError("aobake._kernels was not built")
    if kernels is not None:  # _rings, ring for ring, in one pass per ring
        kernels.dilate_rings(out.reshape(-1), filled.reshape(-1), h, w, out.shape[2],
                             int(padding))
    else:
        _rings(out, filled, int(padding))
    # Texels beyond the last ring keep their input values.
    np.copyto(out, image, where=~filled[..., None])
    return out, filled


def _rings(out: np.ndarray, filled: np.ndarray, padding: int) -> None:
    """``dilate``'s rings in numpy, in place (the reference of the compiled
    ``dilate_rings``): out (H, W, C) float64 with the background zeroed, filled (H, W) bool."""
    h, w = filled.shape
    for _ in range(padding):
        # The ring: unfilled texels with a filled 8-neighbour (a 3x3 dilation of the
        # bool mask).  Only its texels are averaged, so a ring costs its perimeter,
        # not the whole image.
        grown = filled.copy()
        for dr, dc in _NEIGHBOURS:
            grown[max(0, -dr):h - max(0, dr), max(0, -dc):w - max(0, dc)] |= \
                filled[max(0, dr):h - max(0, -dr), max(0, dc):w - max(0, -dc)]
        rows, cols = np.nonzero(grown & ~filled)
        if not len(rows):
            break
        total = np.zeros((len(rows), out.shape[2]))
        count = np.zeros(len(rows))
        for dr, dc in _NEIGHBOURS:  # fixed order: the sums are reproducible
            r, c = rows + dr, cols + dc
            ok = (r >= 0) & (r < h) & (c >= 0) & (c < w)
            ok[ok] = filled[r[ok], c[ok]]
            total[ok] += out[r[ok], c[ok]]
            count += ok
        out[rows, cols] = total / count[:, None]
        filled[rows, cols] = True


def push_pull(image, mask, dtype=np.float64) -> np.ndarray:
    """Fill every texel outside ``mask`` from a pyramid of masked means (push-pull).

    image : (H, W, C) float; mask : (H, W) bool, True where the texel holds a value
    (covered or dilated).  Any H, W >= 1: odd, non-square, not powers of two.
    dtype : the float type computed in and returned (float32 halves the memory traffic
    for a caller that writes float32 anyway; counts are float64 at any dtype).

    Push: level k + 1 texel (i, j) sums the weights and weighted values of level k's
    2x2 block (2i..2i+1, 2j..2j+1); a block running past an odd edge has only the texels
    that exist (the missing ones weigh 0), so level k is ceil(H / 2^k) x ceil(W / 2^k),
    down to 1 x 1.  Level 0 weighs 1 where ``mask`` and 0 elsewhere, so a level-k texel's
    value is the mean of the masked level-0 texels in its 2^k x 2^k footprint (sums carried
    down the pyramid, not means of means).  Pull: from 1 x 1 back to level 0, every texel
    of weight 0 takes its parent's value (piecewise constant).  So an unmasked texel holds
    the mean of the masked texels of the smallest aligned 2^k block around it that has any.

    Why piecewise constant and not a bilinear pull: a box-filtered mip texel (2x2 means
    on the same grid, odd edges as above) whose footprint holds masked texels then averages
    only values made from that footprint's own masked texels, never a neighbouring chart
    or the background.  A bilinear pull would be smoother in the gutters, but it blends the
    neighbouring blocks (other charts included) into those footprints.
    Every fill value is a convex combination of masked values with the same weights in
    every channel, so it stays in their range and keeps every order between channels
    (``ci_low <= value <= ci_high``); it needs no renormalisation except for directions.

    Returns (H, W, C) ``dtype`` (a view of channel-major planes): masked texels unchanged
    (bit for bit, after the cast to ``dtype``), every other texel filled; a plain copy when
    ``mask`` is empty (nothing to fill from) or full.
    """
    image, mask = _checked(image, mask)
    dtype = np.dtype(dtype)
    if dtype.kind != "f":
        raise ValueError(f"dtype must be a float type, got {dtype}")
    h, w, c = image.shape
    if mask.all() or not mask.any():
        return np.array(image, dtype=dtype)
    # Channel-major planes (C, H, W), each level padded to even sides with weight-0 texels
    # (so 2x2 blocks are plain strided views and a parent repeated 2x2 covers its level):
    # every pass is then a whole-plane, memory-bound numpy operation.
    keep = np.zeros((h + h % 2, w + w % 2), dtype=bool)
    keep[:h, :w] = mask
    planes = np.zeros((c,) + keep.shape, dtype=dtype)
    # The transpose goes in bands of rows that stay in cache (a whole-image transpose of 13
    # channels reads every cache line 13 times: 3x slower).  Unmasked values never enter a
    # sum (they may be NaN): zeroed while the band is in cache, and weight 0.
    band = max(1, (1 << 19) // (w * c * image.itemsize))
    for r in range(0, h, band):
        end = min(r + band, h)
        target = planes[:, r:end, :w]
        target[...] = np.moveaxis(image[r:end], -1, 0)
        np.copyto(target, 0, where=~mask[r:end])
    # Push: sums of weights and values, level by level down to 1 x 1.
    weight, total = keep.astype(np.float64), planes  # float64 counts: exact at any size
    levels = []
    while weight.shape != (1, 1):
        weight, total = _even(_block_sum(weight)), _even(_block_sum(total))
        levels.append((weight, total))
    # Pull, coarsest first: the mean where a level has weight, the parent's value elsewhere.
    # The 1 x 1 level has weight > 0 (mask is not empty).
    value = total / weight.astype(dtype)
    for weight, total in reversed(levels[:-1]):
        has = weight > 0
        total /= np.where(has, weight, 1.0).astype(dtype)  # 0 / 1 = 0 in the holes
        _pull(total, ~has, value)
        value = total
    # Level 0: only the holes are written; the masked texels keep their values, bit for bit.
    _pull(planes, ~keep, value)
    return np.moveaxis(planes[:, :h, :w], 0, -1)


def _block_sum(a: np.ndarray) -> np.ndarray:
    """(..., h, w) with h, w even -> (..., h/2, w/2): sums of 2x2 blocks."""
    # Pairs of rows first (contiguous inner loops), then pairs of columns; a fixed order
    # of the terms, so the sums are reproducible.
    rows = a[..., 0::2, :] + a[..., 1::2, :]
    return rows[..., 0::2] + rows[..., 1::2]


def _even(a: np.ndarray) -> np.ndarray:
    """(..., h, w) -> (..., h + h % 2, w + w % 2), padded with zeros (weight 0); 1 x 1 stays."""
    h, w = a.shape[-2:]
    if (h, w) == (1, 1) or not (h % 2 or w % 2):
        return a
    return np.pad(a, [(0, 0)] * (a.ndim - 2) + [(0, h % 2), (0, w % 2)])


def _pull(level: np.ndarray, holes: np.ndarray, parent: np.ndarray) -> None:
    """Write into ``level`` (C, h, w), h and w even, where ``holes`` (h, w) bool, the value
    of its parent texel in ``parent`` (C, >= h/2, >= w/2); other texels are left alone."""
    c, h, w = level.shape
    # Repeat along columns, then broadcast over the two rows of each block: one pass over
    # the level with contiguous inner loops, no full-size temporary.
    half = np.repeat(parent[:, :h // 2, :w // 2], 2, axis=2)
    np.copyto(level.reshape(c, h // 2, 2, w), half[:, :, None, :],
              where=holes.reshape(h // 2, 2, w))
