"""The bake report: configuration to reproduce it, parameters actually used, statistics."""

from __future__ import annotations

import functools
import threading

import numpy as np

from aobake import _native
from aobake.quantities import conventions


def versions() -> dict:
    """Versions of aobake and the libraries whose behaviour decides the numbers."""
    lookup = _prefetch
    if lookup is not None:
        lookup.join()
    return dict(_versions())


_prefetch: threading.Thread | None = None


def prefetch_versions() -> None:
    """Start looking the versions up on a thread of its own: importing importlib.metadata
    and reading six packages' metadata takes ~0.1 s, which a bake hides behind loading,
    unwrapping and tracing (its threads wait in C with the GIL released)."""
    global _prefetch
    if _prefetch is None:
        _prefetch = threading.Thread(target=_versions, name="aobake-versions", daemon=True)
        _prefetch.start()


@functools.lru_cache(maxsize=1)
def _versions() -> dict:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in ("aobake", "embreex", "trimesh", "numpy", "xatlas", "OpenImageIO"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "unknown"
    return out


def error_summary(quantities, values: dict, rays: np.ndarray) -> dict:
    """Each quantity's summary (mean, mean and 95th-percentile error) over sampled points."""
    # a block of points at a time: no (n,) mask where every point was sampled (the usual)
    block = 1 << 16
    counts = [int(np.count_nonzero(rays[s:s + block])) for s in range(0, len(rays), block)]
    if not sum(counts):
        return {}
    if sum(counts) == len(rays):  # the arrays themselves (the same values, order), no copies
        sampled = slice(None)
    else:
        sampled = rays > 0
    return {q.name: q.summary(values[q.value.name][sampled], values[q.error.name][sampled])
            for q in quantities}


def build(target: str, scene, config, record: dict, method, done, *, wall: float, threads: int,
          chunk_rays: int, warnings: list, kernels: dict, executor: dict) -> dict:
    """The report dict of one bake, from the method's record (``method.record(estimates)``:
    its ``parameters``) and the target's (``done``: a ``records.Finished``);
    ``kernels``: stage -> compiled? (``_native.used``)."""
    parameters = dict(record["parameters"])
    parameters["kernels"] = _native.used(kernels)
    rays = done.rays
    if done.rays_key != "rays_per_point" and "rays_per_point" in parameters:
        parameters[done.rays_key] = parameters.pop("rays_per_point")  # what a "point" is here
    report = {
        "aobake_report": 1,
        "target": target,
        "config": config.record(method.name, target),
        "conventions": conventions(config.weighting),
        "scene": scene.stats(),
        "parameters": parameters,
        "points": int(done.points),
    }
    if method.casts_rays:
        cast = int(np.sum(rays, dtype=np.int64)) if done.cast is None else int(done.cast)
        report.update({
            "points_sampled": int(np.count_nonzero(rays)),
            "rays_cast": cast,
            "wall_time_s": wall,
            "rays_per_second": cast / wall if wall > 0 else None,
        })
    else:
        report["wall_time_s"] = wall
    report.update({
        "threads": threads,
        "chunk_rays": int(chunk_rays),
        "executor": executor,
        "error": error_summary(method.error_quantities(), done.values, rays)
        if method.casts_rays else {},
        "warnings": list(scene.warnings) + list(warnings),
        "versions": versions(),
    })
    return report
