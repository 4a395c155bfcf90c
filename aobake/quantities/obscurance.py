"""Zhukov obscurance: (1/pi) int rho(L) cos dw with rho(L) = 1 - exp(-tau L).

A miss (nothing within the max distance) counts rho = 1: 1 = open, 0 = occluded.
Needs hit distances, hence closest-hit queries.
"""

from __future__ import annotations

import numpy as np

from aobake import stats
from aobake.quantities import ao
from aobake.quantities.base import Field, Quantity, Traced


def rho(distance: np.ndarray, tau: float) -> np.ndarray:
    """Zhukov obscurance rho(L) = 1 - exp(-tau L) in [0, 1]; 1 for a miss (L = inf).

    distance : float32 array, inf on a miss.  Written to avoid 0 * inf at the
    extremes: tau = 0 gives 0 for every hit, tau = inf gives 1 for every hit at L > 0.
    """
    miss = ~np.isfinite(distance)
    hit_l = np.where(miss, 0.0, distance).astype(np.float32)
    if np.isinf(tau):
        value = (hit_l > 0).astype(np.float32)
    else:
        value = -np.expm1(np.float32(-tau) * hit_l)
    return np.where(miss, np.float32(1.0), value)


def estimate(traced: Traced):
    return stats.mean_and_stderr(rho(traced.distance, traced.tau), traced.iid)


QUANTITY = Quantity(
    name="obscurance",
    value=Field("obscurance", 1, np.float32, ("obscurance",), "_OBSCURANCE", ("obscurance",),
                "distance-weighted openness: 1 = open, 0 = occluded"),
    error=Field("obscurance_stderr", 1, np.float32, ("obscurance_stderr",), "_OBSCURANCE_STDERR",
                ("obscurance_stderr",), "one standard error of obscurance"),
    estimate=estimate,
    no_information=ao.no_information,
    conventions={
        "cosine": {"obscurance": "(1/pi) int rho(L) cos dw with rho(L) = 1 - exp(-tau L); "
                                 "a miss counts rho = 1"},
        "uniform": {"obscurance": "(1/2pi) int rho(L) dw with rho(L) = 1 - exp(-tau L); "
                                  "a miss counts rho = 1"},
    },
    needs_distance=True,
    summary=ao.summary,
)
