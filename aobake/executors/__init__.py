"""Executors: where a method's estimates are computed (see ``aobake.executors.base``).

``EXECUTORS`` maps ``--executor`` names to their classes, each built as
``cls(workers=None, chunk_points=None)`` and answering ``estimate(job, method, plan,
threads, chunk_rays, progress) -> Estimates``.  A new executor is one module
with such a class, shipping ``aobake.executors.worker.run_item`` and the job's items,
plus one line here.
"""

from aobake.executors.base import Job, WorkItem, items, ranges
from aobake.executors.local import ThreadsExecutor
from aobake.registry import LazyRegistry, lazy_attributes

#: executor name -> class (the processes' and Dask's modules imported when first used)
EXECUTORS = LazyRegistry({"threads": "aobake.executors.local:ThreadsExecutor",
                          "processes": "aobake.executors.processes:ProcessesExecutor",
                          "dask": "aobake.executors.dask:DaskExecutor"})

__getattr__ = lazy_attributes(__name__, {"DaskExecutor": "aobake.executors.dask",
                                         "ProcessesExecutor": "aobake.executors.processes"})

__all__ = ["DaskExecutor", "EXECUTORS", "Job", "ProcessesExecutor", "ThreadsExecutor",
           "WorkItem", "items", "ranges"]
