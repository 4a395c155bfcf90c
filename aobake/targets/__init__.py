"""Targets: where AO is measured (see ``aobake.targets.base`` for the protocol).

``TARGETS`` maps target names to their classes; ``points`` is the library's
``bake_points`` (it needs the points, so it has no CLI name); ``view`` is ``aobake view``.
"""

from aobake.targets.camera import CameraTarget
from aobake.targets.points import PointsTarget
from aobake.targets.texels import TexelTarget
from aobake.targets.vertices import VertexTarget

#: target name -> class; the CLI offers those that need no arguments
TARGETS = {"vertices": VertexTarget, "texels": TexelTarget, "points": PointsTarget,
           "view": CameraTarget}
CLI_TARGETS = ("vertices", "texels")
