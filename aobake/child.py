"""Start a child Python process that imports the same ``aobake`` as this one.

aobake runs some work in child interpreters (xatlas, which can crash or deadlock, in
``aobake.targets.texels.unwrap``).  ``python -c CODE`` puts the current directory first on
the child's ``sys.path``, so a child started from a checkout's root imports the checkout's
source tree, not the installed package its parent runs: a tree with no compiled kernels, or
another version of the code (issue 21).  ``python_child`` returns the command and the
environment of a child that imports exactly this process's package.

How: the child's code starts with a short prelude that drops the current directory ``-c``
put first on ``sys.path`` and puts this package's root (the directory holding this
``aobake`` package, passed as a literal in the prelude) first instead.  The rest of the
parent's path is kept: ``-I`` (isolated mode) would also drop ``PYTHONPATH``, the user's
site-packages and every other ``PYTHON*`` setting the parent ran with, so the child could
miss dependencies the parent found; ``-P``/``PYTHONSAFEPATH`` only exist from Python 3.11
(aobake supports 3.10) and the variable would leak into grandchildren.  For an editable
install the root is the checkout itself, so the child imports the sources, as its parent.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import NamedTuple

#: the directory that holds the ``aobake`` package this process imported
PACKAGE_ROOT = str(Path(__file__).absolute().parent.parent)


class Child(NamedTuple):
    """``subprocess.run(child.argv, env=child.env, ...)``"""

    argv: list[str]
    env: dict[str, str]


def prelude(root: str = PACKAGE_ROOT) -> str:
    """Python source that makes ``import aobake`` in this interpreter find the package under
    ``root``: ``-c``'s current directory (``''``, the first entry) is dropped, ``root`` is
    put first."""
    return ("import sys as _s\n"
            "if _s.path and _s.path[0] == '':\n"
            "    del _s.path[0]\n"
            f"_s.path.insert(0, {root!r})\n"
            "del _s\n")


def python_child(code: str, args=(), env: dict | None = None) -> Child:
    """The command and environment of a child Python that runs ``code`` (as ``python -c``,
    with ``args`` as ``sys.argv[1:]``) and imports the same ``aobake`` as this process.

    env : the child's environment (default: this process's), copied.  Nothing in it is
        needed to find the package (the prelude does that), so a caller may change it freely;
        a child that starts Python children of its own starts them with ``python_child`` too.
    """
    env = dict(os.environ if env is None else env)
    return Child([sys.executable, "-c", prelude() + code, *map(str, args)], env)
