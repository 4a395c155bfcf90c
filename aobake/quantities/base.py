"""What a quantity is: its fields (one spelling from result attribute to file), its
estimator, its no-information answer, its convention text and its summaries.

A new quantity is one new module in this package defining a :class:`Quantity`
plus one line in ``aobake.quantities.QUANTITIES``; the CLI's ``--quantity``
choices, the result attributes, the NPZ/PLY/glTF/EXR names, the report and the
README's output table all read from there.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class Field:
    """One per-point array of a bake, named once for every place it appears.

    name : BakeResult attribute, NPZ key, report key, metadata key
    width : components per point (1 scalar, 3 vector)
    dtype : dtype stored in NPZ (float32 for estimates, far finer than their errors)
    ply : PLY vertex property names (width of them)
    gltf : glTF custom vertex attribute (starts with "_"), or None
    exr : lightmap EXR channel names (width of them), or () when not a texel channel
    meaning : one line for docs and the README
    """

    name: str
    width: int
    dtype: type
    ply: tuple
    gltf: str | None
    exr: tuple
    meaning: str


@dataclass(frozen=True)
class Traced:
    """What the tracer hands every estimator for k points.

    directions : (k, R, m, 3) float32 unit ray directions (R replicates of m rays),
    occluded : (k, R, m) bool (a hit within the max distance),
    distance : (k, R, m) float32 hit distance, inf on a miss | None (when no quantity needs it),
    normals : (k, 3) float64 unit, iid : bool (samples.iid), tau : float per unit of the distances (the tracer's local frame),
    kernels : the compiled module or None (numpy formulations),
    confidence : the two-sided level of the intervals (0.95),
    max_distance : the max distance in scene units (0: every ray misses by definition),
    path : (k, R, m) float64 each ray's path sample (``aobake.paths``: albedo^k when it
    escapes after k bounces, else 0) | None (when no quantity needs paths), albedo : rho,
    inward : (k, R, m) float64 the inward rays' distances from the point to the first
    surface behind it, scene units, a miss counted as ``cap`` | None (when no quantity
    needs inward rays: ``quantities.thickness``), cap : that cap (scene units).
    """

    directions: np.ndarray
    occluded: np.ndarray
    distance: np.ndarray | None
    normals: np.ndarray
    iid: bool
    tau: float
    kernels: object = None
    confidence: float = 0.95
    max_distance: float = float("inf")
    path: np.ndarray | None = None
    albedo: float = 0.0
    inward: np.ndarray | None = None
    cap: float = 1.0


@dataclass(frozen=True)
class Quantity:
    """A quantity a bake can estimate.

    name : the one spelling (``--quantity``, config, report)
    value, error : its two fields (the estimate and its one-standard-error)
    interval : (low, high) fields of its confidence interval, or () (bent normals: the
        error is an angle)
    moments : Traced -> dict of additive statistics of these rays, each (k, R, ...) float64
        per replicate (escape counts, sums, squared deviations)
    extend : (a, b, na, nb) -> the moments of a's na samples per replicate followed by b's nb
        (a streamed point's pieces, folded in order)
    finish : (moments, traced, m) -> {field name: (k,) | (k, 3) float64} for all its fields,
        from the moments of m samples per replicate (``traced`` for its normals and settings)
    no_information : normals (k, 3) -> the same dict for points that cast no rays
    conventions : weighting -> {metadata key: text} (what 0 and 1 mean)
    texel : "scalar" (texel = mean of its samples) | "direction" (normalised mean,
        optionally in tangent space)
    needs_distance : True when it needs closest-hit distances (dearer queries)
    needs_paths : True when it needs each ray's path beyond its first hit (``aobake.paths``)
    needs_inward : True when it needs rays into the inward hemisphere (about -n) and their
        distances (``Traced.inward``); its ``no_information`` then takes ``cap=``
    kernels : the compiled stages its estimator uses (for the report)
    bounds : (low, high) the range of a scalar value (what image steps clip to)
    summary : (value, error) over sampled points -> report dict
    """

    name: str
    value: Field
    error: Field
    moments: Callable
    extend: Callable
    finish: Callable
    no_information: Callable
    conventions: dict
    texel: str = "scalar"
    needs_distance: bool = False
    needs_paths: bool = False
    needs_inward: bool = False
    bounds: tuple = (0.0, 1.0)
    kernels: tuple = ()
    summary: Callable | None = field(default=None)
    interval: tuple = ()

    def estimate(self, traced: Traced) -> dict:
        """Traced (all m samples of each replicate) -> {field name: (k,) | (k, 3) float64}."""
        return self.finish(self.moments(traced), traced, traced.occluded.shape[2])

    @property
    def fields(self) -> tuple:
        return (self.value, self.error, *self.interval)
