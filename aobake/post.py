"""Image-space post-processing of baked texel maps.

Images follow the texel convention of ``aobake.targets.texels``: arrays
``(H, W, C)`` with row 0 at the top of the image (v near 1).
"""

from __future__ import annotations

import numpy as np

# The 8 neighbours of a texel as (row, col) offsets.
_NEIGHBOURS = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)]


def dilate(image, mask, padding: int) -> tuple[np.ndarray, np.ndarray]:
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
    """
    image = np.asarray(image)
    mask = np.asarray(mask, dtype=bool)
    if image.ndim != 3:
        raise ValueError(f"image must be (H, W, C), got {image.shape}")
    if mask.shape != image.shape[:2]:
        raise ValueError(f"mask must be {image.shape[:2]}, got {mask.shape}")
    if int(padding) != padding or padding < 0:
        raise ValueError(f"padding must be a non-negative integer, got {padding}")
    if padding == 0:
        return image, mask
    out = np.array(image, dtype=np.float64)
    # Background values never enter a mean: they are zeroed and not counted.
    out[~mask] = 0.0
    filled = mask.copy()
    h, w = filled.shape
    for _ in range(int(padding)):
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
    # Texels beyond the last ring keep their input values.
    out[~filled] = np.asarray(image, dtype=np.float64)[~filled]
    return out, filled
