"""What a target is: where AO is measured, and how per-point estimates become a result.

A target turns a scene into sample points (``sample``), and a method's estimates
at those points into its result (``finish``).  ``aobake.api.run`` calls them in
that order, with the method in between.  The scene's occluders are built before
``sample`` and handed to it as a function returning them (it waits for their build):
a target that needs first hits (the camera) casts its primary rays through them; one
that does not never calls it, so the build overlaps its work.
A new target is one module with such a class plus one line in
``aobake.targets.TARGETS``.
"""

from __future__ import annotations

from typing import Protocol

from aobake.records import Finished, SamplePoints  # noqa: F401  (what a target makes)


class Target(Protocol):
    name: str

    def rays_per_point(self, config) -> int: ...

    def sample(self, scene, config, occluders, threads: int, timings: dict, warnings: list,
               phase=None) -> SamplePoints: ...

    def finish(self, scene, config, plan: SamplePoints, estimates, timings: dict,
               warnings: list) -> Finished: ...
