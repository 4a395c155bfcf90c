"""The default executor, ``threads``: one process, the method's own thread pool.  (The
``processes`` one is in ``aobake.executors.processes``: its multiprocessing machinery is
imported only when it is asked for.)"""

from __future__ import annotations

import os

from aobake.executors.base import items, merged, release


class ThreadsExecutor:
    """Today's behaviour: the method runs in this process on ``threads`` threads."""

    name = "threads"

    def __init__(self, workers: int | None = None, chunk_points: int | None = None):
        self.workers, self.chunk_points = workers, chunk_points

    def estimate(self, job, method, plan, threads: int, chunk_rays: int, progress=None):
        """Estimates of every point of ``plan`` (``SamplePoints``) by ``method``."""
        try:
            if not self.chunk_points or not len(plan.points):  # (no points: nothing to cut)
                return method.estimate(plan, threads, chunk_rays, progress)
            # An explicit split runs item by item here too (the same bits: tested), each
            # item's rows landing in the result as it ends (nothing held per item after it)
            result, done = merged(method, plan), 0
            for item in items(job, plan, self.chunk_points):
                result.add(item.start, item.stop,
                           method.estimate(item.sample_points(), threads, chunk_rays))
                done += item.stop - item.start
                if progress:
                    progress(done, len(plan.points))
            return result.result()
        finally:
            release(method)


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)
