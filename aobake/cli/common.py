"""What every command of the CLI shares: the error, signal and exit-code contract
(``guarded``), warnings routed to one line, and the allocator setting of the process.
A leaf of the CLI: every command imports it, and it imports no command."""

from __future__ import annotations

import logging
import sys

import click

from aobake.cli.signals import Terminated, catch_signals, interrupted, restore_signals
from aobake.errors import AobakeError, UsageError

__all__ = ["Command", "Terminated", "catch_signals", "guarded", "keep_freed_memory",
           "restore_signals", "route_python_warnings"]


class Command(click.Command):
    """A click command whose own usage errors (an unknown option, a missing value, a bad
    choice) keep the contract every other error keeps: one line ``aobake: error: ...`` on
    stderr, then how to get help, status 2, where click would print its usage block and an
    ``Error:`` line a pipeline's log filter for ``aobake: error:`` would miss."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True,
             **extra):
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode, **extra)
        try:
            code = super().main(args, prog_name, complete_var, False, **extra)
        except click.ClickException as exc:  # usage errors (2), file errors (1)
            path = getattr(getattr(exc, "ctx", None), "command_path", None) or prog_name
            click.echo(f"aobake: error: {exc.format_message()}", err=True)
            if isinstance(exc, click.UsageError):
                click.echo(f"Try '{path or 'aobake'} --help' for help.", err=True)
            sys.exit(exc.exit_code)
        except click.Abort as exc:
            # click turns a SIGINT while it parses into Abort: the signal's contract (130)
            cause = exc.__cause__ or exc.__context__
            if isinstance(cause, KeyboardInterrupt):
                raise cause from None
            click.echo("aobake: error: aborted (end of input)", err=True)
            sys.exit(1)
        # as click's standalone mode: the process ends here (--help and ctx.exit(n) give
        # their status; a command that returned gives 0)
        sys.exit(code if isinstance(code, int) else 0)


#: glibc mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
#: the largest mmap threshold glibc accepts on 64-bit systems (DEFAULT_MMAP_THRESHOLD_MAX)
_MMAP_THRESHOLD_MAX = 32 << 20


def keep_freed_memory() -> None:
    """Let this process reuse the memory it frees instead of handing it back to the system.

    By default glibc gives freed blocks above an adaptive threshold back to the system and
    the next array of that size takes fresh pages, each zeroed by the kernel on its first
    touch; a lightmap bake allocates and frees arrays of tens of MB in every phase.  With
    the threshold fixed at its largest value and no trimming, freed blocks below it are
    reused: the bunny's 1024^2 lightmap bake takes 80k page faults instead of 143k and
    0.2-0.3 s less system time (2 ms per MB first touched on this machine's virtual
    memory).  The CLI process only: the library leaves its host's allocator alone.
    Elsewhere (not glibc) this does nothing.
    """
    import ctypes

    try:
        libc = ctypes.CDLL(None)  # this process's symbols (find_library would run ldconfig)
        if not hasattr(libc, "gnu_get_libc_version") or not hasattr(libc, "mallopt"):
            return
        libc.mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_MAX)
        libc.mallopt(_M_TRIM_THRESHOLD, ctypes.c_int(2**31 - 1))
    except (OSError, AttributeError):  # pragma: no cover - no C library to tune
        pass


def guarded(quiet: bool, function, *args) -> None:
    """Run a bake command's work under the CLI's contract: library errors as one line and
    exit 1, SIGINT 130, SIGTERM/SIGHUP 128 + the signal (outputs are one transaction: an
    interrupted bake leaves no file)."""
    handler = _LineHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("aobake: warning: %(message)s"))
    logging.basicConfig(level=logging.ERROR if quiet else logging.WARNING, handlers=[handler])
    route_python_warnings(quiet)
    keep_freed_memory()
    previous = catch_signals()
    try:
        function(*args)
    except UsageError as exc:  # settings that cannot go together: misuse, as click's own
        click.echo(f"aobake: error: {exc}", err=True)
        sys.exit(2)
    except (AobakeError, ValueError) as exc:
        click.echo(f"aobake: error: {exc}", err=True)
        sys.exit(1)
    except (KeyboardInterrupt, Terminated) as exc:
        # the output transaction has removed its temporary files on the way here
        sys.exit(interrupted(exc))
    finally:
        restore_signals(previous)


class _LineHandler(logging.StreamHandler):
    """Each record on a line of its own: on a terminal the progress line ("aobake: loading
    ...", written without a newline so that the next stage replaces it) is cleared first,
    so a warning never shares its line."""

    def emit(self, record) -> None:
        stream = self.stream
        try:
            if stream is not None and stream.isatty():
                stream.write("\r\033[K")
        except (AttributeError, ValueError, OSError):  # a closed or odd stream: write as is
            pass
        super().emit(record)


def route_python_warnings(quiet: bool) -> None:
    """A Python or numpy warning that escapes the library reaches the user as one
    ``aobake: warning:`` line (never a source line and a stack position)."""
    import warnings

    def show(message, category, filename, lineno, file=None, line=None):
        if not quiet:
            click.echo(f"aobake: warning: {category.__name__}: {message}", err=True)

    warnings.showwarning = show
