"""Executors: where a method's estimates are computed (see ``aobake.executors.base``).

``EXECUTORS`` maps ``--executor`` names to their classes, each built as
``cls(workers=None, chunk_points=None)`` and answering ``estimate(job, method, plan,
threads, chunk_rays, progress) -> Estimates``.  A new executor is one module
with such a class, shipping ``aobake.executors.worker.run_item`` and the job's items,
plus one line here.
"""

from aobake.executors.base import Job, WorkItem, items, ranges
from aobake.executors.dask import DaskExecutor
from aobake.executors.local import ProcessesExecutor, ThreadsExecutor

#: executor name -> class
EXECUTORS = {"threads": ThreadsExecutor, "processes": ProcessesExecutor, "dask": DaskExecutor}

__all__ = ["DaskExecutor", "EXECUTORS", "Job", "ProcessesExecutor", "ThreadsExecutor",
           "WorkItem", "items", "ranges"]
