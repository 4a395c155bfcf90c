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

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np


@dataclass
class SamplePoints:
    """Where to trace.

    points : (n, 3) float64 scene units, normals : (n, 3) float64 unit (zero = not
    traced: 0 rays, no-information values), ids : (n,) int64 sample-stream ids (a
    point's rays are a pure function of (seed, id, sample id): equal ids get equal
    rays), sizes : (n,) float64 the size of each point's own triangles (sqrt of twice their
    mean area; sets the ray offset) or None when unknown, kernels : stage -> compiled? for
    the compiled stages the target ran, state : whatever ``finish`` needs back, faces :
    (n,) int64 the triangle each point lies on (-1: none) and bary : (n, 3) float64 its
    barycentric coordinates there, or None when the target does not know them (vertices,
    query points): a method that interpolates on the surface (``file``) needs them;
    image : the view's G-buffer (``aobake.screen.gbuffer.GBuffer``: depth, hardware depths,
    view-space normals, coverage, the camera) when the points are a camera's pixels (their
    ids are then the pixel indices r * W + c), else None: what a screen-space method reads.
    """

    points: np.ndarray
    normals: np.ndarray
    ids: np.ndarray
    sizes: np.ndarray | None = None
    kernels: dict = field(default_factory=dict)
    state: object = None
    faces: np.ndarray | None = None
    bary: np.ndarray | None = None
    image: object = None


@dataclass
class Finished:
    """A target's result before the report, and what the report needs from it.

    result : BakeResult | TexelResult (``report`` filled in by ``run``),
    values, rays : the per-point fields and rays (n,) the error summary is taken over,
    points : how many points the report counts, cast : rays traced (None = sum of rays),
    report : extra report sections (e.g. ``texture``),
    rays_key : the report's name for the rays each point cast.
    """

    result: object
    values: dict
    rays: np.ndarray
    points: int
    cast: int | None = None
    report: dict = field(default_factory=dict)
    rays_key: str = "rays_per_point"


class Target(Protocol):
    name: str

    def rays_per_point(self, config) -> int: ...

    def sample(self, scene, config, occluders, threads: int, timings: dict, warnings: list,
               phase=None) -> SamplePoints: ...

    def finish(self, scene, config, plan: SamplePoints, estimates, timings: dict,
               warnings: list) -> Finished: ...
