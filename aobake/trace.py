"""Run a per-chunk function over a thread pool; results land by index, never by arrival.

embreex releases the GIL inside ``run()`` and numpy releases it in large
element-wise loops, so plain threads scale.  At most ``2 * threads`` chunks are
in flight, which bounds memory whatever the number of points.
"""

from __future__ import annotations

import os
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from typing import Callable


def default_threads() -> int:
    """All cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def run_chunks(
    n_chunks: int,
    work: Callable[[int], object],
    land: Callable[[int, object], None],
    threads: int,
    progress: Callable[[int], None] | None = None,
) -> None:
    """Call ``work(i)`` for i in range(n_chunks) on ``threads`` threads and ``land(i, result)``
    on the calling thread.  ``land`` must place results by ``i`` so the outcome does not
    depend on completion order.  ``progress(i)`` is called after each landing.
    """
    if threads <= 1:
        for i in range(n_chunks):
            land(i, work(i))
            if progress:
                progress(i)
        return
    with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="aobake") as pool:
        pending, next_chunk = {}, 0
        try:
            while next_chunk < n_chunks or pending:
                while next_chunk < n_chunks and len(pending) < 2 * threads:
                    pending[pool.submit(work, next_chunk)] = next_chunk
                    next_chunk += 1
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    i = pending.pop(future)
                    land(i, future.result())
                    if progress:
                        progress(i)
        except BaseException:
            for future in pending:
                future.cancel()
            raise
