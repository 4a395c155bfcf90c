"""Work that must be isolated runs in a child Python process that imports the same ``aobake``.

Some work can take its process down or hang it: xatlas has been seen to segfault on some
inputs and, once, to deadlock in its thread pool (the unwrap,
``aobake.targets.texels.unwrap``); a driver's OpenGL context is the next such work.  It runs
as a ``Worker``: a function ``module.function(inputs) -> outputs`` (dicts of arrays, passed
through .npz files) called in a child Python with a time limit and retries (``run``), so a
crash, a hang or an exception there becomes a ``ChildError`` here.  A child can be started
ahead (``prestart``) so that its interpreter start and imports overlap the parent's own work.
A child never outlives its parent: it ends itself when the parent is gone (``watch_parent``),
and a prestarted one when its standard input closes.

The same ``aobake``: ``python -c CODE`` puts the current directory first on the child's
``sys.path``, so a child started from a checkout's root imports the checkout's source tree,
not the installed package its parent runs: a tree with no compiled kernels, or another
version of the code (issue 21).  ``python_child`` returns the command and the environment of
a child that imports exactly this process's package.

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

import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

log = logging.getLogger(__name__)

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


# --- isolated work -------------------------------------------------------------------


class Worker(NamedTuple):
    """Work that runs in child processes (made by ``worker``).

    name : what messages call it ("xatlas"; also in the temporary directory's name),
    code : Python source a new child runs, the paths of its inputs and outputs (.npz) as
    ``sys.argv[1:]``, warm : Python source a prestarted child runs: its imports, then it
    waits for those two paths as a JSON list on one line of its standard input (none: it
    was not needed).  A test may swap either for a stand-in (a crash, a hang).
    """

    name: str
    code: str
    warm: str


def worker(name: str, module: str, function: str, warm_up: str = "") -> Worker:
    """The ``Worker`` that calls ``module.function(inputs)`` in a child: inputs and outputs
    are dicts name -> np.ndarray (the outputs anything ``np.savez`` takes).

    The packages above ``module`` are stubs in the child (their ``__path__`` only): their
    ``__init__`` modules import the whole baker (``aobake``'s: 0.2 s of a child's start, on
    the critical path of the work).  ``warm_up``: Python source a prestarted child runs after
    importing ``module``, before it waits (imports the work will need).
    """
    parents = module.split(".")[:-1]
    packages = tuple(".".join(parents[:i + 1]) for i in range(len(parents)))
    head = ("import importlib.util, sys, types\n"
            f"for name in {packages!r}:\n"
            "    stub = types.ModuleType(name)\n"
            "    stub.__path__ = importlib.util.find_spec(name).submodule_search_locations\n"
            "    sys.modules[name] = stub\n"
            "from aobake.child import serve, watch_parent\n"
            "watch_parent()\n"
            f"from {module} import {function} as work\n")
    code = head + "serve(work, sys.argv[1:])\n"
    warm = (head + "import json\n" + warm_up
            + "line = sys.stdin.readline()\nif line:\n    serve(work, json.loads(line))\n")
    return Worker(name, code, warm)


def serve(function, paths) -> None:
    """The child's side of ``run``: ``function`` of the arrays in ``paths[0]`` (.npz), its
    outputs written to ``paths[1]`` (.npz)."""
    _serving[:] = [str(path) for path in paths]
    if _orphaned():  # the parent died before this child read its work
        _abandon()
    with np.load(paths[0]) as data:
        inputs = {key: data[key] for key in data.files}
    np.savez(paths[1], **function(inputs))


#: the environment variable that gives a child its parent's process id (``_command``)
PARENT_VARIABLE = "AOBAKE_CHILD_PARENT"
#: seconds between a child's looks at whether its parent is still there
WATCH_SECONDS = 0.25
#: the paths a child is serving (in a temporary directory its parent made), and the
#: process id of that parent (empty: not watched)
_serving: list = []
_parent: list = []


def watch_parent() -> None:
    """In a child: end this process when the parent that started it is gone (its parent
    process id changes: the child was handed to init or a subreaper).  A parent killed
    outright (a pool worker ended by its pool on an interrupt, the out-of-memory killer)
    cannot end its children, and a child drawing hemicubes would go on for minutes.  The
    temporary directory of the work it serves, which that parent can no longer remove,
    goes with it.  A child still starting is left to find out itself: a prestarted one
    reads the end of its standard input, or its work (``serve`` looks first)."""
    expected = os.environ.get(PARENT_VARIABLE)
    if not expected or not expected.isdigit():
        return
    _parent[:] = [int(expected)]

    def watch():
        while not (_orphaned() and _serving):
            time.sleep(WATCH_SECONDS)
        _abandon()

    threading.Thread(target=watch, name="aobake-watch-parent", daemon=True).start()


def _orphaned() -> bool:
    return bool(_parent) and os.getppid() != _parent[0]


def _abandon() -> None:
    """End this orphaned child, removing its parent's temporary directory of the work."""
    if _serving:
        folder = Path(_serving[0]).parent
        if folder.name.startswith("aobake-"):
            shutil.rmtree(folder, ignore_errors=True)
    os._exit(1)


class ChildError(Exception):
    """A worker's child that delivered nothing: ``TimedOut``, ``Crashed`` or ``Failed``."""


class TimedOut(ChildError):
    """Every attempt outlived the time limit (``limit`` seconds, ``attempts`` times)."""

    def __init__(self, message: str, limit: float, attempts: int):
        super().__init__(message)
        self.limit, self.attempts = limit, attempts


class Crashed(ChildError):
    """The child was ended by a signal: ``how`` it ended ("crashed with SIGSEGV", "was
    killed by signal 64")."""

    def __init__(self, how: str):
        super().__init__(how)
        self.how = how


class Failed(ChildError):
    """The child exited with an error: ``line``, the last line of its standard error (an
    exception's type and message; "exit status N" when it wrote nothing), ``stderr`` all
    of it."""

    def __init__(self, line: str, stderr: str):
        super().__init__(line)
        self.line, self.stderr = line, stderr


def _command(code: str, args=()) -> Child:
    """``python_child`` of a worker's ``code``, with its allocator tuned."""
    argv, env = python_child(code, args)
    env[PARENT_VARIABLE] = str(os.getpid())  # the child ends when this process is gone
    # glibc: reuse freed memory rather than fault fresh pages in (see aobake.cli's
    # _keep_freed_memory): the child's own process, so its allocator is ours to tune
    env.setdefault("MALLOC_MMAP_THRESHOLD_", str(32 << 20))
    env.setdefault("MALLOC_TRIM_THRESHOLD_", str(2**31 - 1))
    return Child(argv, env)


# At most one prestarted child per worker name waits for its work.
_waiting_lock = threading.Lock()
_waiting: dict[str, subprocess.Popen] = {}


def prestart(worker: Worker) -> subprocess.Popen | None:
    """Start a child for ``worker`` now (its interpreter start and imports, ~0.15 s for the
    unwrap's, then overlap whatever the caller does next); the next ``run`` of a worker of
    that name hands it its work.  At most one waits per name; ``discard`` ends it when no
    work comes.  Returns the waiting child (None where it could not start), so that its
    owner can end exactly that one (``discard(worker, proc)``)."""
    with _waiting_lock:
        proc = _waiting.get(worker.name)
        if proc is not None and proc.poll() is None:
            return proc
        _reap(_waiting.pop(worker.name, None))
        try:
            argv, env = _command(worker.warm)
            proc = _waiting[worker.name] = subprocess.Popen(
                argv, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                stderr=subprocess.PIPE, text=True)
        except OSError as exc:  # only a head start: the work starts its own child
            log.debug("could not prestart the %s child: %s", worker.name, exc)
            return None
        return proc


def waiting(worker: Worker) -> subprocess.Popen | None:
    """The prestarted child waiting for ``worker``'s work, if any."""
    with _waiting_lock:
        return _waiting.get(worker.name)


def discard(worker: Worker, proc: subprocess.Popen | None = None) -> None:
    """End a prestarted child of ``worker`` that no work will use: the one waiting, or only
    ``proc`` if that is the one still waiting (not one another caller started since)."""
    with _waiting_lock:
        waiting = _waiting.get(worker.name)
        if waiting is None or (proc is not None and waiting is not proc):
            return
        del _waiting[worker.name]
    _reap(waiting)


def _reap(proc: subprocess.Popen | None) -> None:
    """End ``proc`` (if still running) and close its pipes."""
    if proc is not None:
        if proc.poll() is None:
            proc.kill()
        proc.communicate()


def _take(worker: Worker) -> subprocess.Popen | None:
    with _waiting_lock:
        proc = _waiting.pop(worker.name, None)
    if proc is not None and proc.poll() is not None:  # died while waiting: not usable
        _reap(proc)
        return None
    return proc


def _attempt(worker: Worker, src: Path, dst: Path, limit: float) -> subprocess.CompletedProcess:
    """The work in the prestarted child if there is one, else in a new one (either is killed
    after ``limit`` seconds, subprocess.TimeoutExpired, or on any exception here, such as
    the CLI's SIGTERM).  A prestarted child that fails (killed while it waited, say) hands
    the work to a new one: its failure says nothing about the work."""
    proc = _take(worker)
    if proc is not None:
        try:
            out, err = proc.communicate(json.dumps([str(src), str(dst)]) + "\n", timeout=limit)
        except BaseException:
            _reap(proc)
            raise
        if proc.returncode == 0 and dst.is_file():
            return subprocess.CompletedProcess(proc.args, 0, out, err)
        log.debug("the prestarted %s child failed (exit %s): a new one takes the job",
                  worker.name, proc.returncode)
    argv, env = _command(worker.code, (src, dst))
    return subprocess.run(argv, env=env, capture_output=True, text=True, timeout=limit)


def run(worker: Worker, inputs: dict, limit: float, attempts: int = 2) -> dict:
    """``worker``'s function of ``inputs`` (name -> array, as ``np.savez`` takes them) in a
    child process: the prestarted one if it waits, else a new one.

    A child still running after ``limit`` seconds is killed (a hang cannot be caught any
    other way) and the work tried again, ``attempts`` times in all.  Returns the outputs
    (name -> np.ndarray, read into memory).  Raises ``TimedOut`` (every attempt), ``Crashed``
    (a signal ended the child) or ``Failed`` (it exited with an error).
    """
    with tempfile.TemporaryDirectory(prefix=f"aobake-{worker.name}-") as tmp:
        src, dst = Path(tmp, "in.npz"), Path(tmp, "out.npz")
        np.savez(src, **inputs)
        for attempt in range(1, attempts + 1):
            try:
                proc = _attempt(worker, src, dst, limit)
                break
            except subprocess.TimeoutExpired:
                log.warning("%s did not finish in %.0f s (attempt %d of %d)", worker.name,
                            limit, attempt, attempts)
        else:
            raise TimedOut(f"{worker.name} did not finish in {limit:.0f} s, {attempts} times",
                           limit, attempts)
        if proc.returncode < 0:
            try:
                how = f"crashed with {signal.Signals(-proc.returncode).name}"
            except ValueError:
                how = f"was killed by signal {-proc.returncode}"
            raise Crashed(how)
        if proc.returncode != 0:
            last = proc.stderr.strip().splitlines()[-1:] or [f"exit status {proc.returncode}"]
            raise Failed(last[0], proc.stderr)
        with np.load(dst) as data:
            return {key: data[key] for key in data.files}
