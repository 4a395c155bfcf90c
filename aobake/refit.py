"""``aobake refit``: one bake, many falloffs.

A bake made with ``keep_distances`` (``--keep-distances``) keeps every ray's nearest-hit
distance.  From them AO at any max distance up to the baked one, and obscurance at any tau,
follow without tracing: a ray of the fresh bake with max distance D' is a hit exactly when
the kept distance is below D' (the same nearest hit: Embree's triangle test does not depend
on the search distance), and its obscurance weight is rho of that distance.  The rays
themselves (directions, offsets) are a pure function of the seed and the point ids, so the
refit equals a fresh bake of the same seed with the new parameters, bit for bit
(``tests/test_refit.py``).  The one exception has measure zero: a hit whose float32
distance equals the new max distance exactly.

Bent normals need the ray directions, which are not kept: refit gives ao and obscurance.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from aobake import _native
from aobake.backends.embree import _FAR
from aobake.config import BakeConfig, parse_distance
from aobake.errors import InputError
from aobake.quantities import QUANTITIES, Traced
from aobake.results import BakeResult
from aobake.samplers import sample_set

log = logging.getLogger(__name__)

#: quantities a refit can recompute from distances alone
REFITTABLE = ("ao", "obscurance")
#: points refitted at once (memory: their rays' distances, a few arrays of them)
_BLOCK_RAYS = 1 << 22


def load(path) -> BakeResult:
    """A vertex bake from an NPZ written with ``--keep-distances`` (positions, fields,
    kept distances and its report as far as the metadata holds it)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable NPZ archive ({exc})") from None
    if "ray_distances" not in arrays or "ray_point" not in arrays:
        raise InputError(f"{path}: no kept ray distances: bake it with --keep-distances")
    try:
        meta = json.loads(str(arrays["metadata"]))
        config, parameters = meta["config"], meta["parameters"]
    except (KeyError, ValueError):
        raise InputError(f"{path}: its metadata has no bake configuration") from None
    values = {name: arrays[name].astype(np.float64)
              for name in arrays if name in _field_names()}
    report = {"config": config, "parameters": parameters,
              "conventions": meta.get("conventions", {}), "versions": meta.get("versions", {})}
    return BakeResult(arrays["positions"], arrays["faces"], arrays["normals"],
                      arrays["rays"].astype(np.int32), values, report,
                      kept={"ray_distances": arrays["ray_distances"],
                            "ray_point": arrays["ray_point"]})


def _field_names() -> set:
    return {f.name for q in QUANTITIES.values() for f in q.fields}


def refit(bake, *, tau=None, max_distance=None, quantities=None, source: str = "<memory>"
          ) -> BakeResult:
    """AO and obscurance of ``bake`` (a BakeResult with ``kept`` distances, or the path of an
    NPZ written with ``--keep-distances``) at a new ``tau`` and/or ``max_distance`` (at most
    the baked one), without tracing.

    quantities : which of ao/obscurance to compute (default: those baked, plus obscurance
    when tau is given).  Returns a BakeResult whose arrays equal a fresh bake's of the same
    seed and parameters, with the kept distances carried over (so it can be refitted again).
    """
    start = time.perf_counter()
    if not isinstance(bake, BakeResult):
        source = str(bake)
        bake = load(bake)
    if not bake.kept:
        raise InputError(f"{source}: no kept ray distances: bake it with keep_distances=True")
    old = BakeConfig.from_dict(bake.report["config"])
    params = bake.report["parameters"]
    if quantities is None:
        quantities = [q for q in old.quantities if q in REFITTABLE]
        if tau is not None and "obscurance" not in quantities:
            quantities.append("obscurance")
    wanted = [q for q in quantities]
    bad = sorted(set(wanted) - set(REFITTABLE))
    if bad:
        raise InputError(f"{source}: refit computes {list(REFITTABLE)} from distances; "
                         f"{bad} need(s) the ray directions: bake again")
    if not wanted:
        raise InputError(f"{source}: nothing to refit (ask for ao or obscurance)")
    changes = {"quantities": tuple(wanted)}
    if tau is not None:
        changes["tau"] = tau
    if max_distance is not None:
        changes["max_distance"] = parse_distance(max_distance)
    new = replace(old, **changes)
    diagonal, scale = float(params["diagonal"]), float(params["trace_scale"])
    baked = float(params["max_distance"])
    distance = new.resolve_max_distance(diagonal)
    if distance > baked:
        raise InputError(f"{source}: max distance {distance:g} is beyond the baked "
                         f"{baked:g}: rays were only searched that far")
    tau_local = new.resolve_tau(diagonal) / scale

    rows = bake.kept["ray_distances"]
    point = np.asarray(bake.kept["ray_point"], dtype=np.int64)
    samples = sample_set(old.sampler, old.rays, old.replicates)
    groups, m = samples.groups, samples.m
    if rows.shape != (rows.shape[0], groups * m) or len(point) != len(bake.positions):
        raise InputError(f"{source}: kept distances of shape {rows.shape} do not match "
                         f"{groups} x {m} rays per point")
    traced_rows = np.zeros(len(rows), dtype=bool)
    traced_rows[point[bake.rays > 0]] = True
    qs = [QUANTITIES[q] for q in new.quantities]
    normals = np.zeros((len(rows), 3))
    normals[point] = bake.normals
    out = {}
    for q in qs:
        out.update(q.no_information(normals))
    tfar = np.minimum(np.float32(min(distance * scale, 3.0e38)), _FAR)
    kernels = _native.kernels()
    index = np.flatnonzero(traced_rows)
    block = max(1, _BLOCK_RAYS // (groups * m))
    for start_row in range(0, len(index), block):
        sel = index[start_row:start_row + block]
        d = rows[sel].reshape(len(sel), groups, m)
        # The fresh bake's distance query: a hit only below the (new) search distance.
        d = np.where(d < tfar, d, np.float32(np.inf))
        values = _estimate(qs, d, normals[sel], samples, tau_local, kernels, new, distance)
        for name, array in values.items():
            out[name][sel] = array
    fields = {name: array[point] for name, array in out.items()}
    report = json.loads(json.dumps(bake.report, default=str))
    report["config"] = new.to_dict()
    report["parameters"] = dict(params, max_distance=distance, tau=new.resolve_tau(diagonal))
    report["refit"] = {"from": source, "baked_max_distance": baked,
                       "seconds": time.perf_counter() - start}
    log.info("refit %s: %s at max distance %g, tau %g", source, ", ".join(new.quantities),
             distance, new.resolve_tau(diagonal))
    return BakeResult(bake.positions, bake.faces, bake.normals, bake.rays, fields, report,
                      kept=bake.kept)


def _estimate(qs, distance, normals, samples, tau_local, kernels, config, max_distance):
    """Fields of k points from their (k, R, m) float32 distances, folded as the tracer does
    (whole, or in pieces for a streamed point) so the sums are the same."""
    occluded = np.isfinite(distance)
    k, groups, m = distance.shape

    def traced(j0, count):
        return Traced(None, np.ascontiguousarray(occluded[:, :, j0:j0 + count]),
                      np.ascontiguousarray(distance[:, :, j0:j0 + count]), normals, samples.iid,
                      tau_local, kernels, config.confidence, max_distance)

    if samples.piece >= m:
        whole = traced(0, m)
        out = {}
        for q in qs:
            out.update(q.estimate(whole))
        return out
    piece = samples.piece
    out = {}
    for q in qs:
        moments, done = None, 0
        for j0 in range(0, m, piece):
            count = min(piece, m - j0)
            # The tracer streams one point per piece; moments are per point and replicate,
            # so k points at once give the same numbers.
            new = q.moments(traced(j0, count))
            moments = new if moments is None else q.extend(moments, new, done, count)
            done += count
        out.update(q.finish(moments, traced(0, 1), m))
    return out


__all__ = ["REFITTABLE", "load", "refit"]
