"""Signals under the command line's contract: SIGINT exits 130, SIGTERM 143 and SIGHUP 129,
each with one line and no traceback, and the outputs' transaction removes its temporary
files on the way out (the signal unwinds the stack like KeyboardInterrupt).

Imports only the standard library's ``signal``: :func:`aobake.cli.entry` installs these
handlers before anything else is imported.
"""

from __future__ import annotations

import signal
import sys
import threading


class Terminated(BaseException):
    """SIGTERM or SIGHUP arrived: unwinds like KeyboardInterrupt (so every temporary file
    is removed) and exits 128 + the signal number (143 for SIGTERM)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum, self.name = signum, signal.Signals(signum).name


def _raise(signum, frame):
    raise Terminated(signum)


def catch_signals() -> dict:
    """SIGTERM and SIGHUP handled like SIGINT (only in the main thread, where Python can);
    returns the previous handlers for :func:`restore_signals`."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    previous = {}
    for name in ("SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signum = getattr(signal, name)
            previous[signum] = signal.signal(signum, _raise)
    return previous


def restore_signals(previous: dict) -> None:
    for signum, handler in previous.items():
        signal.signal(signum, handler)


def interrupted(exc: BaseException) -> int:
    """Say that ``exc`` (KeyboardInterrupt or :class:`Terminated`) stopped the command, and
    return its exit status."""
    if isinstance(exc, Terminated):
        sys.stderr.write(f"aobake: error: terminated ({exc.name}): no output written\n")
        return 128 + exc.signum
    sys.stderr.write("aobake: error: interrupted (SIGINT): no output written\n")
    return 130
