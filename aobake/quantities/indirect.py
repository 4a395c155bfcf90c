"""Indirect light, one bounce or more (``-q indirect``): the sky's light reflected to the
point by the surfaces it sees (``aobake.paths`` traces the paths).

``(1/pi) int (1 - V(w)) L(h(w)) cos dw`` (cosine; ``--weighting uniform``: ``(1/2pi) int
... dw``) with ``L(h) = rho A(h)`` for one bounce; each first-level ray's sample is rho^k
when its path escapes after k <= ``--bounces`` reflections, else 0.  0 = no indirect
light (an open point, a black world); its largest value is rho / (1 - rho) in a closed
world with many bounces (below 1 for rho <= 1/2).  Error bars as obscurance's: the
replicates' spread of per-ray values in [0, 1].
"""

from __future__ import annotations

import numpy as np

from aobake import stats
from aobake.quantities import ao, obscurance
from aobake.quantities.base import Quantity, Traced


def moments(traced: Traced) -> dict:
    total, m2 = stats.sums(traced.path, traced.iid)
    return {"total": total, "m2": m2}  # (k, R) each, as obscurance's


extend = obscurance.extend  # the same moments: per-replicate sums and squared deviations


def finish(moments: dict, traced: Traced, m: int) -> dict:
    groups = moments["total"].shape[1]
    mean, se, dof = stats.spread_of_sums(moments["total"], moments["m2"], m, traced.iid)
    # Exact by construction: a black world (albedo 0) or no max distance (nothing is hit)
    # gives every ray the sample 0.
    if traced.max_distance == 0 or traced.albedo == 0:
        return ao.fields_of(FIELDS, mean, *stats.exact(mean))
    return ao.fields_of(FIELDS, mean, *stats.error_bars(mean, se, groups * m, dof,
                                                        traced.confidence))


FIELDS = ao.scalar_fields("indirect", "sky light reflected to the point by what it sees "
                                      "(albedo, bounces): 0 = none")


QUANTITY = Quantity(
    name="indirect",
    value=FIELDS[0],
    error=FIELDS[1],
    interval=FIELDS[2:],
    moments=moments,
    extend=extend,
    finish=finish,
    no_information=ao.no_information_of(FIELDS),
    conventions={
        "cosine": {"indirect": "(1/pi) int (1 - V) L(h) cos dw, L(h) = albedo x the cosine AO "
                               "at the hit h (one bounce; --bounces N: a path's sample is "
                               "albedo^k when it escapes after k <= N bounces); two-sided "
                               "Lambertian surfaces under a uniform white sky"},
        "uniform": {"indirect": "(1/2pi) int (1 - V) L(h) dw, L(h) as for cosine (the bounce "
                                "rays are cosine-distributed: Lambertian reflection)"},
    },
    needs_paths=True,
    summary=ao.summary,
)
