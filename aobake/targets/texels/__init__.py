"""Lightmap target: the texels of a UV atlas, each the mean of K surface samples.

Stages, one module each: ``atlas`` (own UVs or a new xatlas atlas, via
``unwrap``; ``uvcheck`` decides whether own UVs can be baked), ``raster``
(texels -> samples on triangles), ``surface`` (samples -> points and shading
normals), then tracing (not here), then ``gather`` (samples -> texel channels,
errors, gutters).  Texel conventions: see ``aobake.targets.texels.raster``.
"""

# The target and its stages (xatlas, the rasteriser, seams, ...) are imported on first use,
# not with the package: a per-vertex bake or a view never needs them (issue 21: fixed cost).
from aobake.registry import lazy_attributes

__getattr__ = lazy_attributes(__name__, {"TexelTarget": "aobake.targets.texels.target",
                                         "MIN_TEXELS_PER_CHART": "aobake.targets.texels.target"})
