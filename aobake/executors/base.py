"""What an executor is: where a method's estimates are computed.

An executor takes the bake's :class:`Job` (everything a worker needs to rebuild the
method: the scene, the configuration, the method's name, the rays per point and whether
the compiled kernels run; all picklable) and the sample points, cuts the points into
:class:`WorkItem` ranges, has each estimated and merges the results by point index
(``aobake.records.merge``).  Every point's estimate depends on that point alone, so
every executor, worker count and split gives the same bits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Job:
    """One bake as a worker rebuilds it.

    scene : ``aobake.scene.Scene`` (as loaded and repaired by the parent), config :
    BakeConfig, method : ``METHODS`` key, rays_per_point : int (the target's), compiled :
    bool (run the compiled kernels, as the parent decided), key : str naming this job in a
    worker's cache (a worker builds the occluders and the method once per job).
    """

    scene: object
    config: object
    method: str
    rays_per_point: int
    compiled: bool
    key: str


@dataclass(frozen=True)
class WorkItem:
    """Points start..stop-1 of a job: points (k, 3) float64, normals (k, 3) float64, ids
    (k,) int64, sizes (k,) float64 | None, faces (k,) int64 | None, bary (k, 3) float64 |
    None (``SamplePoints`` fields), image : the view's whole G-buffer or None (not cut: a
    screen-space method reads a pixel's neighbours)."""

    key: str
    start: int
    stop: int
    points: np.ndarray
    normals: np.ndarray
    ids: np.ndarray
    sizes: np.ndarray | None
    faces: np.ndarray | None = None
    bary: np.ndarray | None = None
    image: object = None

    def sample_points(self):
        """The item's points as ``SamplePoints``."""
        from aobake.records import SamplePoints

        return SamplePoints(self.points, self.normals, self.ids, sizes=self.sizes,
                            faces=self.faces, bary=self.bary, image=self.image)


def release(method) -> None:
    """End what ``method`` holds for estimating in this process (the hemicube's OpenGL child
    started ahead, ``close``): every executor calls it as its ``estimate`` returns or fails,
    and before handing the work to workers elsewhere, so no process a bake started
    outlives it."""
    close = getattr(method, "close", None)
    if close is not None:
        close()


def ranges(n: int, per_item: int) -> list:
    """[(start, stop), ...] cutting 0..n-1 into consecutive ranges of ``per_item`` points."""
    per_item = max(1, int(per_item))
    return [(start, min(n, start + per_item)) for start in range(0, n, per_item)]


def cut(job: Job, plan, start: int, stop: int) -> WorkItem:
    """The work item of points start..stop-1 of ``plan`` (``SamplePoints``): its per-point
    arrays cut (views of the plan's, or the rows a plan that makes them on demand gives:
    ``records.BlockSizes``, ``records.PointRange``), the view's image whole."""
    sel = slice(start, stop)

    def part(array):
        return None if array is None else array[sel]

    return WorkItem(job.key, start, stop, plan.points[sel], plan.normals[sel], plan.ids[sel],
                    part(plan.sizes), part(plan.faces), part(plan.bary), plan.image)


class Items:
    """The work items of ``plan`` (``SamplePoints``), ``per_item`` points each: a sequence
    whose items are cut when asked for (``len``, indexing, iteration), so an executor holds
    the items in flight, not a cut of every point's rows at once."""

    def __init__(self, job: Job, plan, per_item: int):
        self.job, self.plan = job, plan
        self.bounds = ranges(len(plan.points), per_item)

    def __len__(self) -> int:
        return len(self.bounds)

    def __getitem__(self, k: int) -> WorkItem:
        return cut(self.job, self.plan, *self.bounds[k])

    def __iter__(self):
        for start, stop in self.bounds:
            yield cut(self.job, self.plan, start, stop)


def items(job: Job, plan, per_item: int) -> Items:
    """The work items of ``plan``, ``per_item`` points each (:class:`Items`: cut when read)."""
    return Items(job, plan, per_item)


def whole(job: Job, plan) -> WorkItem:
    """The work item of every point of ``plan``, its arrays as the plan holds them (not cut:
    a plan's sizes made a block at a time stay so), for cutting items from it."""
    return WorkItem(job.key, 0, len(plan.points), plan.points, plan.normals, plan.ids,
                    plan.sizes, plan.faces, plan.bary, plan.image)


def merged(method, plan):
    """A ``records.Merged`` for the estimates of ``plan``'s points, with the folds
    ``method`` asks for (``folds(plan)``: extras it reads as a summary, not per point)."""
    from aobake.records import Merged

    folds = getattr(method, "folds", None)
    return Merged(len(plan.points), folds(plan) if folds is not None else None)
