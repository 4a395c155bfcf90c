"""What a method is: how a value is estimated at sample points, whatever the target.

A method is prepared once per scene (``METHODS[name].prepare(scene, config, occluders,
rays_per_point)``) and then estimates fields at any set of sample points
(``estimate(points, threads, chunk_rays, progress) -> Estimates``).  Each point's
estimate depends on that point alone (its position, normal, size and sample-stream
id), so :func:`merge` of the estimates of any split of the points gives the same
arrays as one call on all of them: that is what lets an executor split a bake over
threads, processes or machines.  ``record(estimates)`` gives the report's
parameters from the merged estimates, never from state left on the method.
"""

from __future__ import annotations

from typing import Callable, Protocol

from aobake.errors import InputError
from aobake.records import Estimates, merge  # noqa: F401  (the type every method returns)


def refuse_ray_settings(name: str, config) -> None:
    """InputError for the settings that only mean something to a method casting rays
    (--tolerance, --keep-distances), asked of method ``name``, which casts none."""
    if getattr(config, "tolerance", None) is not None:
        raise InputError(f"--tolerance sets a ray count: --method {name} casts no rays")
    if getattr(config, "keep_distances", False):
        raise InputError(f"--keep-distances keeps ray distances: --method {name} casts no "
                         "rays")


class Method(Protocol):
    """name : the registry key; casts_rays : whether ``estimate`` returns ray counts."""

    name: str
    casts_rays: bool

    @classmethod
    def prepare(cls, scene, config, occluders, rays_per_point: int) -> "Method": ...

    def estimate(self, points, threads: int, chunk_rays: int,
                 progress: Callable[[int, int], None] | None = None) -> Estimates: ...

    def record(self, estimates: Estimates) -> dict: ...

    def kernel_stages(self) -> dict: ...
