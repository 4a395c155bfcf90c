"""Atomic file output: write to a temporary file beside the target, then rename; and
transactions, in which several outputs appear together or not at all.

A crash or an exception half-way through a write leaves no partial file behind,
and an existing file at the target is replaced in one step (``os.replace``).
Inside :func:`transaction`, renames wait until every output of the block was
written; on any failure (an exception, a signal turned into one) every temporary
file is removed and no output of the block appears.

Temporary files are named ``.<name>.aobake-unfinished-<random><suffix>``: a person who
finds one left by a killed process can tell what it is and that it may be deleted.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import threading
from pathlib import Path
from typing import Iterator

from aobake.errors import OutputError

_state = threading.local()
# Read once, at import (single-threaded): os.umask can only be read by setting it, which
# is process-wide and would race with files other threads create.
_UMASK = os.umask(0)
os.umask(_UMASK)


def _mode(tmp: Path) -> None:
    # mkstemp makes the file 0600; give the output the mode a plain open() would.
    os.chmod(tmp, 0o666 & ~_UMASK)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path to write to; rename it onto ``path`` on success (at the end of
    the enclosing :func:`transaction`, if there is one).

    The temporary file lives in the same directory (so the rename is atomic on
    one filesystem) and keeps the target's suffix (so writers that choose a
    format by extension, such as OpenImageIO, still work).  On any exception the
    temporary file is removed and the exception propagates.
    """
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise OutputError(f"{path}: output directory {directory} does not exist")
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.aobake-unfinished-",
                                        suffix=path.suffix, dir=directory)
    except OSError as exc:
        raise OutputError(f"{path}: cannot write to {directory} ({exc.strerror})") from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        _mode(tmp)
        pending = getattr(_state, "pending", None)
        if pending is None:
            os.replace(tmp, path)
        else:
            pending.append((tmp, path))
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


@contextlib.contextmanager
def transaction() -> Iterator[None]:
    """Outputs written with :func:`atomic_path` inside the block appear together at its end,
    or (on any exception) not at all."""
    if getattr(_state, "pending", None) is not None:  # nested: the outer one commits
        yield
        return
    _state.pending = []
    try:
        yield
        _commit(_state.pending)
    except BaseException:
        for tmp, _ in _state.pending:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
        raise
    finally:
        _state.pending = None


def _commit(pending: list) -> None:
    """Rename every temporary file onto its output; if one rename fails, undo the ones done
    (files they replaced are restored from a backup) and raise OutputError naming the output."""
    done = []  # (path, backup or None)
    try:
        for tmp, path in pending:
            backup = None
            if path.exists():
                backup = path.with_name(f".{path.name}.aobake-backup-{os.getpid()}")
                os.replace(path, backup)
            done.append((path, backup))
            try:
                os.replace(tmp, path)
            except OSError as exc:
                raise OutputError(f"{path}: {(exc.strerror or str(exc)).lower()}") from None
    except BaseException:
        for path, backup in reversed(done):
            with contextlib.suppress(OSError):
                if backup is not None:
                    os.replace(backup, path)
                else:
                    path.unlink()
        raise
    for _, backup in done:
        if backup is not None:
            with contextlib.suppress(OSError):
                backup.unlink()


@contextlib.contextmanager
def outside_transaction() -> Iterator[None]:
    """Writes in the block rename at once (scratch files that are read back, not outputs)."""
    pending = getattr(_state, "pending", None)
    _state.pending = None
    try:
        yield
    finally:
        _state.pending = pending
