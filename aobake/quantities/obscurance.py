"""Zhukov obscurance: (1/pi) int rho(L) cos dw with rho(L) = 1 - exp(-tau L).

A miss (nothing within the max distance) counts rho = 1: 1 = open, 0 = occluded.
Needs hit distances, hence closest-hit queries.
"""

from __future__ import annotations

import numpy as np

from aobake import stats
from aobake.quantities import ao
from aobake.quantities.base import Quantity, Traced


def rho(distance: np.ndarray, tau: float) -> np.ndarray:
    """Zhukov obscurance rho(L) = 1 - exp(-tau L) in [0, 1]; 1 for a miss (L = inf).

    distance : float32 array, inf on a miss.  Written to avoid 0 * inf at the
    extremes: tau = 0 gives 0 for every hit, tau = inf gives 1 for every hit at L > 0.
    """
    miss = ~np.isfinite(distance)
    hit_l = np.where(miss, 0.0, distance).astype(np.float32)
    if np.isinf(tau):
        value = (hit_l > 0).astype(np.float32)
    elif tau > float(np.finfo(np.float32).max):
        # tau beyond float32 (e.g. --tau 1e308): tau L overflows to inf for every L > 0,
        # rho = 1 there, as for tau = inf (no stray overflow warning on the way).
        value = (hit_l > 0).astype(np.float32)
    else:
        with np.errstate(over="ignore"):  # tau L beyond float32: -expm1(-inf) = 1, exact
            value = -np.expm1(np.float32(-tau) * hit_l)
    return np.where(miss, np.float32(1.0), value)


def moments(traced: Traced) -> dict:
    total, m2 = stats.sums(rho(traced.distance, traced.tau), traced.iid)
    return {"total": total, "m2": m2}  # (k, R) each


def extend(a: dict, b: dict, na: int, nb: int) -> dict:
    total, m2 = stats.merge_sums((a["total"], a["m2"]), (b["total"], b["m2"]), na, nb)
    return {"total": total, "m2": m2}


def finish(moments: dict, traced: Traced, m: int) -> dict:
    groups = moments["total"].shape[1]
    mean, se, dof = stats.spread_of_sums(moments["total"], moments["m2"], m, traced.iid)
    # Exact by construction: with no max distance nothing is hit (rho = 1 for every ray);
    # with tau = inf every ray has rho = 1 (any hit at L > 0, or a miss) or every ray has
    # rho = 0 (an origin inside the ground plane, L = 0): the rays cannot disagree.
    if traced.max_distance == 0 or np.isinf(traced.tau):
        return ao.fields_of(FIELDS, mean, *stats.exact(mean))
    return ao.fields_of(FIELDS, mean, *stats.error_bars(mean, se, groups * m, dof,
                                                        traced.confidence))


FIELDS = ao.scalar_fields("obscurance", "distance-weighted openness: 1 = open, 0 = occluded")


QUANTITY = Quantity(
    name="obscurance",
    value=FIELDS[0],
    error=FIELDS[1],
    interval=FIELDS[2:],
    moments=moments,
    extend=extend,
    finish=finish,
    no_information=ao.no_information_of(FIELDS),
    conventions={
        "cosine": {"obscurance": "(1/pi) int rho(L) cos dw with rho(L) = 1 - exp(-tau L); "
                                 "a miss counts rho = 1"},
        "uniform": {"obscurance": "(1/2pi) int rho(L) dw with rho(L) = 1 - exp(-tau L); "
                                  "a miss counts rho = 1"},
    },
    needs_distance=True,
    summary=ao.summary,
)
