"""A registry whose entries are imported when first used (``TARGETS``, ``METHODS``,
``EXECUTORS``).

Each plugin (a target, a method, an executor) is one module; the registry names them
without importing them, so a per-vertex bake does not import the lightmap target's stages,
the OpenGL hemicube, the screen-space methods or Dask (issue 21: the command's start-up
paid ~0.17 s for importing every plugin).  Keys (the CLI's choices) are known without any
import; ``registry[name]`` imports the plugin's module once and returns its class.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping


class LazyRegistry(Mapping):
    """name -> object, each given as "module:attribute" and imported on first lookup.

    entries : dict name -> "package.module:Attribute" (in the order the registry lists them).
    """

    def __init__(self, entries: dict):
        self._entries = dict(entries)
        self._loaded: dict = {}

    def __getitem__(self, name):
        if name not in self._loaded:
            module, attribute = self._entries[name].split(":")  # KeyError for unknown names
            self._loaded[name] = getattr(importlib.import_module(module), attribute)
        return self._loaded[name]

    def __iter__(self):
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, name) -> bool:
        return name in self._entries

    def __repr__(self) -> str:
        return f"LazyRegistry({self._entries!r})"


def lazy_attributes(module_name: str, where: dict):
    """A module ``__getattr__`` (PEP 562) resolving the names of ``where`` (name -> module)
    on first use, so a package's ``from package import Class`` keeps working without the
    package importing every plugin."""
    def __getattr__(name: str):
        if name in where:
            return getattr(importlib.import_module(where[name]), name)
        raise AttributeError(f"module {module_name!r} has no attribute {name!r}")
    return __getattr__
