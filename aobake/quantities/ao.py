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


def moments(traced: Traced) -> dict:
    # Contributions are 0/1: escape counts are exact and cheaper than float sums.
    return {"escapes": escape_counts(traced.occluded, traced.kernels)}  # (k, R)


def extend(a: dict, b: dict, na: int, nb: int) -> dict:
    return {"escapes": a["escapes"] + b["escapes"]}  # exact: integers below 2^53


def finish(moments: dict, traced: Traced, m: int) -> dict:
    counts = moments["escapes"]
    groups = counts.shape[1]
    mean, se, dof = stats.binary_spread(counts, m, traced.iid)
    if traced.max_distance == 0:  # every ray gives the same answer (1, or 0 inside the ground)
        return fields_of(FIELDS, mean, *stats.exact(mean))
    return fields_of(FIELDS, mean, *stats.error_bars(mean, se, groups * m, dof, traced.confidence))


def scalar_fields(name: str, value: str) -> tuple:
    """The four fields of a scalar quantity in [0, 1] (value, stderr, interval ends),
    named ``name``, ``name_stderr``, ``name_ci_low``, ``name_ci_high`` everywhere (glTF in
    capitals with a leading ``_``)."""
    def field(suffix, meaning):
        full = name + suffix
        return Field(full, 1, np.float32, (full,), "_" + full.upper(), (full,), meaning)
    return (field("", value), field("_stderr", f"one standard error of {name}"),
            field("_ci_low", f"lower end of the confidence interval of {name}"),
            field("_ci_high", f"upper end of the confidence interval of {name}"))


def fields_of(fields: tuple, mean, stderr, low, high) -> dict:
    """The field dict of a scalar quantity with ``fields`` (from scalar_fields)."""
    return dict(zip((f.name for f in fields), (mean, stderr, low, high)))


def no_information_of(fields: tuple):
    def no_information(normals: np.ndarray) -> dict:
        """The midpoint 1/2 with error 1/2 and the interval [0, 1]: nothing is known."""
        k = len(normals)
        return fields_of(fields, np.full(k, 0.5), np.full(k, 0.5), np.zeros(k), np.ones(k))
    return no_information


FIELDS = scalar_fields("ao", "ambient occlusion: 1 = fully open, 0 = fully occluded")


def summary(value: np.ndarray, error: np.ndarray) -> dict:
    return {"mean": float(value.mean()), **stats.summary(error)}


QUANTITY = Quantity(
    name="ao",
    value=FIELDS[0],
    error=FIELDS[1],
    interval=FIELDS[2:],
    moments=moments,
    extend=extend,
    finish=finish,
    no_information=no_information_of(FIELDS),
    conventions={
        "cosine": {"ao": "cosine-weighted visibility (1/pi) int V(w) cos dw: 1 = fully open, "
                         "0 = fully occluded"},
        "uniform": {"ao": "uniform-weighted visibility (1/2pi) int V(w) dw (the open fraction of "
                          "the hemisphere's solid angle): 1 = fully open, 0 = fully occluded"},
    },
    kernels=("escape_counts",),
    summary=summary,
)
