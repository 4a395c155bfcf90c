"""What a bake returns: per-point results (vertices, query points) or a lightmap."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from aobake.quantities import FIELDS


@dataclass
class BakeResult:
    """Per-point results.

    positions : (n, 3) float64, faces : (f, 3) int64 | None (None for query points),
    normals : (n, 3) float64 (the normals the hemispheres were built on),
    rays : (n,) int32 rays cast per point,
    values : field name -> (n,) / (n, 3) float64 for the quantities baked (see
    ``aobake.quantities.FIELDS``); each is also an attribute (``result.ao``,
    ``result.ao_stderr``, ``result.bent_normal`` ...), None when not baked,
    report : dict (configuration, parameters used, statistics, versions),
    kept : with ``keep_distances``, {"ray_distances": (p, R m) float32 every traced point's
    hit distances in the tracer's local units (inf on a miss; ``parameters.trace_scale``
    converts), "ray_point": (n,) int32 the row of each result point}, else {}.
    """

    positions: np.ndarray
    faces: np.ndarray | None
    normals: np.ndarray
    rays: np.ndarray
    values: dict = field(default_factory=dict)
    report: dict = field(default_factory=dict)
    kept: dict = field(default_factory=dict)

    def __getattr__(self, name):
        if name in FIELDS and name != "values":
            return self.__dict__.get("values", {}).get(name)
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")

    def fields(self) -> dict:
        """Per-point arrays that were computed, keyed and ordered as in the NPZ/PLY/GLB outputs."""
        known = {"normals": self.normals, "rays": self.rays, **self.values}
        return {name: known[name] for name in FIELDS if known.get(name) is not None}


@dataclass
class TexelResult:
    """A baked lightmap.

    channels : name -> (H, W) float32 images after gutter dilation ('ao', 'ao_stderr',
    'obscurance', 'obscurance_stderr', 'bent_normal.X/.Y/.Z', 'bent_normal_stderr', 'rays',
    'coverage'; the EXR names of ``aobake.quantities.FIELDS``),
    row 0 = top of the image (v near 1), texel centres at u = (c + 0.5) / W,
    v = 1 - (r + 0.5) / H; covered : (H, W) bool texels with surface samples;
    atlas : ``aobake.targets.texels.atlas.Atlas``; report : dict.
    """

    channels: dict
    covered: np.ndarray
    atlas: object
    report: dict
