"""The ``processes`` executor: a pool of worker processes, each single-threaded, over work
items of point ranges."""

from __future__ import annotations

import logging
import multiprocessing
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

import numpy as np

from aobake.records import merge
from aobake.executors import worker
from aobake.executors.base import items

log = logging.getLogger(__name__)

#: work items per worker when the split is not given: enough that a slow item does not
#: leave the other workers idle at the end, few enough that each carries real tracing
ITEMS_PER_WORKER = 4


class ProcessesExecutor:
    """A local pool of ``workers`` processes (default: one per thread asked for), each
    tracing single-threaded; the scene is sent to each worker once (the pool's
    initializer), which builds its occluders and method once and keeps them for all its
    items.  Work items are ``chunk_points`` points (default: the points split into
    ITEMS_PER_WORKER items per worker)."""

    name = "processes"

    def __init__(self, workers: int | None = None, chunk_points: int | None = None):
        self.workers, self.chunk_points = workers, chunk_points

    def estimate(self, job, method, plan, threads: int, chunk_rays: int, progress=None):
        n = len(plan.points)
        workers = max(1, self.workers or threads)
        per_item = self.chunk_points or max(1, -(-n // (workers * ITEMS_PER_WORKER)))
        work = items(job, plan, per_item)
        if not work:
            return method.estimate(plan, threads, chunk_rays, progress)
        # "spawn": a clean interpreter (no copy of this process's threads or Embree state);
        # the worker imports aobake by name, exactly the package this process runs, since
        # multiprocessing hands the child this process's sys.path.
        context = multiprocessing.get_context("spawn")
        parts, done = [], 0
        pool = ProcessPoolExecutor(max_workers=min(workers, len(work)), mp_context=context,
                                   initializer=worker.install, initargs=(job,))
        try:
            pending = {pool.submit(worker.run_item, item, 1, chunk_rays): item
                       for item in work}
            while pending:
                finished, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    pending.pop(future)
                    start, stop, part = future.result()
                    parts.append((np.arange(start, stop), part))
                    done += stop - start
                    if progress:
                        progress(done, n)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
        log.info("processes executor: %d items of <= %d points on %d workers", len(work),
                 per_item, min(workers, len(work)))
        return merge(parts, n)
