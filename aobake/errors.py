"""Exceptions the library raises for bad input or unwritable output.

The CLI turns every ``AobakeError`` into a one-line message and a non-zero exit
code; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations


class AobakeError(Exception):
    """Base class: a problem the user can fix (bad file, bad option, bad path)."""


class InputError(AobakeError, ValueError):
    """An input file or argument is missing, unreadable or invalid.

    The message names the file (when there is one) and the problem.
    """


class OutputError(AobakeError, OSError):
    """An output cannot be written (unwritable path, would overwrite the input...)."""


class UsageError(InputError):
    """A request whose settings cannot go together (a method the target cannot serve, a
    format that cannot hold what was asked): refused before any work.  The command line
    exits 2 for it, as for any misuse of its options."""
