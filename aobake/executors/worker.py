"""What runs inside a worker process: the per-worker cache of prepared methods.

This module is importable on purpose: a process pool (and Dask, which ships functions
defined in ``__main__`` by value) must find :func:`run_item` and its cache by name, so
the occluders and the method a worker builds for a job are kept across that job's
items instead of being rebuilt for each.
"""

from __future__ import annotations

import contextlib

from aobake import _native
from aobake.records import Estimates

#: job key -> (Job, prepared method); a worker holds the jobs it was given
_CACHE: dict = {}

#: the most jobs a worker keeps: a long-lived worker (Dask) is sent one scene after another
#: (a batch's assets); the oldest is dropped when a new one arrives, so its memory holds at
#: most this many scenes and acceleration structures (the executor also forgets a job when
#: its bake ends: ``forget``)
KEEP_JOBS = 2


def install(job) -> None:
    """Pool initializer: remember ``job`` (its method is built on the first item)."""
    _CACHE[job.key] = (job, None)
    while len(_CACHE) > KEEP_JOBS:  # dicts keep insertion order: the oldest goes first
        _CACHE.pop(next(iter(_CACHE)))


def forget(key: str) -> bool:
    """Drop job ``key`` (its scene, occluders and method) from this worker's cache; True if
    it was there."""
    return _CACHE.pop(key, None) is not None


def prepared(job):
    """The method of ``job``, built once per worker: occluders, then the method on them."""
    from aobake import occluders as occluder_stage
    from aobake.methods import METHODS

    entry = _CACHE.get(job.key)
    if entry is None or entry[1] is None:
        with _kernels(job.compiled):
            built = occluder_stage.build(job.scene, job.config)
            method = METHODS[job.method].prepare(job.scene, job.config, built,
                                                 job.rays_per_point, compiled=job.compiled)
        _CACHE[job.key] = entry = (job, method)
    return entry[1]


def run_item(item, threads: int, chunk_rays: int, job=None) -> tuple[int, int, Estimates]:
    """Estimate one work item: (start, stop, Estimates of its points).  ``job`` is given
    when the worker may not have it yet (Dask); a pool's initializer installed it."""
    if job is not None and job.key not in _CACHE:
        install(job)
    job = _CACHE[item.key][0]
    method = prepared(job)
    with _kernels(job.compiled):
        return item.start, item.stop, method.estimate(item.sample_points(), threads,
                                                      chunk_rays)


@contextlib.contextmanager
def _kernels(compiled: bool):
    """The parent's choice of kernels, on this thread."""
    if compiled:
        yield
    else:
        with _native.numpy_only():
            yield
