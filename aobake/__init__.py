"""aobake: a ray-traced ambient-occlusion reference baker (Embree through embreex).

Python API::

    import aobake
    result = aobake.bake("mesh.obj", quantities=("ao", "obscurance"), rays=256)
    result.ao, result.ao_stderr, result.report

    values = aobake.bake_points("mesh.obj", points, normals, rays=1024)
    lightmap = aobake.bake_texels("mesh.obj", resolution=1024)
    aobake.write(lightmap, "ao.exr", report="report.json")   # exactly the CLI's files
    aobake.bake_file("mesh.obj", "ao.exr", rays=64)           # as the command line does

The names are resolved on first use (PEP 562), so ``import aobake`` is cheap and the
command line can catch a signal before the library is imported.
"""

import importlib
import logging

#: public name -> the module that defines it
_WHERE = {
    "bake": "aobake.api", "bake_points": "aobake.api", "bake_texels": "aobake.api",
    "bake_view": "aobake.api", "bake_view_truths": "aobake.api", "run": "aobake.api",
    "bake_file": "aobake.job",
    "BakeConfig": "aobake.settings",
    "AobakeError": "aobake.errors", "InputError": "aobake.errors",
    "OutputError": "aobake.errors", "UsageError": "aobake.errors",
    "write": "aobake.outputs",
    "BakeResult": "aobake.records", "TexelResult": "aobake.records",
    "ViewResult": "aobake.records",
    "Scene": "aobake.scene", "load_scene": "aobake.scene",
}

__all__ = sorted(_WHERE) + ["outputs"]
__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())


def __getattr__(name: str):
    if name in _WHERE:
        value = getattr(importlib.import_module(_WHERE[name]), name)
        globals()[name] = value  # once: later lookups are plain attribute reads
        return value
    if name == "outputs":
        return importlib.import_module("aobake.outputs")
    raise AttributeError(f"module 'aobake' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
