"""Bent normal: the normalised mean of the unoccluded sample directions.

A unit vector (the surface normal when no ray escapes); its error is an angle in
radians (:func:`estimate`).
"""

from __future__ import annotations

import numpy as np

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

    The bent normal is b / |b| with b the mean of f = d [ray escapes] over all rays.
    Its error is the delta method for normalising: the component of b's error
    perpendicular to b, over |b|: stderr^2 = tr(P Cov(b) P) / |b|^2 with
    P = I - b b^T / |b|^2 (the expected squared angle to the true bent normal).
    Cov(b) comes from the same source as the AO error: i.i.d. per-ray
    contributions (``random``) or the spread of the R replicate means.  Capped at
    pi/2, which is also the value when fewer than two rays (i.i.d.) or two replicates
    (QMC) have an escaping ray (then the spread says nothing about the error, which can
    be 90 degrees) or there is no spread.
    """
    total, escapes, normals = moments["total"], moments["escapes"], traced.normals
    k, groups = escapes.shape
    if traced.iid:
        count = groups * m
        b = total.sum(axis=1) / count  # (k, 3)
    else:
        per = total / m  # replicate means (k, R, 3)
        count = groups
        b = per.sum(axis=1) / count
    unit, length = normalize(b)
    length = length[:, 0]
    ok = length > 0
    bent = np.where(ok[:, None], unit, normals)
    stderr = np.full(k, NO_INFORMATION_ANGLE)
    if count >= 2:
        if traced.iid:  # sum over rays of |dev_perp|^2 = tr(S) - u^T S u
            scatter = moments["scatter"].sum(axis=1)  # (k, 3, 3); R = 1
            perp2 = np.trace(scatter, axis1=1, axis2=2) \
                - np.einsum("ki,kij,kj->k", unit, scatter, unit)
        else:
            dev = per - b[:, None, :]
            along = np.einsum("kjc,kc->kj", dev, unit)
            perp2 = (np.square(dev).sum(axis=2) - np.square(along)).sum(axis=1)
        var = np.maximum(perp2, 0.0) / (count * (count - 1))
        with np.errstate(divide="ignore", invalid="ignore"):
            angle = np.sqrt(var) / length
        # A spread needs two independent contributions with an escape: two rays (i.i.d.) or
        # two replicates (QMC: escapes inside one replicate tell nothing about its error).
        escaped = escapes.sum(axis=1) if traced.iid else np.count_nonzero(escapes > 0, axis=1)
        known = ok & (escaped >= 2)
        stderr = np.where(known, np.minimum(angle, NO_INFORMATION_ANGLE), NO_INFORMATION_ANGLE)
    return {"bent_normal": bent, "bent_normal_stderr": stderr}


def no_information(normals: np.ndarray) -> dict:
    """The surface normal, up to pi/2 off."""
    return {"bent_normal": normals.copy(),
            "bent_normal_stderr": np.full(len(normals), NO_INFORMATION_ANGLE)}


def summary(value: np.ndarray, error: np.ndarray) -> dict:
    return {"stderr_mean_rad": float(error.mean()), "stderr_p95_rad": float(np.percentile(error, 95))}


QUANTITY = Quantity(
    name="bent_normal",
    value=Field("bent_normal", 3, np.float32, ("bent_normal_x", "bent_normal_y", "bent_normal_z"),
                "_BENT_NORMAL", ("bent_normal.X", "bent_normal.Y", "bent_normal.Z"),
                "mean unoccluded direction (unit)"),
    error=Field("bent_normal_stderr", 1, np.float32, ("bent_normal_stderr",), "_BENT_NORMAL_STDERR",
                ("bent_normal_stderr",), "angular standard error of bent_normal (radians)"),
    moments=moments,
    extend=extend,
    finish=finish,
    no_information=no_information,
    conventions={
        "cosine": {
            "bent_normal": "normalised mean of the unoccluded sample directions; the surface "
                           "normal if none",
            "bent_normal_stderr": "angular standard error of the bent normal in radians (delta "
                                  "method); pi/2 when nothing escapes or there is no spread to "
                                  "measure"},
        "uniform": {
            "bent_normal": "normalised uniform-measure mean of the unoccluded directions; the "
                           "surface normal if none",
            "bent_normal_stderr": "angular standard error of the bent normal in radians (delta "
                                  "method); pi/2 when nothing escapes or there is no spread to "
                                  "measure"},
    },
    texel="direction",
    summary=summary,
)
