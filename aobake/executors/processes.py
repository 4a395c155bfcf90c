"""The ``processes`` executor: a pool of worker processes, each single-threaded, over work
items of point ranges.

Interrupts: the pool starts and stops with SIGINT, SIGTERM and SIGHUP held
(``executors.signals``), so no worker reads half a job and no pool is left half-built; the
workers leave interrupts to this process (a terminal's Ctrl-C reaches them too), which
ends them with SIGTERM on an interrupt or a failed item (their unfinished items are not
wanted; a child a worker started ends itself: ``aobake.child.watch_parent``).
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import multiprocessing
import os
import pickle
import shutil
import signal
import tempfile
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from aobake.errors import AobakeError
from aobake.executors import signals, worker
from aobake.executors.base import items, merged, release

log = logging.getLogger(__name__)


class PoolError(AobakeError):
    """A worker process of the pool died (killed, out of memory, a crash in native code)."""


#: work items per worker when the split is not given: enough that a slow item does not
#: leave the other workers idle at the end, few enough that each carries real tracing
ITEMS_PER_WORKER = 4

#: the most points an item carries when the split is not given: a set of many instances is
#: cut into more items, not larger ones, so what the items in flight hold (their points
#: sent, their results back: ~150 bytes a point) does not grow with the bake (65,536 points
#: of 64 rays: ~1-2 s of one worker's tracing, against ~5 ms of pickling and round trip)
MAX_ITEM_POINTS = 1 << 16

#: items in flight per worker (submitted, not yet landed): each item is cut when submitted
#: and its rows land in the result when it ends, so the parent holds this many items'
#: points and results, not every item's (one queued behind the one running keeps every
#: worker busy)
IN_FLIGHT_PER_WORKER = 2


class ProcessesExecutor:
    """A local pool of ``workers`` processes (default: one per thread asked for), each
    tracing single-threaded; the scene is sent to each worker once (a file the pool's
    initializer reads), which builds its occluders and method once and keeps them for all
    its items.  Work items are ``chunk_points`` points (default: the points split into
    ITEMS_PER_WORKER items per worker, at most MAX_ITEM_POINTS each)."""

    name = "processes"

    def __init__(self, workers: int | None = None, chunk_points: int | None = None):
        self.workers, self.chunk_points = workers, chunk_points

    def estimate(self, job, method, plan, threads: int, chunk_rays: int, progress=None):
        n = len(plan.points)
        workers = max(1, self.workers or threads)
        per_item = self.chunk_points or max(1, min(-(-n // (workers * ITEMS_PER_WORKER)),
                                                   MAX_ITEM_POINTS))
        work = items(job, plan, per_item)
        if not work:
            try:
                return method.estimate(plan, threads, chunk_rays, progress)
            finally:
                release(method)
        release(method)  # each worker prepares its own; what was started ahead here is not used
        # "spawn": a clean interpreter (no copy of this process's threads or Embree state);
        # the worker imports aobake by name, exactly the package this process runs, since
        # multiprocessing hands the child this process's sys.path.
        context = multiprocessing.get_context("spawn")
        if hasattr(signal, "pthread_sigmask"):
            # multiprocessing's resource tracker is started once, before the signals are
            # blocked below: starting it unblocks SIGINT and SIGTERM in the thread that does
            from multiprocessing import resource_tracker

            resource_tracker.ensure_running()
        result, done, pool = merged(method, plan), 0, None
        todo = iter(work)
        folder = tempfile.mkdtemp(prefix="aobake-job-")
        try:
            # The job goes to the workers through a file: multiprocessing writes a worker's
            # start-up data into a pipe whose reading end the parent keeps open until the
            # write is done, so a worker that died before reading more than the pipe holds
            # (64 KiB) would leave this process blocked in that write for ever.
            path = os.path.join(folder, "job.pickle")
            with open(path, "wb") as stream:
                pickle.dump(job, stream, protocol=pickle.HIGHEST_PROTOCOL)
            # Each worker is spawned by a submit: an interrupt waits until all have been
            # (a few milliseconds each; the workers start with it blocked, signals.held)
            with signals.held(children=True):
                pool = ProcessPoolExecutor(max_workers=min(workers, len(work)),
                                           mp_context=context, initializer=_start_worker,
                                           initargs=(path,))
                pending = {}
                for item in itertools.islice(todo, IN_FLIGHT_PER_WORKER * workers):
                    pending[pool.submit(worker.run_item, item, 1, chunk_rays)] = item
            while pending:
                finished, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    item = pending.pop(future)
                    try:
                        start, stop, part = future.result()
                    except BrokenProcessPool:
                        raise PoolError(
                            f"a worker process died while points {item.start}..{item.stop - 1} "
                            "were estimated (killed, out of memory, or a crash in native "
                            "code); the bake was stopped") from None
                    result.add(start, stop, part)
                    del part
                    done += stop - start
                    if progress:
                        progress(done, n)
                    for item in itertools.islice(todo, 1):  # the next item takes its place
                        pending[pool.submit(worker.run_item, item, 1, chunk_rays)] = item
        except BaseException:
            if pool is not None:  # an interrupt or a failed item: the rest is not wanted
                _end_workers(pool)
            raise
        finally:
            try:
                if pool is not None:
                    with signals.held():  # a pool closed halfway leaves semaphores behind
                        pool.shutdown(wait=True, cancel_futures=True)
            finally:
                shutil.rmtree(folder, ignore_errors=True)
        log.info("processes executor: %d items of <= %d points on %d workers", len(work),
                 per_item, min(workers, len(work)))
        return result.result()


def _start_worker(path: str) -> None:
    """Pool initializer: interrupts left to the parent (``signals.worker_ready``), then the
    job read from ``path`` and remembered (``worker.install``)."""
    signals.worker_ready()
    with open(path, "rb") as stream:
        worker.install(pickle.load(stream))


def _end_workers(pool) -> None:
    """End the pool's worker processes now (SIGTERM), their items unfinished."""
    terminate = getattr(pool, "terminate_workers", None)  # Python 3.14
    if terminate is not None:
        with contextlib.suppress(Exception):
            terminate()
        return
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        with contextlib.suppress(Exception):
            process.terminate()
