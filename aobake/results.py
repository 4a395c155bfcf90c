"""What a bake returns, in two kinds: per-point results (``points``: vertices, query points)
and images (``image``: lightmap texels and camera pixels).  Writers are chosen by
(kind, extension) (``aobake.outputs.registry``); each result says its kind and the target
that made it, so nothing is guessed from its attributes."""

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

    #: the result kind (writers are chosen by kind and extension) and the target writers
    #: check formats against (query points write the same formats as vertices)
    kind = "points"
    target = "vertices"

    def __getattr__(self, name):
        if name in FIELDS and name != "values":
            return self.__dict__.get("values", {}).get(name)
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")

    def fields(self) -> dict:
        """Per-point arrays that were computed, keyed and ordered as in the NPZ/PLY/GLB outputs."""
        known = {"normals": self.normals, "rays": self.rays, **self.values}
        return {name: known[name] for name in FIELDS if known.get(name) is not None}


@dataclass
class ImageResult:
    """An image of per-pixel values (the ``image`` kind).

    channels : name -> (H, W) float32 (EXR channel names of ``aobake.quantities.FIELDS``,
    plus ``coverage``), row 0 = top of the image; covered : (H, W) bool pixels with values;
    report : dict.
    """

    channels: dict
    covered: np.ndarray
    report: dict

    kind = "image"


@dataclass
class TexelResult(ImageResult):
    """A baked lightmap.

    channels : name -> (H, W) float32 images after gutter dilation ('ao', 'ao_stderr',
    'obscurance', 'obscurance_stderr', 'bent_normal.X/.Y/.Z', 'bent_normal_stderr', 'rays',
    'coverage'; the EXR names of ``aobake.quantities.FIELDS``),
    row 0 = top of the image (v near 1), texel centres at u = (c + 0.5) / W,
    v = 1 - (r + 0.5) / H; covered : (H, W) bool texels with surface samples;
    atlas : ``aobake.targets.texels.atlas.Atlas``; report : dict.
    """

    atlas: object = None

    target = "texels"


@dataclass
class ViewResult(ImageResult):
    """A camera view (``aobake view``): the G-buffer and per-pixel values.

    channels : name -> (H, W) float32 (``aobake.targets.camera.GBUFFER`` and the method's
    fields; docs/conventions.md), covered : (H, W) bool pixels that see the scene,
    camera : ``aobake.camera.Camera``; report : dict (its ``camera`` section re-projects a
    pixel exactly).
    """

    camera: object = None

    target = "view"
