"""aobake: a ray-traced ambient-occlusion reference baker (Embree through embreex).

Python API::

    import aobake
    result = aobake.bake("mesh.obj", quantities=("ao", "obscurance"), rays=256)
    result.ao, result.ao_stderr, result.report

    values = aobake.bake_points("mesh.obj", points, normals, rays=1024)
    lightmap = aobake.bake_texels("mesh.obj", resolution=1024)
    aobake.write(lightmap, "ao.exr", report="report.json")   # exactly the CLI's files
"""

import logging

from aobake import outputs
from aobake.bake import bake, bake_points, bake_texels, bake_view, bake_view_truths, run
from aobake.config import BakeConfig
from aobake.errors import AobakeError, InputError, OutputError
from aobake.outputs import write
from aobake.results import BakeResult, TexelResult, ViewResult
from aobake.scene import Scene, load_scene

__all__ = ["AobakeError", "BakeConfig", "BakeResult", "InputError", "OutputError", "Scene",
           "TexelResult", "ViewResult", "bake", "bake_points", "bake_texels", "bake_view",
           "bake_view_truths",
           "load_scene", "outputs", "run",
           "write"]
__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())
