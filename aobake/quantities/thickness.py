"""Thickness: the mean distance from a surface point through the inside to the back side.

    T = (1/pi) int_{H-} min(L(w), C) |cos| dw     (cosine weighting; uniform: (1/2pi) int)

over the *inward* hemisphere H- about -n, L(w) the distance to the first surface the ray
meets (the far side of the object, seen from inside: any face, front or back), C the cap.
Rays are drawn from the weighting's own measure about -n, so each contributes
f = min(L, C) and T is their mean (0 = no thickness: a surface lies right behind the
point; larger = thicker, in scene units).

**Misses are capped**, never dropped: a ray that meets nothing within the max distance (an
open mesh, a hole, or a max distance shorter than the object) counts the cap C, the max
distance when it is finite, else the scene's bounding-box diagonal (no chord of the scene is
longer).  T is then the exact expectation of a bounded quantity, with an honest error bar;
on a closed mesh within the max distance nothing misses and the cap never enters.

The inward rays come from a key stream of their own (``samplers.inward_key``), so
thickness's errors are independent of AO's at the same point and of every other point's.
Their origins are offset *inward* by the point's ray offset and the distances measured from
there: behind a parallel surface a ray is short by offset / cos theta, on average 2 x the
offset (cosine weighting), far below any error bar (the tests allow it).  Closed forms (tested):
from any point of a sphere of radius r the chord at angle theta to -n is 2 r cos theta, so
T = 2 r E[cos theta] = 4 r / 3 (cosine) or r (uniform); a slab of thickness t with cap C:
T = t (2 - t / C) for C >= t (cosine).
"""

from __future__ import annotations

import numpy as np

from aobake import stats
from aobake.quantities import ao, obscurance
from aobake.quantities.base import Field, Quantity, Traced


def moments(traced: Traced) -> dict:
    total, m2 = stats.sums(traced.inward, traced.iid)
    return {"total": total, "m2": m2}  # (k, R) each


#: one point's pieces folded in order: the same running sums as obscurance's (the same bits)
extend = obscurance.extend


def finish(moments: dict, traced: Traced, m: int) -> dict:
    groups = moments["total"].shape[1]
    mean, se, _ = stats.spread_of_sums(moments["total"], moments["m2"], m, traced.iid)
    # Where every ray (replicate) agrees the spread says nothing: the resolution of n rays
    # over [0, C] instead, C / n (as AO's 1/n), never a zero that would claim exactness.
    stderr = np.where(se > 0, se, traced.cap / (groups * m))
    return {FIELDS[0].name: mean, FIELDS[1].name: stderr}


def no_information(normals: np.ndarray, cap: float = 1.0) -> dict:
    """The midpoint C/2 with error C/2: nothing is known of a point that cast no rays."""
    k = len(normals)
    return {FIELDS[0].name: np.full(k, 0.5 * cap), FIELDS[1].name: np.full(k, 0.5 * cap)}


FIELDS = (Field("thickness", 1, np.float32, ("thickness",), "_THICKNESS", ("thickness",),
                "mean distance through the inside to the back side (scene units; misses "
                "count the cap)"),
          Field("thickness_stderr", 1, np.float32, ("thickness_stderr",),
                "_THICKNESS_STDERR", ("thickness_stderr",),
                "one standard error of thickness"))

QUANTITY = Quantity(
    name="thickness",
    value=FIELDS[0],
    error=FIELDS[1],
    moments=moments,
    extend=extend,
    finish=finish,
    no_information=no_information,
    conventions={
        "cosine": {"thickness": "(1/pi) int min(L, C) |cos| dw over the inward hemisphere "
                                "(about -n): the cosine-weighted mean distance to the first "
                                "surface behind the point (scene units); a miss counts the "
                                "cap C (the max distance, else the scene's diagonal)"},
        "uniform": {"thickness": "(1/2pi) int min(L, C) dw over the inward hemisphere (about "
                                 "-n) (scene units); a miss counts the cap C (the max "
                                 "distance, else the scene's diagonal)"},
    },
    needs_inward=True,
    bounds=(0.0, float("inf")),
    summary=ao.summary,
)
