"""Targets: where AO is measured (see ``aobake.targets.base`` for the protocol).

``TARGETS`` maps target names to their classes; ``points`` is the library's
``bake_points`` (it needs the points, so it has no CLI name); ``view`` is ``aobake view``;
``projected_texels`` / ``projected_vertices`` bake a source mesh onto a low mesh's UVs or
vertices through a cage (``aobake.targets.projected``: they need the low mesh).
"""

from aobake.targets.camera import CameraTarget
from aobake.targets.points import PointsTarget
from aobake.targets.projected import ProjectedTexelTarget, ProjectedVertexTarget
from aobake.targets.texels import TexelTarget
from aobake.targets.vertices import VertexTarget

#: target name -> class; the CLI offers those that need no arguments
TARGETS = {"vertices": VertexTarget, "texels": TexelTarget, "points": PointsTarget,
           "view": CameraTarget, "projected_texels": ProjectedTexelTarget,
           "projected_vertices": ProjectedVertexTarget}
CLI_TARGETS = ("vertices", "texels")
