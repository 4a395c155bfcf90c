"""Methods: how a value is estimated at sample points (see ``aobake.methods.base``).

``METHODS`` maps ``--method`` names to their classes.  ``rays`` (ray tracing with honest
error bars) is the reference; an approximation is one more module with a class having
``name``, ``casts_rays = False``, ``prepare``, ``estimate``, ``record`` and
``kernel_stages``, plus one line here.
"""

from aobake.methods.base import Estimates, Method, merge
from aobake.methods.discs import DiscsMethod
from aobake.methods.file import FileMethod
from aobake.methods.hemicube import HemicubeMethod
from aobake.methods.rays import RaysMethod
from aobake.methods.ssao import SCREEN_METHODS

#: method name -> class
METHODS = {"rays": RaysMethod, "discs": DiscsMethod, "file": FileMethod,
           "hemicube": HemicubeMethod, **SCREEN_METHODS}

__all__ = ["Estimates", "METHODS", "Method", "RaysMethod", "merge"]
