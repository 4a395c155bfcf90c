"""Embree queries through ``aobake._embree`` (occlusion in packets), on embreex's libembree4.

:func:`binding` answers once per process whether the compiled module was built and the
Embree library embreex loaded was found and accepted; ``EmbreeBackend`` then traces
through it, else through embreex.  Both give the same occlusion answers (packets answer
each ray alone; tests/test_native_embree.py compares them); the compiled one is faster
(benchmarks/bench_backend.py).  ``aobake._native.embreex_only`` forces embreex on this
thread (tests, benchmarks); the report's ``parameters.embree_binding`` says which ran.
"""

from __future__ import annotations

import glob
import logging
import os
import threading

from aobake._native import embreex_forced

log = logging.getLogger(__name__)

#: the packet width the occlusion queries use, where the CPU allows it (at most 16;
#: benchmarks/bench_backend.py --widths measures each)
PACKET_WIDTH = 16

_lock = threading.Lock()
_opened: tuple | None = None  # (module, version, packet width) or (None, reason)


def library_path() -> str | None:
    """The libembree4 file embreex's extension loaded (None if it cannot be told)."""
    import embreex.rtcore_scene  # noqa: F401  (loads the library into this process)

    try:  # Linux: the file actually mapped, whatever its wheel-specific name
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as maps:
            for line in maps:
                path = line.rstrip("\n").split(None, 5)[-1]
                if "libembree4" in os.path.basename(path) and os.path.isfile(path):
                    return path
    except OSError:
        pass
    import embreex

    root = os.path.dirname(os.path.dirname(embreex.__file__))
    for pattern in ("embreex.libs/libembree4*", "embreex/.dylibs/libembree4*"):
        found = sorted(glob.glob(os.path.join(root, pattern)))
        if found:
            return found[0]
    return None


def _open() -> tuple:
    try:
        from aobake import _embree
    except ImportError as exc:  # not built (no C compiler at install, or Windows)
        return None, f"aobake._embree not built ({exc})"
    path = library_path()
    if path is None:
        return None, "embreex's libembree4 not found"
    try:
        version, width = _embree.open(path)
    except (OSError, RuntimeError) as exc:
        return None, str(exc)
    return _embree, version, width


def binding():
    """(module, the widest packet this CPU answers) of the compiled binding, or None where
    embreex traces."""
    global _opened
    if embreex_forced():
        return None
    with _lock:
        if _opened is None:
            _opened = _open()
            if _opened[0] is None:
                log.info("tracing through embreex: %s", _opened[1])
    return None if _opened[0] is None else (_opened[0], _opened[2])


def packet_width(widest: int) -> int:
    """The width the queries use: ``PACKET_WIDTH`` or the widest this CPU answers."""
    return min(PACKET_WIDTH, widest)
