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
import math
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from aobake import _native
from aobake.constants import RAY_FAR
from aobake.outputs.npz import read_npz
from aobake.outputs.table import Unreadable, parse_json
from aobake.settings import BakeConfig, parse_distance
from aobake.errors import InputError
from aobake.outputs.npz import RAY_MISS, decode_ray_distances
from aobake.quantities import QUANTITIES, Traced
from aobake.records import BakeResult
from aobake.samplers import sample_set

log = logging.getLogger(__name__)

#: quantities a refit can recompute from distances alone
REFITTABLE = ("ao", "obscurance")
#: points refitted at once (memory: their rays' distances, a few arrays of them)
_BLOCK_RAYS = 1 << 22


def load(path) -> BakeResult:
    """A vertex bake from an NPZ written with ``--keep-distances`` (positions, fields,
    kept distances and its report as far as the metadata holds it).  The archive is read
    with its sizes bounded by its bytes; what it holds is checked by ``refit`` (``_check``)
    before anything is computed.  Raises InputError naming the file."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, not an .npz file")
    try:
        arrays = read_npz(path)
    except Unreadable as exc:
        raise InputError(f"{path}: not a readable NPZ archive ({exc})") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read it ({(exc.strerror or str(exc)).lower()})"
                         ) from None
    if "ray_distances" not in arrays or "ray_point" not in arrays:
        raise InputError(f"{path}: no kept ray distances: bake it with --keep-distances")
    missing = [name for name in ("positions", "faces", "normals", "rays", "metadata")
               if name not in arrays]
    if missing:
        raise InputError(f"{path}: no {', '.join(missing)} array{'s' * (len(missing) > 1)}: not "
                         "a vertex bake written by aobake")
    text = arrays["metadata"]
    if text.shape != () or text.dtype.kind != "U":
        raise InputError(f"{path}: its metadata is a {text.dtype} array of shape {text.shape}, "
                         "not JSON text")
    try:
        meta = parse_json(str(text[()]), "its metadata")
    except Unreadable as exc:
        raise InputError(f"{path}: {exc}") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("config"), dict) \
            or not isinstance(meta.get("parameters"), dict):
        raise InputError(f"{path}: its metadata has no bake configuration (config and "
                         "parameters objects)")
    # float64 as BakeResult holds them (other kinds are refused by _check)
    values = {name: arrays[name].astype(np.float64) if arrays[name].dtype.kind in "iuf"
              else arrays[name] for name in arrays if name in _field_names()}
    report = {"config": meta["config"], "parameters": meta["parameters"],
              "conventions": meta.get("conventions", {}), "versions": meta.get("versions", {})}
    return BakeResult(arrays["positions"], arrays["faces"], arrays["normals"], arrays["rays"],
                      values, report,
                      kept={"ray_distances": arrays["ray_distances"],
                            "ray_point": arrays["ray_point"]})


def _field_names() -> set:
    return {f.name for q in QUANTITIES.values() for f in q.fields}


def refit(bake, *, tau=None, max_distance=None, quantities=None, source: str = "<memory>"
          ) -> BakeResult:
    """AO and obscurance of ``bake`` (a BakeResult with ``kept`` distances, or the path of an
    NPZ written with ``--keep-distances``) at a new ``tau`` and/or ``max_distance`` (at most
    the baked one), without tracing.

    quantities : which of ao/obscurance to compute, a name or a list of names (default:
    those baked, plus obscurance when tau is given).  Returns a BakeResult whose arrays equal a fresh bake's of the same
    seed and parameters, kept distances included: those of hits below the new max distance,
    the rest misses, as that bake keeps them (so it can be refitted again, at a max distance
    up to its own).
    Everything read from ``bake`` is checked against its own metadata first (``_check``):
    a malformed or hand-edited file is an InputError naming it, never a wrong answer.
    """
    start = time.perf_counter()
    if not isinstance(bake, BakeResult):
        if not isinstance(bake, (str, os.PathLike)):
            raise InputError(f"refit: bake must be a BakeResult made with keep_distances=True "
                             f"or the path of its .npz, got {type(bake).__name__}")
        source = str(bake)
        bake = load(bake)
    if not bake.kept:
        raise InputError(f"{source}: no kept ray distances: bake it with keep_distances=True")
    wanted = _quantities(quantities, source)
    old, params, (diagonal, scale, baked), rows, point, samples = _check(bake, source)
    if wanted is None:
        wanted = [q for q in old.quantities if q in REFITTABLE]
        if tau is not None and "obscurance" not in wanted:
            wanted.append("obscurance")
    if not wanted:
        raise InputError(f"{source}: nothing to refit (ask for ao or obscurance)")
    changes = {"quantities": tuple(wanted)}
    if tau is not None:
        changes["tau"] = tau
    if max_distance is not None:
        changes["max_distance"] = parse_distance(max_distance)
    new = replace(old, **changes)
    distance = new.resolve_max_distance(diagonal)
    if distance > baked:
        raise InputError(f"{source}: max distance {distance:g} is beyond the baked "
                         f"{baked:g}: rays were only searched that far")
    tau_local = new.resolve_tau(diagonal) / scale

    groups, m = samples.groups, samples.m
    traced_rows = np.zeros(len(rows), dtype=bool)
    traced_rows[point[bake.rays > 0]] = True
    qs = [QUANTITIES[q] for q in new.quantities]
    normals = np.zeros((len(rows), 3))
    normals[point] = bake.normals
    out = {}
    for q in qs:
        out.update(q.no_information(normals))
    tfar = np.minimum(np.float32(min(distance * scale, 3.0e38)), np.float32(RAY_FAR))
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
    # The kept distances a fresh bake at this max distance would keep: its hits are the ones
    # below it, the rest misses.  So the result is that bake's, kept distances too, and can
    # be refitted again (a hit beyond its own max distance is refused there: ``_check``).
    rows = np.where(rows < tfar, rows, np.float32(np.inf))
    report = json.loads(json.dumps(bake.report, default=str))
    report["config"] = new.to_dict()
    report["parameters"] = dict(params, max_distance=distance, tau=new.resolve_tau(diagonal))
    report["refit"] = {"from": source, "baked_max_distance": baked,
                       "seconds": time.perf_counter() - start}
    log.info("refit %s: %s at max distance %g, tau %g", source, ", ".join(new.quantities),
             distance, new.resolve_tau(diagonal))
    kept = {"ray_distances": rows, "ray_point": point.astype(np.int32)}
    return BakeResult(bake.positions, bake.faces, bake.normals,
                      np.asarray(bake.rays).astype(np.int32), fields, report, kept=kept)


def _quantities(quantities, source: str) -> list | None:
    """``refit``'s ``quantities`` checked: None, or a name or a list of names of
    ``REFITTABLE`` quantities; InputError for anything else (a str is one name, not its
    letters; a quantity refit cannot compute is named as such, an unknown name too)."""
    if quantities is None:
        return None
    if isinstance(quantities, str):
        quantities = [quantities]
    elif not isinstance(quantities, (list, tuple)) or \
            not all(isinstance(q, str) for q in quantities):
        raise InputError(f"refit: quantities must be a name or a list of names from "
                         f"{list(REFITTABLE)}, got {quantities!r}")
    wanted = list(dict.fromkeys(quantities))
    unknown = [q for q in wanted if q not in QUANTITIES]
    if unknown:
        raise InputError(f"refit: unknown quantit{'ies' if len(unknown) > 1 else 'y'} "
                         f"{', '.join(map(repr, unknown))}; refit computes "
                         f"{' and '.join(REFITTABLE)}")
    bad = [q for q in wanted if q not in REFITTABLE]
    if bad:
        raise InputError(f"{source}: refit computes {' and '.join(REFITTABLE)} from the kept "
                         f"distances; {', '.join(bad)} need{'s' if len(bad) == 1 else ''} the "
                         "ray directions, which are not kept: bake again")
    return wanted


def _check(bake: BakeResult, source: str):
    """Everything refit reads from ``bake``, checked against its metadata before anything
    is computed: (config, parameters, (diagonal, trace_scale, baked max distance), ray
    distances (p, R m) float32 with inf for a miss, ray_point (n,) int64, the sample set).
    Raises InputError('SOURCE: problem')."""
    def refuse(text):
        raise InputError(f"{source}: {text}")

    report = bake.report if isinstance(bake.report, dict) else {}
    config, params = report.get("config"), report.get("parameters")
    if not isinstance(config, dict) or not isinstance(params, dict):
        refuse("its metadata has no bake configuration (config and parameters objects)")
    try:
        old = BakeConfig.from_dict(config)
    except (InputError, TypeError, ValueError) as exc:
        refuse(f"its metadata's config is not a bake configuration: {exc}")
    numbers = []
    for key, lowest in (("diagonal", "positive"), ("trace_scale", "positive"),
                        ("max_distance", "non-negative")):
        value = params.get(key)
        try:  # strict JSON writes inf as the string "inf"
            number = float(value) if isinstance(value, (int, float, str)) and \
                not isinstance(value, bool) else math.nan
        except ValueError:
            number = math.nan
        finite_needed = key != "max_distance"  # an unlimited search is inf
        if math.isnan(number) or (finite_needed and not math.isfinite(number)) \
                or number < 0 or (lowest == "positive" and number == 0):
            refuse(f"its metadata's parameters.{key} is {value!r}: it must be a "
                   f"{'finite ' if finite_needed else ''}{lowest} number")
        numbers.append(number)
    diagonal, scale, baked = numbers
    try:
        samples = sample_set(old.sampler, old.rays, old.replicates)
    except ValueError as exc:
        refuse(f"its metadata's config: {exc}")

    positions = np.asarray(bake.positions)
    per_vertex = {"positions": positions, "normals": np.asarray(bake.normals),
                  "rays": np.asarray(bake.rays),
                  "ray_point": np.asarray(bake.kept.get("ray_point")),
                  **{name: np.asarray(value) for name, value in bake.values.items()}}
    lengths = {name: len(a) if a.ndim else 0 for name, a in per_vertex.items()}
    if len(set(lengths.values())) > 1:
        common = max(set(lengths.values()), key=list(lengths.values()).count)
        odd = ", ".join(f"{name} {length}" for name, length in lengths.items() if length != common)
        refuse(f"its per-vertex arrays differ in length: {odd}, the others {common}")
    n = lengths["positions"]
    for label, array in (("positions", positions), ("normals", np.asarray(bake.normals))):
        if array.dtype.kind not in "iuf" or array.shape != (n, 3):
            refuse(f"{label} must be ({n}, 3) numbers, got {array.shape} of {array.dtype}")
        if not np.isfinite(array).all():
            refuse(f"{int(np.count_nonzero(~np.isfinite(array).all(axis=1)))} of its {n} "
                   f"{label} are not finite")
    faces = np.asarray(bake.faces if bake.faces is not None else np.zeros((0, 3), np.int64))
    if faces.size and (faces.dtype.kind not in "iu" or faces.ndim != 2 or faces.shape[1] != 3
                       or faces.min() < 0 or faces.max() >= n):
        refuse(f"faces must be (f, 3) indices of its {n} vertices")
    rays = np.asarray(bake.rays)
    cast = samples.groups * samples.m
    if rays.dtype.kind not in "iu" or rays.shape != (n,):
        refuse(f"rays must be ({n},) integers, got {rays.shape} of {rays.dtype}")
    if np.any((rays != 0) & (rays != cast)):
        refuse(f"rays per vertex must be 0 or the {cast} its configuration casts "
               f"({old.rays} rays, {old.replicates} replicates, {old.sampler})")
    for name, value in bake.values.items():
        value = np.asarray(value)
        if value.dtype.kind not in "iuf" or len(value) != n or not np.isfinite(value).all():
            refuse(f"{name} must be {n} finite numbers per vertex")

    stored = np.asarray(bake.kept.get("ray_distances"))
    point = np.asarray(bake.kept.get("ray_point"))
    if stored.dtype.kind != "f":
        refuse(f"ray_distances holds {stored.dtype} values: distances are floats "
               f"(float32, {RAY_MISS:g} for a miss)")
    if stored.ndim != 2 or stored.shape[1] != cast:
        refuse(f"kept distances of shape {stored.shape} do not match {samples.groups} x "
               f"{samples.m} rays per point")
    if point.dtype.kind not in "iu" or point.shape != (n,):
        refuse(f"ray_point must be ({n},) integers, got {point.shape} of {point.dtype}")
    point = point.astype(np.int64)
    if n and (point.min() < 0 or point.max() >= len(stored)):
        refuse(f"ray_point indexes rows {point.min()}..{point.max()} of ray_distances, which "
               f"has {len(stored)}")
    rows = decode_ray_distances(stored)
    bad = np.isnan(rows) | (rows < 0)
    if bad.any():
        refuse(f"{int(np.count_nonzero(bad))} kept distances are NaN or negative (a hit's "
               f"distance is >= 0; a miss is stored as {RAY_MISS:g})")
    # a hit was found below the baked search distance (float32, as the tracer's tfar)
    reach = np.minimum(np.float32(min(baked * scale, 3.0e38)), np.float32(RAY_FAR))
    beyond = np.isfinite(rows) & (rows > reach * np.float32(1 + 2 ** -20))
    if beyond.any():
        refuse(f"{int(np.count_nonzero(beyond))} kept distances are beyond the baked max "
               f"distance ({baked:g} scene units = {float(reach):g} local units)")
    return old, params, (diagonal, scale, baked), rows, point, samples


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
