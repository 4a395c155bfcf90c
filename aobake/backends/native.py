"""Embree queries through ``aobake._embree`` (occlusion in packets), on embreex's libembree4.

:func:`binding` answers once per process whether the compiled module was built and the
Embree library embreex loaded was found and accepted; ``EmbreeBackend`` then traces
through it, else through embreex.  Both give the same occlusion answers (packets answer
each ray alone; tests/test_native_embree.py compares them); the compiled one is faster
(benchmarks/bench_backend.py).  ``aobake._native.embreex_only`` forces embreex on this
thread (tests, benchmarks); the report's ``parameters.embree_binding`` says which ran, and
the packet width the occlusion queries used (:func:`packet_width`: Embree's native width on
this CPU unless ``AOBAKE_PACKET_WIDTH`` says otherwise).
"""

from __future__ import annotations

import glob
import logging
import os
import threading

from aobake._native import embreex_forced

log = logging.getLogger(__name__)

#: the packet width every occlusion query uses, set in this process (None: chosen per CPU
#: by :func:`packet_width`; benchmarks/bench_backend.py --widths sets it)
PACKET_WIDTH: int | None = None
#: the environment variable that sets it from outside (a process's command line, a
#: benchmark's child): 1, 4, 8 or 16
WIDTH_VARIABLE = "AOBAKE_PACKET_WIDTH"
WIDTHS = (1, 4, 8, 16)

_lock = threading.Lock()
_opened: tuple | None = None  # (module, version, widest, native) or (None, reason)


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
        version, widest, native = _embree.open(path)
    except (OSError, RuntimeError) as exc:
        return None, str(exc)
    return _embree, version, widest, native


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


def native_width() -> int | None:
    """The widest packet Embree traces natively on this CPU (16 with AVX-512, 8 with AVX2,
    4 with SSE; Embree's device properties), or None where embreex traces."""
    found = binding()
    return None if found is None else _opened[3]


def packet_width(widest: int) -> tuple:
    """(width, source): the packet width the occlusion queries use, and what chose it.

    ``PACKET_WIDTH`` set in this process, else ``AOBAKE_PACKET_WIDTH`` from the
    environment, else Embree's native width on this CPU (source ``"native"``).

    Why the native width, and not a timing made at first use: on both CPUs measured the
    native width was the fastest or tied (an AVX-512 machine: 16 lanes 1.11x faster than 8
    on the bunny, 1.10x on the ogre; an AVX2 AMD EPYC, whose Embree splits a packet of 16
    into two of 8: 8 lanes 1.39x faster than 16 on the bunny, a tie on the ogre;
    docs/performance.md, "Occlusion in packets").  A width is only a speed choice (every
    width gives the same answers, ray for ray: tests/test_native_embree.py), so a rule
    read from Embree keeps a machine's speed the same from run to run, where a timing
    would depend on the load at the moment it ran (on a shared machine, often), add its
    time to every process, or leave a cache per CPU to go stale when Embree changes.
    ``benchmarks/bench_packet_width.py`` measures the widths on any machine;
    ``AOBAKE_PACKET_WIDTH`` overrides the rule where it is wrong.

    ``widest``: the widest width this Embree answers here (binding()[1]).  Raises
    InputError for a width that is not 1, 4, 8 or 16, or wider than ``widest``."""
    from aobake.errors import InputError

    if PACKET_WIDTH is not None:
        width, source = PACKET_WIDTH, "PACKET_WIDTH"
    elif os.environ.get(WIDTH_VARIABLE, "").strip():
        text = os.environ[WIDTH_VARIABLE].strip()
        if not text.isdigit() or int(text) not in WIDTHS:
            raise InputError(f"{WIDTH_VARIABLE}={text!r}: must be 1, 4, 8 or 16")
        width, source = int(text), WIDTH_VARIABLE
    else:
        return min(native_width() or widest, widest), "native"
    if width not in WIDTHS or width > widest:
        raise InputError(f"{source}={width}: must be 1, 4, 8 or 16, at most {widest} here")
    return width, source
