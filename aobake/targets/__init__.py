"""Targets: where AO is measured (see ``aobake.targets.base`` for the protocol).

``TARGETS`` maps the CLI's ``--target`` names to their classes; ``points`` is
the library's ``bake_points`` (it needs the points, so it has no CLI name).
"""

from aobake.targets.points import PointsTarget
from aobake.targets.texels import TexelTarget
from aobake.targets.vertices import VertexTarget

#: target name -> class; the CLI offers those that need no arguments
TARGETS = {"vertices": VertexTarget, "texels": TexelTarget, "points": PointsTarget}
CLI_TARGETS = ("vertices", "texels")
