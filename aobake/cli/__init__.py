"""The command line: one module per command, over the library.

``aobake MESH --out OUT`` (:mod:`aobake.cli.bake`), ``aobake view`` (:mod:`.view`),
``aobake batch`` (:mod:`.batch`), ``aobake refit`` (:mod:`.refit`) and ``aobake compare``
(``aobake.compare``'s command); :mod:`.options` makes every command's options and its
grouped help from the settings and the registries; :mod:`.common` holds the error, signal
and exit-code contract every command shares.

This package's own module imports nothing heavy: :func:`entry` catches SIGINT, SIGTERM and
SIGHUP *before* it imports click, numpy or the library, so a signal while the command
starts ends it with the contract's message and status (130, 143, 129), never a traceback.
"""

from __future__ import annotations

import os
import sys


def entry() -> None:
    """The process entry of the ``aobake`` command, ``python -m aobake`` and ``cli.py``:
    ``main`` and its exit status, then the process ends without the interpreter's teardown.

    Once the outputs are closed and renamed, the teardown only frees what the bake held
    (every array one by one, the modules' objects) for memory the system takes back anyway:
    0.18 s after a 1024^2 lightmap of the bunny.  The streams and logging are flushed first;
    the library, and ``main`` run inside another program (click's test runner), end as
    usual.
    """
    code = 0
    try:  # first: a SIGINT from here on is this command's, never a traceback
        from aobake.cli.signals import catch_signals

        catch_signals()  # from here on SIGTERM/SIGHUP unwind like SIGINT's KeyboardInterrupt
        from aobake.cli.bake import main

        main()  # click's standalone mode ends with SystemExit, 0 included
    except SystemExit as exc:
        code = exc.code
    except BaseException as exc:  # noqa: BLE001 - a signal while importing or parsing
        from aobake.cli.signals import Terminated, interrupted

        if not isinstance(exc, (KeyboardInterrupt, Terminated)):
            raise
        code = interrupted(exc)
    if code is None:
        code = 0
    elif not isinstance(code, int):  # sys.exit("message"): the message, status 1
        sys.stderr.write(f"{code}\n")
        code = 1
    if "logging" in sys.modules:
        sys.modules["logging"].shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            if stream is not None:  # None: no console (pythonw, a detached process)
                stream.flush()
        except Exception:  # noqa: BLE001 - a closed or broken pipe: nothing more to say
            pass
    # atexit hooks do not run (the CLI registers none; a coverage tool's would be skipped).
    os._exit(code)


def __getattr__(name: str):
    # ``from aobake.cli import main`` (tests, embedding programs) without this module
    # importing click at its top
    if name in ("main", "SUBCOMMANDS"):
        from aobake.cli import bake as module

        return getattr(module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
