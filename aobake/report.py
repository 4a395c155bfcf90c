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
    sampled = rays > 0
    if not sampled.any():
        return {}
    return {q.name: q.summary(values[q.value.name][sampled], values[q.error.name][sampled])
            for q in quantities}


def build(target: str, scene, tracer, config, *, points: int, rays: np.ndarray, values: dict,
          wall: float, threads: int, chunk_rays: int, warnings: list, kernels: dict,
          cast: int | None = None) -> dict:
    """The report dict of one bake.  ``cast``: rays actually traced when points shared
    samples (default: the sum of ``rays``); ``kernels``: stage -> compiled? (``_native.used``)."""
    cast = int(rays.astype(np.int64).sum()) if cast is None else int(cast)
    parameters = tracer.parameters()
    parameters["kernels"] = _native.used(kernels)
    return {
        "aobake_report": 1,
        "target": target,
        "config": config.to_dict(),
        "conventions": conventions(config.weighting),
        "scene": scene.stats(),
        "parameters": parameters,
        "points": int(points),
        "points_sampled": int(np.count_nonzero(rays)),
        "rays_cast": cast,
        "wall_time_s": wall,
        "rays_per_second": cast / wall if wall > 0 else None,
        "threads": threads,
        "chunk_rays": int(chunk_rays),
        "error": error_summary(tracer.quantities, values, rays),
        "warnings": list(scene.warnings) + list(warnings),
        "versions": versions(),
    }
