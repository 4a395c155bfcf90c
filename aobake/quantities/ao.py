"""Ambient occlusion: A = (1/pi) int V(w) cos dw (cosine) or (1/2pi) int V(w) dw (uniform).

Directions are drawn from the weighting's own measure, so each ray contributes
f = [ray escapes] and A is the fraction of escaping rays: 1 = fully open,
0 = fully occluded.
"""

from __future__ import annotations

import numpy as np

from aobake import stats
from aobake.quantities.base import Field, Quantity, Traced


def escape_counts(occluded: np.ndarray, kernels=None) -> np.ndarray:
    """(k, R, m) bool occluded -> (k, R) float64 number of rays that escaped."""
    k, groups, m = occluded.shape
    if kernels is None:
        return (m - np.count_nonzero(occluded, axis=2)).astype(np.float64)
    # count_nonzero over a short last axis costs as much as generating the rays.
    blocked = np.empty(k * groups, dtype=np.int32)
    kernels.row_counts(np.ascontiguousarray(occluded), k * groups, m, blocked)
    return (m - blocked).reshape(k, groups).astype(np.float64)


def estimate(traced: Traced):
    # Contributions are 0/1: escape counts are exact and cheaper than float sums.
    counts = escape_counts(traced.occluded, traced.kernels)
    return stats.binary_mean_and_stderr(counts, traced.occluded.shape[2], traced.iid)


def no_information(normals: np.ndarray):
    """The midpoint 1/2 with error 1/2: nothing is known."""
    return np.full(len(normals), 0.5), np.full(len(normals), 0.5)


def summary(value: np.ndarray, error: np.ndarray) -> dict:
    return {"mean": float(value.mean()), **stats.summary(error)}


QUANTITY = Quantity(
    name="ao",
    value=Field("ao", 1, np.float32, ("ao",), "_AO", ("ao",),
                "ambient occlusion: 1 = fully open, 0 = fully occluded"),
    error=Field("ao_stderr", 1, np.float32, ("ao_stderr",), "_AO_STDERR", ("ao_stderr",),
                "one standard error of ao"),
    estimate=estimate,
    no_information=no_information,
    conventions={
        "cosine": {"ao": "cosine-weighted visibility (1/pi) int V(w) cos dw: 1 = fully open, "
                         "0 = fully occluded"},
        "uniform": {"ao": "uniform-weighted visibility (1/2pi) int V(w) dw (the open fraction of "
                          "the hemisphere's solid angle): 1 = fully open, 0 = fully occluded"},
    },
    kernels=("escape_counts",),
    summary=summary,
)
