"""The compiled kernels (``aobake._kernels``: one C file per stage, listed in aobake/_kernels.c),
loaded once, and which of them a bake ran.

Each kernel has a numpy formulation that gives identical bits (tested); the
kernel is only faster.  A stage asks :func:`kernels` once per bake and passes
the answer down, and the report records that same answer per stage
(:func:`used`), so ``parameters.kernels`` says truthfully what ran, also when
:func:`numpy_only` forces the numpy path.
"""

from __future__ import annotations

import contextlib
import threading
from typing import Iterator

try:  # built by setup.py; optional (a failed build leaves the numpy path)
    from aobake import _kernels as _compiled
except ImportError:  # pragma: no cover - exercised only where no C compiler was available
    _compiled = None

#: stage -> the kernel function it uses
KERNELS = {"ray_generation": "fill_rays", "escape_counts": "row_counts",
           "rasterizer": "raster_rows", "atlas_packing": "pack_charts", "seam_solve": "seam_csr_cg",
           "gutters": "dilate_rings"}
#: every function the stages call (a module built from an older checkout lacks some)
FUNCTIONS = set(KERNELS.values()) | {"radix_argsort", "surface_interp", "chart_marks",
                                      "seam_pattern", "seam_values", "surface_shading",
                                      "parity_union_find", "triangle_normals",
                                      "vertex_normal_sums", "pixel_rays",
                                      "box_rays", "obj_floats", "obj_corners",
                                      "orient_terms", "orient_volumes"}

if _compiled is not None and not FUNCTIONS <= set(dir(_compiled)):
    # An editable install not rebuilt since the kernels changed: numpy for everything
    # (the same results, slower; the report says "numpy") rather than a failing stage.
    import logging

    logging.getLogger(__name__).warning(
        "aobake._kernels is out of date (no %s): using numpy; rebuild it with "
        "`pip install -e .` or `python setup.py build_ext --inplace`",
        ", ".join(sorted(FUNCTIONS - set(dir(_compiled)))))
    _compiled = None

_state = threading.local()


def built() -> bool:
    """True when ``aobake._kernels`` was compiled at install."""
    return _compiled is not None


def kernels():
    """The compiled module, or None when it was not built or :func:`numpy_only` is active."""
    if getattr(_state, "numpy_only", False):
        return None
    return _compiled


@contextlib.contextmanager
def _forced(flag: str) -> Iterator[None]:
    """Set the thread-local ``flag`` inside the block (restored after)."""
    before = getattr(_state, flag, False)
    setattr(_state, flag, True)
    try:
        yield
    finally:
        setattr(_state, flag, before)


def numpy_only():
    """Run bakes started on this thread inside the block on the numpy formulations."""
    return _forced("numpy_only")


def embreex_only():
    """Build Embree backends started on this thread inside the block on embreex rather
    than ``aobake._embree`` (``aobake.backends.native``: the same answers, slower)."""
    return _forced("embreex_only")


def embreex_forced() -> bool:
    """True inside :func:`embreex_only` on this thread."""
    return getattr(_state, "embreex_only", False)


def carried(function):
    """``function`` wrapped to run, on any thread, with the ``numpy_only`` and
    ``embreex_only`` states of the thread calling ``carried`` (they are thread-local)."""
    forced = getattr(_state, "numpy_only", False)
    embreex = embreex_forced()

    def call(*args, **kwargs):
        with contextlib.ExitStack() as stack:
            if forced:
                stack.enter_context(numpy_only())
            if embreex:
                stack.enter_context(embreex_only())
            return function(*args, **kwargs)

    return call


def label(compiled: bool) -> str:
    return "compiled" if compiled else "numpy"


def used(stages: dict) -> dict:
    """stages: stage name -> bool compiled | None (stage not run) -> the report's ``kernels``."""
    return {stage: ("not used" if stages.get(stage) is None else label(stages[stage]))
            for stage in KERNELS}
