"""Methods: how a value is estimated at sample points (see ``aobake.methods.base``).

``METHODS`` maps ``--method`` names to their classes.  ``rays`` (ray tracing with honest
error bars) is the reference; an approximation is one more module with a class having
``name``, ``casts_rays = False``, ``prepare``, ``estimate``, ``record`` and
``kernel_stages``, plus one line here.
"""

from aobake.methods.base import Estimates, Method, merge
from aobake.registry import LazyRegistry, lazy_attributes

#: method name -> class (each module imported when the method is first used)
METHODS = LazyRegistry({
    "rays": "aobake.methods.rays:RaysMethod", "discs": "aobake.methods.discs:DiscsMethod",
    "file": "aobake.methods.file:FileMethod", "hemicube": "aobake.methods.hemicube:HemicubeMethod",
    "crytek": "aobake.methods.ssao:CrytekMethod", "shanmugam": "aobake.methods.ssao:ShanmugamMethod",
    "gtao": "aobake.methods.ssao:GtaoMethod", "heightfield": "aobake.methods.ssao:HeightfieldMethod",
    "depthmaps": "aobake.methods.depthmaps:DepthmapsMethod"})

__getattr__ = lazy_attributes(__name__, {"RaysMethod": "aobake.methods.rays"})

__all__ = ["Estimates", "METHODS", "Method", "RaysMethod", "merge"]
