"""The import floors of the package (issue 31, docs/STYLE "readers register beside their
writers"): read from the source with ``ast``, over every module under ``aobake/``, so a
module added tomorrow is held to them too.

1. A package below another never imports it: ``aobake.outputs`` (writers and their readers)
   imports nothing of ``aobake.compare``, which reads through it; nor does a method.
2. No module imports a private (``_name``) of another package: neither ``from aobake.x
   import _y``, nor ``import aobake.x._y``, nor ``x._y`` on a module it imported.  A
   private belongs to the top-level unit that defines it (``aobake.outputs``, ``aobake.api``
   ...); the root package's own private modules (``aobake._native`` and the compiled
   kernels it loads) are the whole project's.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import aobake

ROOT = Path(aobake.__file__).resolve().parent

#: package -> the packages it may never import (data flows one way)
#: what sits above the plugins: the commands, the scoring tool and the composition
_ABOVE = ("aobake.cli", "aobake.compare", "aobake.api", "aobake.job", "aobake.batch")
BELOW = {
    "aobake.outputs": _ABOVE,
    "aobake.methods": _ABOVE,
    "aobake.targets": _ABOVE,
    # an executor splits records (aobake.records) and knows no target
    "aobake.executors": _ABOVE + ("aobake.targets",),
    # settings are values: the plugins import their records, not the reverse
    "aobake.settings": _ABOVE + ("aobake.methods", "aobake.targets", "aobake.executors",
                                 "aobake.outputs"),
}

#: (importing module, private reached) that predate this test, in files other changes own;
#: each is to be made public (or moved) by its owner, and then removed here (the last test
#: fails while an entry lingers, so the list only shrinks)
KNOWN: set = set()


def _modules():
    """(dotted name, is a package, path) of every module under aobake/."""
    for path in sorted(ROOT.rglob("*.py")):
        parts = path.relative_to(ROOT.parent).with_suffix("").parts
        package = parts[-1] == "__init__"
        yield ".".join(parts[:-1] if package else parts), package, path


MODULES = list(_modules())


def _resolve(module: str, package: bool, level: int, name: str | None) -> str:
    """The absolute module a (possibly relative) ``from ... import`` names."""
    if not level:
        return name or ""
    base = module.split(".") if package else module.split(".")[:-1]
    base = base[:len(base) - (level - 1)]
    return ".".join(base + ([name] if name else []))


def _imports(module: str, package: bool, tree: ast.AST):
    """Every (line, dotted name) the module imports: modules, and ``module.name`` for each
    name of a ``from module import name``; and the attribute names it reads through an
    aobake module it imported (``glb._write_glb`` as ``aobake.outputs.glb._write_glb``)."""
    bound = {}  # local name -> the aobake module (or module.name) it stands for
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
                if alias.name.startswith("aobake"):
                    local = alias.asname or alias.name.split(".")[0]
                    bound[local] = alias.name if alias.asname else local
        elif isinstance(node, ast.ImportFrom):
            source = _resolve(module, package, node.level, node.module)
            for alias in node.names:
                target = f"{source}.{alias.name}"
                yield node.lineno, target
                if source.startswith("aobake"):
                    bound[alias.asname or alias.name] = target
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                and node.value.id in bound and node.attr.startswith("_") \
                and not node.attr.startswith("__"):
            yield node.lineno, f"{bound[node.value.id]}.{node.attr}"


def _unit(dotted: str) -> str:
    """The top-level unit a module belongs to: aobake.outputs.glb -> aobake.outputs."""
    return ".".join(dotted.split(".")[:2])


def _private_owner(dotted: str) -> str | None:
    """The unit owning the first private part of ``dotted`` (None: nothing private, or a
    private of the root package, which is everyone's)."""
    parts = dotted.split(".")
    for i, part in enumerate(parts[1:], start=1):
        if part.startswith("_") and not part.startswith("__"):
            return None if i == 1 else _unit(".".join(parts[:i]))
    return None


def _violations():
    below, private = [], set()
    for module, package, path in MODULES:
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        for line, dotted in _imports(module, package, tree):
            where = f"{path.relative_to(ROOT.parent)}:{line}"
            for floor, above in BELOW.items():
                if (module == floor or module.startswith(floor + ".")) and any(
                        dotted == a or dotted.startswith(a + ".") for a in above):
                    below.append(f"{where}: {module} imports {dotted}")
            if not dotted.startswith("aobake."):
                continue
            owner = _private_owner(dotted)
            if owner is not None and owner != _unit(module):
                private.add((module, dotted, where))
    return below, private


BELOW_FOUND, PRIVATE_FOUND = _violations()


def test_the_walk_sees_the_package():
    names = {m for m, _, _ in MODULES}
    assert {"aobake.outputs", "aobake.outputs.glb", "aobake.compare", "aobake.methods.file"} \
        <= names
    # the checks find what they look for (a module that broke both floors would be caught)
    tree = ast.parse("from aobake.compare import read\nfrom aobake.outputs import glb\n"
                     "glb._write_glb\nimport aobake.outputs.npz as n\nn._savez\n"
                     "from ..compare.values import kind\n")
    found = [d for _, d in _imports("aobake.outputs.x", False, tree)]
    assert "aobake.compare.read" in found and "aobake.outputs.glb._write_glb" in found
    assert "aobake.outputs.npz._savez" in found and "aobake.compare.values.kind" in found
    assert _private_owner("aobake.outputs.glb._write_glb") == "aobake.outputs"
    assert _private_owner("aobake._native.embreex_forced") is None


def test_a_lower_package_never_imports_a_higher_one():
    assert not BELOW_FOUND, "\n".join(BELOW_FOUND)


def test_no_module_imports_a_private_of_another_package():
    new = sorted(f"{where}: {module} reaches {dotted}" for module, dotted, where
                 in PRIVATE_FOUND if (module, dotted) not in KNOWN)
    assert not new, ("a private of another package is imported (make it public where it is "
                     "defined, or move the code):\n" + "\n".join(new))


def test_every_known_private_import_is_still_there():
    found = {(m, d) for m, d, _ in PRIVATE_FOUND}
    gone = sorted(entry for entry in KNOWN if entry not in found)
    assert not gone, f"no longer reached: remove them from KNOWN in {__file__}: {gone}"

