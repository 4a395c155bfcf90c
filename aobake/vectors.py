"""Row-vector helpers shared by every stage (one zero-safe normaliser, one shape check)."""

from __future__ import annotations

import numpy as np

from aobake.errors import InputError


def normalize(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit rows of ``vectors`` (..., 3) float64 and their lengths (..., 1) float64.

    Rows of zero or non-finite length become zero rather than NaN (callers decide
    what such a row means: no normal, no direction).
    """
    length = np.linalg.norm(vectors, axis=-1, keepdims=True)
    ok = np.isfinite(length) & (length > 0)
    return np.divide(vectors, length, out=np.zeros(np.shape(vectors)), where=ok), length


def check_rows(name: str, array, width: int = 3, n: int | None = None,
               dtype=np.float64) -> np.ndarray:
    """``array`` as (n, width) ``dtype``; ValueError naming ``name`` and the shape otherwise."""
    array = np.asarray(array)
    want = f"({'n' if n is None else n}, {width})"
    if array.dtype.kind not in "biuf":  # complex, object, strings: not coordinates
        raise InputError(f"{name} must be real numbers, got dtype {array.dtype}")
    if array.ndim != 2 or array.shape[1] != width or (n is not None and len(array) != n):
        raise InputError(f"{name} must be {want}, got {array.shape}")
    return array.astype(dtype, copy=False)
