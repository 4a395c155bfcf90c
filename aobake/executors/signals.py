"""Interrupts while worker processes start or stop: held until they have, then delivered.

A pool or cluster interrupted half-started or half-closed leaves worker processes behind,
or workers reading a job the parent stopped writing (an ``UnpicklingError`` traceback from
each) and semaphores nobody unlinks ("leaked semaphore objects").  So the parent holds
SIGINT, SIGTERM and SIGHUP while it starts or stops its workers (:func:`held`) and
delivers the first that came afterwards, to the handlers it had (the CLI's: exit 130 or
143 with one line).

The workers themselves leave interrupts to the parent: a terminal's Ctrl-C reaches every
process of its group, and each worker would print its own ``KeyboardInterrupt``
traceback.  A process started inside ``held(children=True)`` inherits the signals blocked
(the mask survives fork and exec; a Python handler would not), so nothing can interrupt
its start; it calls :func:`worker_ready` when it is ready: SIGINT ignored, the others
unblocked (the parent ends its workers with SIGTERM).
"""

from __future__ import annotations

import contextlib
import signal
import threading

#: the signals a CLI turns into exceptions (SIGINT: KeyboardInterrupt; SIGTERM, SIGHUP)
SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP")
                if hasattr(signal, name))


@contextlib.contextmanager
def held(children: bool = False):
    """Hold SIGINT, SIGTERM and SIGHUP while the block runs, then deliver the first that
    came (to the handlers the process had; Python handles signals in the main thread
    only, elsewhere the block runs as it is).  children : also block them in this
    thread's signal mask, which the processes the block starts inherit (see the module's
    docstring); a signal that arrives meanwhile waits in the kernel or is caught here."""
    main = threading.current_thread() is threading.main_thread()
    caught: list = []

    def hold(signum, frame):
        caught.append(signum)

    previous = {}
    mask = None
    try:
        if main:
            for signum in SIGNALS:
                previous[signum] = signal.signal(signum, hold)
        if children and hasattr(signal, "pthread_sigmask"):
            mask = signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        if mask is not None:  # one that waited in the kernel is delivered now
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        if caught:
            signal.raise_signal(caught[0])


def worker_ready() -> None:
    """In a worker started inside ``held(children=True)``: SIGINT ignored from now on (an
    interrupt is its parent's to handle; a Ctrl-C that came while it started is
    discarded), SIGTERM and SIGHUP unblocked, with their default action (the process
    ends)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, SIGNALS)
