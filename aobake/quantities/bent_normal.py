"""Bent normal: the normalised mean of the unoccluded sample directions.

A unit vector (the surface normal when no ray escapes); its error is an angle in
radians, one standard error raised for the few degrees of freedom it is measured on, so that
the cone of z(C) of it around the bent normal (1.96 at --confidence 0.95) holds the true one
with probability >= C (:func:`finish`).
"""

from __future__ import annotations

import numpy as np

from aobake import stats
from aobake.quantities.base import Field, Quantity, Traced
from aobake.vectors import normalize

#: Angular standard error (radians) reported when there is nothing to measure it
#: from (no escaping ray, a single ray or replicate, no rays): the bent normal is
#: then only known to lie in the hemisphere, up to pi/2 from the normal.
NO_INFORMATION_ANGLE = np.pi / 2


def moments(traced: Traced) -> dict:
    """Per replicate: total (k, R, 3) sum of f = d [ray escapes], escapes (k, R) count, and
    (i.i.d. only) scatter (k, R, 3, 3) sum of (f - mean)(f - mean)^T."""
    directions, occluded = traced.directions, traced.occluded
    m = directions.shape[2]
    f = (directions * ~occluded[..., None]).astype(np.float64)  # (k, R, m, 3)
    total = f.sum(axis=2)
    out = {"total": total,
           "escapes": (m - np.count_nonzero(occluded, axis=2)).astype(np.float64)}
    if traced.iid:
        dev = f - (total / m)[:, :, None, :]
        out["scatter"] = np.einsum("krmi,krmj->krij", dev, dev)
    return out


def extend(a: dict, b: dict, na: int, nb: int) -> dict:
    out = {"total": a["total"] + b["total"], "escapes": a["escapes"] + b["escapes"]}
    if "scatter" in a:  # Chan et al.'s pairwise update of the scatter matrix
        delta = b["total"] / nb - a["total"] / na
        out["scatter"] = a["scatter"] + b["scatter"] \
            + np.einsum("kri,krj->krij", delta, delta) * (na * nb / (na + nb))
    return out


def finish(moments: dict, traced: Traced, m: int) -> dict:
    """Bent normal and its angular standard error for k points, from m samples per replicate.

    Returns {bent_normal: (k, 3) float64 unit, bent_normal_stderr: (k,) float64 radians}.

    The bent normal is b / |b| with b the sum of f = d [ray escapes] over all rays, a sum of
    independent *units*: the rays (i.i.d., ``random``) or the R replicates' sums (QMC).  Its
    error is the delta method for normalising: the component of b's error perpendicular to
    b, over |b| (the expected squared angle to the true bent normal).  Only the u units with
    an escaping ray say anything about the direction: the others add 0 to b and nothing
    perpendicular to it.  So the variance is measured among those u, conditionally on which
    escaped: with x_j the component of unit j's sum perpendicular to b (they sum to 0),

        se^2 = u / (u - 1) sum_j |x_j|^2 / |b|^2,    on u - 1 degrees of freedom

    (counting every ray or replicate instead, as before, made se too small by
    sqrt((u - 1) n / (u (n - 1))) where few escape: 0.71 with two escaping rays).

    The reported stderr is se t_{u-1}(C) / z(C) (:func:`aobake.stats.normal_equivalent`,
    C = ``traced.confidence``): the bent normal has no interval field, so its one number
    carries the degrees of freedom, and the cone of z(C) stderr (1.96 at C = 0.95) holds the
    true bent normal with probability >= C.  The angle's error is 2-D; its squared length
    over se^2 is an F ratio between F(1, u - 1) (all of it along one axis: exactly t^2, the
    worst case) and F(2, 2 (u - 1)) (isotropic), so the t quantile is the bound that holds for
    every error shape.  With the default 4 replicates the raise is 1.62 (t_3 / z at 0.95);
    the rms of angle / stderr is then 0.75 (isotropic) to 1.07 (one-dimensional), and ~1
    for ``random`` with many escaping rays.  Measured coverage: docs/conventions.md.

    Capped at pi/2 (NO_INFORMATION_ANGLE), which is also the value when fewer than two units
    have an escaping ray (then the spread says nothing about the error, which can be 90
    degrees).
    """
    total, escapes, normals = moments["total"], moments["escapes"], traced.normals
    b = total.sum(axis=1)  # (k, 3)
    unit, length = normalize(b)
    length = length[:, 0]
    ok = length > 0
    bent = np.where(ok[:, None], unit, normals)
    # u and sum_j |x_j|^2 (a unit without an escape has x_j = 0)
    if traced.iid:  # units = rays (R = 1)
        units = escapes.sum(axis=1)
        # the scatter about the mean ray: its part perpendicular to b is the rays' own
        scatter = moments["scatter"].sum(axis=1)  # (k, 3, 3)
        perp2 = np.trace(scatter, axis1=1, axis2=2) \
            - np.einsum("ki,kij,kj->k", unit, scatter, unit)
    else:  # units = replicates
        units = np.count_nonzero(escapes > 0, axis=1).astype(np.float64)
        # projected before squaring: |T|^2 - (T.u)^2 would cancel where T is nearly along u
        along = np.einsum("kjc,kc->kj", total, unit)
        perp2 = np.square(total - along[..., None] * unit[:, None, :]).sum(axis=(1, 2))
    known = ok & (units >= 2)
    dof = np.where(known, units - 1.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        se = np.sqrt(np.maximum(perp2, 0.0) * units / dof) / length
        angle = stats.normal_equivalent(np.where(known, se, 0.0), dof, traced.confidence)
    stderr = np.where(known, np.minimum(angle, NO_INFORMATION_ANGLE), NO_INFORMATION_ANGLE)
    return {"bent_normal": bent, "bent_normal_stderr": stderr}


def no_information(normals: np.ndarray) -> dict:
    """The surface normal, up to pi/2 off."""
    return {"bent_normal": normals.copy(),
            "bent_normal_stderr": np.full(len(normals), NO_INFORMATION_ANGLE)}


def summary(value: np.ndarray, error: np.ndarray) -> dict:
    return {"stderr_mean_rad": float(error.mean()), "stderr_p95_rad": float(np.percentile(error, 95))}


#: what bent_normal_stderr means, in every output's metadata
STDERR_CONVENTION = ("angular standard error of the bent normal in radians (delta method, "
                     "measured on u - 1 degrees of freedom: u the escaping rays (random) or "
                     "replicates with an escaping ray) times t_{u-1}(C) / z(C), C the "
                     "confidence: the cone of z(C) stderr around the bent normal (1.96 at "
                     "0.95) holds the true one with probability >= C; pi/2 when fewer than "
                     "two rays or replicates have an escaping ray")


QUANTITY = Quantity(
    name="bent_normal",
    value=Field("bent_normal", 3, np.float32, ("bent_normal_x", "bent_normal_y", "bent_normal_z"),
                "_BENT_NORMAL", ("bent_normal.X", "bent_normal.Y", "bent_normal.Z"),
                "mean unoccluded direction (unit)"),
    error=Field("bent_normal_stderr", 1, np.float32, ("bent_normal_stderr",), "_BENT_NORMAL_STDERR",
                ("bent_normal_stderr",), "angular standard error of bent_normal (radians; "
                "1.96 of it is a 95% cone at --confidence 0.95)"),
    moments=moments,
    extend=extend,
    finish=finish,
    no_information=no_information,
    conventions={
        "cosine": {
            "bent_normal": "normalised mean of the unoccluded sample directions; the surface "
                           "normal if none",
            "bent_normal_stderr": STDERR_CONVENTION},
        "uniform": {
            "bent_normal": "normalised uniform-measure mean of the unoccluded directions; the "
                           "surface normal if none",
            "bent_normal_stderr": STDERR_CONVENTION},
    },
    texel="direction",
    summary=summary,
)
