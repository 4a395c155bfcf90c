"""Targets: where AO is measured (see ``aobake.targets.base`` for the protocol).

``TARGETS`` maps target names to their classes; ``points`` is the library's
``bake_points`` (it needs the points, so it has no CLI name); ``view`` is ``aobake view``;
``projected_texels`` / ``projected_vertices`` bake a source mesh onto a low mesh's UVs or
vertices through a cage (``aobake.targets.projected``: they need the low mesh).  Each
target's module is imported when the target is first used (``aobake.registry``).
"""

from aobake.registry import LazyRegistry, lazy_attributes

#: target name -> class; the CLI offers those that need no arguments
TARGETS = LazyRegistry({
    "vertices": "aobake.targets.vertices:VertexTarget",
    "texels": "aobake.targets.texels.target:TexelTarget",
    "points": "aobake.targets.points:PointsTarget",
    "view": "aobake.targets.view:ViewTarget",
    "projected_texels": "aobake.targets.projected:ProjectedTexelTarget",
    "projected_vertices": "aobake.targets.projected:ProjectedVertexTarget"})
CLI_TARGETS = ("vertices", "texels")

__getattr__ = lazy_attributes(__name__, {
    "VertexTarget": "aobake.targets.vertices", "TexelTarget": "aobake.targets.texels.target",
    "PointsTarget": "aobake.targets.points", "ViewTarget": "aobake.targets.view",
    "ProjectedTexelTarget": "aobake.targets.projected",
    "ProjectedVertexTarget": "aobake.targets.projected"})
