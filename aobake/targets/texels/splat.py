"""Per-sample values into texels: the mean of each texel's samples (``TexelSamples``).

Used by the texel channels (``aobake.targets.texels.gather``) and by the denoiser's guide
(``aobake.targets.texels.denoise``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from aobake.targets.texels.raster import TexelSamples


def splat_count(samples: TexelSamples, width: int | None = None, height: int | None = None) -> np.ndarray:
    """(height, width) int64 number of samples in each texel."""
    width, height = _size(samples, width, height)
    return np.bincount(samples.texel, minlength=width * height).reshape(height, width)


def splat(samples: TexelSamples, values, width: int | None = None, height: int | None = None) -> np.ndarray:
    """Average per-sample values into texels.

    values : (s,) or (s, c) float.  Returns (height, width, c) float64, the mean
    of the samples in each texel (c = 1 for 1-D values); texels without samples
    are 0 (use ``splat_count`` or ``samples.coverage`` as the mask).
    """
    width, height = _size(samples, width, height)
    values = np.asarray(values, dtype=np.float64)
    if values.ndim == 1:
        values = values[:, None]
    if values.ndim != 2 or values.shape[0] != samples.n_samples:
        raise ValueError(f"values must be ({samples.n_samples},) or ({samples.n_samples}, c), got {values.shape}")
    n = width * height
    count = np.bincount(samples.texel, minlength=n).astype(np.float64)
    out = np.empty((n, values.shape[1]))
    for ch in range(values.shape[1]):
        out[:, ch] = np.bincount(samples.texel, weights=values[:, ch], minlength=n)
    np.divide(out, count[:, None], out=out, where=count[:, None] > 0)
    return out.reshape(height, width, values.shape[1])


def _size(samples: TexelSamples, width, height) -> tuple[int, int]:
    width = samples.width if width is None else int(width)
    height = samples.height if height is None else int(height)
    if (width, height) != (samples.width, samples.height):
        raise ValueError(
            f"size {width}x{height} does not match the samples' {samples.width}x{samples.height}"
        )
    return width, height


def subset(samples: TexelSamples, keep: np.ndarray) -> TexelSamples:
    """The samples where ``keep`` (s,) bool is True (coverage and sharing unchanged)."""
    return replace(samples, texel=samples.texel[keep], face=samples.face[keep],
                   bary=samples.bary[keep], sample=samples.sample[keep],
                   is_fallback=samples.is_fallback[keep])


def texel_counts(samples: TexelSamples) -> np.ndarray:
    """(H, W) int64 the samples in each texel."""
    return np.bincount(samples.texel, minlength=samples.width * samples.height).reshape(
        samples.height, samples.width)
