"""The ``dask`` executor: a bake's points estimated on a Dask cluster (``--executor dask``).

Where: an existing cluster (``scheduler="tls://host:8786"``, reached with Dask's security
settings: docs/scale.md), the session a caller opened (:func:`cluster`, which ``aobake
batch`` opens once for all its assets), or a ``LocalCluster`` started for this bake: one
worker process per core, one thread each, listening on 127.0.0.1 only, no dashboard, its
connections mutual TLS with throw-away credentials when ``cryptography`` is installed.  A
named scheduler is checked before any work (:func:`probe`: its Dask handshake, read with a
plain socket within ``CONNECT_SECONDS``): another service at the address, or a port that
accepts and stays silent, is an InputError saying what answered, not a 3 EiB allocation
or a wait without end; a client that fails to start is closed at once (not at the
interpreter's exit).

How: the job (scene, configuration, method name; ``executors.base.Job``) is scattered once
and replicated to every worker (worker to worker, a tree: the client uploads it once);
each worker builds the occluders and the method once per job and keeps them
(``executors.worker``, an importable module: Dask ships ``__main__``'s functions by value,
a module's by name) for all the job's work items (point ranges).  Items are sized by a
cost model: the first points are estimated here, on one thread, until about
``PILOT_SECONDS`` have passed (those estimates are kept), which gives the seconds per point;
what is left is finished here when it is less than ``MIN_ITEM_SECONDS`` of this process's
threads (shipping the scene would cost more), else cut into items of about
``ITEM_SECONDS`` of a worker's tracing (never under ``MIN_ITEM_SECONDS``, at least
``ITEMS_PER_WORKER`` items per worker when there is that much work); with
``chunk_points``, into items of that many points (no pilot, no shortcut).  Results are
gathered as they finish (a finished item lives in this process, so a worker lost later
loses nothing of it) and merged by point index: every worker count and split gives the
same bits as the local bake.

Faults: a worker that dies mid-item (killed, out of memory, a crash in native code) has
its item re-run on another worker by the scheduler; an item that has been running on
``ALLOWED_FAILURES + 1`` workers when they died is declared poisonous (Dask's
``KilledWorker``) and the bake fails with :class:`ClusterError`: bounded time, a clear
message, never a hang.  ``ALLOWED_FAILURES`` is set as
``distributed.scheduler.allowed-failures`` on the LocalCluster this module starts; a remote
scheduler keeps its own setting (Dask's default is 3).  An exception raised by an item is
not retried (``retries=0``): every item is a pure function of its inputs, so it would
raise again.  If every worker holding the scattered job dies, the job is scattered again
and the unfinished items resubmitted, at most ``MAX_RESHIPS`` times.  An interrupt
(Ctrl-C) cancels the items and closes the cluster this module started.
"""

from __future__ import annotations

import collections
import contextlib
import contextvars
import logging
import math
import struct
import threading
import time
import uuid
from dataclasses import replace

import numpy as np

from aobake.errors import AobakeError, InputError
from aobake.executors import worker
from aobake.executors.base import merged, release, whole as whole_item

log = logging.getLogger(__name__)

#: seconds of one worker's tracing a work item carries (a task's round trip costs 6-11 ms
#: over TCP, 10-25 ms over TLS on loopback: about 1-2% of it)
ITEM_SECONDS = 1.0
#: the least tracing an item carries when the work is split finer for balance
MIN_ITEM_SECONDS = 0.5
#: the most points an item carries (the cost model's items of ITEM_SECONDS hold ~1M points
#: at 4 rays a point): what the items in flight hold in the parent (their points sent, their
#: results back, ~100 bytes a point) stays bounded whatever the rays; 131,072 points of 64
#: rays are 1-3 s of one thread's tracing, of 4 rays ~0.1 s (then the round trip, 10-25 ms,
#: is 10-20% of an item: few rays a point are cheap to trace anyway)
MAX_ITEM_POINTS = 1 << 17
#: items per worker when the work allows (a slow item does not leave the others idle)
ITEMS_PER_WORKER = 2
#: the parent's pilot: point-rays of its first block, and how long it traces (its
#: estimates are kept); blocks grow 4x until this much time has passed
PILOT_RAYS = 1 << 15
PILOT_SECONDS = 0.05
#: worker deaths an item may survive (distributed.scheduler.allowed-failures of the
#: LocalCluster started here): its third death fails the bake
ALLOWED_FAILURES = 2
#: re-runs of an item that raised (deterministic: it would raise again)
RETRIES = 0
#: items in flight per worker (submitted, not yet gathered): each item is cut when submitted
#: and its rows land in the result as it is gathered, so the parent (and a LocalCluster's
#: scheduler, which runs in it) holds this many items' points and results, not every item's
IN_FLIGHT_PER_WORKER = 2
#: times the job is scattered again after every worker holding it died
MAX_RESHIPS = 2
#: seconds a named scheduler has to answer: the probe's connection (retried while it is
#: refused, as Dask retries a scheduler still starting) and Dask's handshake, then the
#: client's own connection.  A scheduler writes its handshake as it accepts (milliseconds);
#: what is still silent after this long is not one.
CONNECT_SECONDS = 10.0
#: seconds to wait for a named scheduler's first workers
WAIT_WORKERS_SECONDS = 60.0
#: the most bytes a Dask handshake may announce (one is ~60: three msgpack fields); a
#: larger length prefix is another protocol's bytes read as a frame length
HANDSHAKE_BYTES = 1 << 16
#: seconds a failed client has to close (it holds no work)
CLOSE_SECONDS = 5.0
#: the length prefixes of Dask's TCP frames (``distributed.comm.tcp``: native uint64)
_LENGTH = struct.Struct("Q")
#: fields of a WorkItem holding one row per point (cut with the items; the rest is whole)
_PER_POINT = ("points", "normals", "ids", "sizes", "faces", "bary")


class ClusterError(AobakeError):
    """The cluster could not finish a bake: an item killed every worker it ran on, the
    scheduler could not be reached or had no workers, or the job's data was lost."""


def require():
    """The ``distributed`` module; InputError saying what to install where it is missing."""
    try:
        import distributed
    except ImportError:
        raise InputError("--executor dask needs Dask: pip install 'aobake[dask]' (or "
                         "'dask[distributed]')") from None
    return distributed


def _security(scheduler: str, security=None):
    """The ``distributed.Security`` a client of ``scheduler`` uses (default: Dask's
    configuration); ClusterError for a ``tls://`` address it has no client credentials for."""
    from distributed import Security

    security = security or Security()  # Dask's configuration
    if str(scheduler).startswith("tls://") and \
            security.get_connection_args("client").get("ssl_context") is None:
        raise ClusterError(
            f"cannot reach the Dask scheduler at {scheduler}: it speaks TLS and Dask's "
            "configuration has no credentials for a client (distributed.comm.tls.ca-file, "
            ".client.cert, .client.key; docs/scale.md)")
    return security


def probe(address: str, security=None, timeout: float | None = None) -> dict:
    """The handshake the Dask comm at ``address`` sends as it accepts a connection (a dict:
    ``compression``, ``python``, ``pickle-protocol``), read within ``timeout`` seconds
    (default CONNECT_SECONDS) with a plain socket, before ``distributed.Client`` is let near
    the address.  Client reads the first 8 bytes of any reply as a frame length (an HTTP
    server's ``HTTP/1.1`` is 3.07 EiB: MemoryError) and waits for a silent peer's handshake
    with no time limit.

    As Dask's ``connect``, the probe writes its own handshake first (so an HTTP server
    answers at once), then reads one frame: an 8-byte length of at most HANDSHAKE_BYTES,
    the frame count and lengths, a msgpack map with a ``python`` entry.  Raises InputError
    ("no Dask scheduler answered at ADDRESS (got ...)") for silence, a closed connection or
    another protocol's bytes; ClusterError where nothing accepts the connection within the
    time (a refusal is retried, as Dask retries a scheduler that is still starting), or a
    ``tls://`` address has no client credentials.  Addresses of Dask's other comms
    (inproc, ucx, ws) are not probed: {}.
    """
    import socket
    import ssl

    from distributed.comm.addressing import parse_address, parse_host_port

    timeout = CONNECT_SECONDS if timeout is None else float(timeout)
    try:
        scheme, location = parse_address(str(address), strict=False)
        host, port = parse_host_port(location)
    except (ValueError, TypeError) as exc:
        raise InputError(f"scheduler {address!r} is not a Dask address ({exc}): give "
                         "tcp://HOST:PORT or tls://HOST:PORT") from None
    if scheme not in ("tcp", "tls"):
        return {}
    context = None
    if scheme == "tls":
        context = _security(address, security).get_connection_args("client")["ssl_context"]
    deadline = time.monotonic() + timeout

    def refuse(got: str):
        return InputError(f"no Dask scheduler answered at {address} (got {got})")

    sock = _dial(address, host, port, deadline, timeout)
    try:
        if context is not None:
            try:
                sock.settimeout(max(1e-3, deadline - time.monotonic()))
                sock = context.wrap_socket(
                    sock, server_hostname=host if context.check_hostname else None)
            except socket.timeout:
                raise refuse(f"no TLS handshake in {timeout:g} s") from None
            except (ssl.SSLError, OSError) as exc:
                raise refuse(f"a failed TLS handshake: {_reason(exc)}") from None
        with contextlib.suppress(OSError):  # a peer that closed at once says so when read
            sock.settimeout(max(1e-3, deadline - time.monotonic()))
            sock.sendall(_handshake_frame())
        head, end = _receive(sock, 8, deadline)
        if len(head) < 8:
            hint = " (a TLS scheduler? its address starts tls://)" if scheme == "tcp" else ""
            said = f"{_preview(head)}, then " if head else ""
            raise refuse(f"{said}nothing in {timeout:g} s" if end == "silent" else
                         f"{said}a closed connection{hint}")
        (size,) = _LENGTH.unpack(head)
        if not 2 * _LENGTH.size <= size <= HANDSHAKE_BYTES:
            more, _ = _receive(sock, 64, min(deadline, time.monotonic() + 0.2), some=True)
            raise refuse(f"{_preview(head + more)}, not a Dask handshake ({size} bytes "
                         "announced)")
        body, end = _receive(sock, size, deadline)
        if len(body) < size:
            raise refuse(f"{_preview(head + body)}, then "
                         + (f"nothing in {timeout:g} s" if end == "silent" else
                            "a closed connection") + f" ({len(body)} of {size} bytes)")
        message = _handshake(body)
        if message is None:
            raise refuse(f"{_preview(head + body)}, not a Dask handshake")
        return message
    finally:
        with contextlib.suppress(OSError):
            sock.close()


def _dial(address: str, host: str, port: int, deadline: float, timeout: float):
    """A TCP connection to host:port, retried while refused until ``deadline``."""
    import socket

    pause, last = 0.01, None
    while (left := deadline - time.monotonic()) > 0:
        try:
            return socket.create_connection((host, port), timeout=left)
        except socket.gaierror as exc:
            raise ClusterError(f"cannot reach the Dask scheduler at {address}: unknown host "
                               f"{host!r} ({_reason(exc)})") from None
        except OSError as exc:
            last = exc
            time.sleep(max(0.0, min(pause, deadline - time.monotonic())))
            pause = min(2 * pause, 0.5)
    raise ClusterError(f"cannot reach the Dask scheduler at {address}: "
                       f"{_reason(last) if last else 'no connection'} (tried for {timeout:g} s)")


def _receive(sock, n: int, deadline: float, some: bool = False) -> tuple:
    """(bytes, how it ended): ``n`` bytes from ``sock`` by ``deadline`` ("done"), or fewer
    when the peer closed ("closed") or stayed silent ("silent"); ``some``: the first
    chunk that arrives before ``deadline`` (at most ``n`` bytes, maybe none)."""
    import socket

    data = b""
    while len(data) < n:
        left = deadline - time.monotonic()
        if left <= 0:
            return data, ("done" if some else "silent")
        try:
            sock.settimeout(left)
            chunk = sock.recv(n - len(data))
        except socket.timeout:
            return data, ("done" if some else "silent")
        except OSError:
            return data, "closed"
        if not chunk:
            return data, "closed"
        data += chunk
        if some:
            break
    return data, "done"


def _handshake_frame() -> bytes:
    """This side's Dask handshake as ``distributed.comm.tcp`` frames it: the length of
    what follows, the frame count (1), the frame's length, the msgpack map.  Its extra
    entry ends in a blank line (a Dask peer ignores entries it does not read): an HTTP
    server, which waits for the end of a request's head, answers at once."""
    import pickle
    import sys

    import msgpack

    body = msgpack.dumps({"compression": None, "python": tuple(sys.version_info)[:3],
                          "pickle-protocol": pickle.HIGHEST_PROTOCOL,
                          "aobake-probe": "\r\n\r\n"}, use_bin_type=True)
    return (_LENGTH.pack(2 * _LENGTH.size + len(body)) + _LENGTH.pack(1)
            + _LENGTH.pack(len(body)) + body)


def _handshake(body: bytes) -> dict | None:
    """The handshake in a frame's bytes (after its length): the frame count, the frames'
    lengths, the first frame a msgpack map with a ``python`` entry; None if it is not one."""
    import msgpack

    try:
        (count,) = _LENGTH.unpack_from(body)
        if not 1 <= count <= (len(body) - _LENGTH.size) // _LENGTH.size:
            return None
        first = _LENGTH.unpack_from(body, _LENGTH.size)[0]
        start = _LENGTH.size * (1 + count)
        if start + first > len(body):
            return None
        message = msgpack.loads(body[start:start + first], raw=False)
    except Exception:  # noqa: BLE001 - any bytes at all may arrive here
        return None
    return message if isinstance(message, dict) and "python" in message else None


def _preview(data: bytes) -> str:
    """What a reply began with, for a message: an HTTP status line, printable text, or
    the first bytes in hex."""
    if data.startswith(b"HTTP/"):
        line = data.split(b"\r\n", 1)[0].split(b"\n", 1)[0][:60]
        return f"an HTTP reply, {line.decode('latin-1')!r}"
    text = data[:40]
    if text and all(32 <= b < 127 or b in (9, 10, 13) for b in text):
        return f"the text {text.decode('ascii')!r}"
    return f"the bytes {text[:16].hex(' ')}" + (" ..." if len(data) > 16 else "")


def _reason(exc: BaseException) -> str:
    """An exception's words (its strerror where an OSError has one), or its type's name."""
    words = getattr(exc, "strerror", None) or getattr(exc, "reason", None) or str(exc)
    return str(words) if str(words) else type(exc).__name__


def _close_failed(client) -> None:
    """Close a client whose start or first wait failed, within CLOSE_SECONDS.  A client
    that will not close is marked closed: its ``__del__`` at the interpreter's exit would
    wait 60 s for an event loop that no longer runs, then print a traceback."""
    with contextlib.suppress(Exception):
        client.close(timeout=CLOSE_SECONDS)
    if getattr(client, "status", "closed") != "closed":
        with contextlib.suppress(Exception):
            client.status = "closed"


class Session:
    """A Dask cluster that bakes go through, connected (or started) when a bake first needs
    it: a batch of assets the parent finishes alone never starts one.

    scheduler : an existing scheduler's address, or None for a LocalCluster of ``workers``
    processes (default one per core); with a scheduler, ``workers`` is how many to wait
    for (default 1); security : ``distributed.Security`` for a remote scheduler (default:
    Dask's configuration).  Once open: ``client``, ``cluster`` (the LocalCluster started
    here, or None), ``address``, ``tls`` (whether its connections are TLS).  ``stats``: one
    dict per bake estimated on the cluster (points, items, the split, seconds of the pilot,
    of the workers' tracing and preparing, wall time: what ``benchmarks/bench_scale.py``
    reports).
    """

    def __init__(self, scheduler: str | None = None, workers: int | None = None,
                 security=None):
        self.scheduler, self.n_workers, self.security = scheduler, workers, security
        self.cluster = self._client = self.address = self.tls = None
        self.stats: list = []
        self._loggers: list = []  # (logger, level) to restore when the session closes
        self._checked = False  # the named scheduler answered the probe

    def check(self) -> None:
        """A named scheduler answers Dask's handshake within CONNECT_SECONDS (:func:`probe`;
        once per session, before anything is sent to it); nothing to check for a
        LocalCluster."""
        if self.scheduler and not self._checked:
            probe(self.scheduler, self.security)
            self._checked = True

    @property
    def opened(self) -> bool:
        return self._client is not None

    @property
    def client(self):
        """The ``distributed.Client`` (connecting, or starting the cluster, now if needed)."""
        if self._client is None:
            self._open()
        return self._client

    def workers(self) -> dict:
        """worker address -> its threads, now."""
        return dict(self.client.nthreads())

    def _open(self) -> None:
        distributed = require()
        # a remote cluster's warnings stay (its workers are someone's to look after); a
        # local one is this module's to report: all of it, as its scheduler logs at
        # CRITICAL, with a traceback, a finished item it can no longer tell a client an
        # interrupt closed
        self._loggers = _quiet(logging.WARNING if self.scheduler else logging.CRITICAL + 1)
        try:
            if self.scheduler:
                self._connect(distributed)
            else:
                self._start(distributed)
        except BaseException:
            self._restore_loggers()
            raise

    def _connect(self, distributed) -> None:
        """Connect to the scheduler (checked first: :meth:`check`), and wait for its first
        workers."""
        scheduler, wanted = self.scheduler, self.n_workers or 1
        security = _security(scheduler, self.security)
        self.check()
        # Made in two steps so that a client whose start fails is still in hand to close
        # here: left to Client.__del__, it is closed at the interpreter's exit, when its
        # event loop's thread no longer runs (60 s of waiting, then a traceback).
        client = distributed.Client.__new__(distributed.Client)
        try:
            client.__init__(scheduler, security=security, timeout=CONNECT_SECONDS,
                            set_as_default=False)
        except Exception as exc:  # noqa: BLE001 - whatever Dask raised, the client is closed
            _close_failed(client)
            raise ClusterError(f"cannot reach the Dask scheduler at {scheduler}: "
                               f"{_reason(exc)}") from None
        except BaseException:
            _close_failed(client)
            raise
        try:
            client.wait_for_workers(wanted, timeout=WAIT_WORKERS_SECONDS)
        except (OSError, TimeoutError) as exc:
            _close_failed(client)
            raise ClusterError(f"the Dask scheduler at {scheduler} has fewer than {wanted} "
                                  f"workers after {WAIT_WORKERS_SECONDS:g} s ({exc})") from None
        except BaseException:
            _close_failed(client)
            raise
        self._client, self.address = client, str(scheduler)
        self.tls = self.address.startswith("tls://")

    def _start(self, distributed) -> None:
        """A LocalCluster: one single-threaded worker process per core (or ``workers``),
        on 127.0.0.1, no dashboard, ALLOWED_FAILURES, TLS where it can."""
        import dask

        from aobake.executors.local import default_workers

        security, self.tls = local_security()
        try:
            # an interrupt during the start waits for it to end, then closes it below
            with _signals_deferred(), dask.config.set(
                    {"distributed.scheduler.allowed-failures": ALLOWED_FAILURES}):
                self.cluster = distributed.LocalCluster(
                    n_workers=self.n_workers or default_workers(), threads_per_worker=1,
                    processes=True, host="127.0.0.1", security=security,
                    dashboard_address=None,
                    # no dashboard; the scheduler's HTTP endpoints (health) on a free
                    # loopback port instead of 8787
                    scheduler_kwargs={"dashboard": False,
                                      "dashboard_address": "127.0.0.1:0"},
                    silence_logs=logging.CRITICAL)  # the workers' own logs
                self._client = distributed.Client(self.cluster, security=security,
                                                  set_as_default=False)
                # A terminal's Ctrl-C reaches every process of its group: the workers leave
                # it to this process, which cancels the items and closes the cluster (each
                # worker would print its own KeyboardInterrupt traceback otherwise).
                self._client.register_plugin(_IgnoreInterrupts())
        except BaseException:
            self._shut()
            raise
        self.address = self.cluster.scheduler_address

    def close(self) -> None:
        """Close the client, and the cluster if this session started it (its worker
        processes are ended: an interrupt arriving meanwhile waits until they are)."""
        try:
            self._shut()
        finally:
            self._restore_loggers()

    def _shut(self) -> None:
        with _signals_deferred():
            try:
                if self._client is not None:
                    self._client.close(timeout=10)
            finally:
                if self.cluster is not None:
                    self.cluster.close(timeout=10)
        self._client = self.cluster = None

    def _restore_loggers(self) -> None:
        for logger, level in self._loggers:
            logger.setLevel(level)
        self._loggers = []


#: the signals a CLI turns into exceptions (SIGINT: KeyboardInterrupt; SIGTERM, SIGHUP)
_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")


@contextlib.contextmanager
def _signals_deferred():
    """Hold SIGINT, SIGTERM and SIGHUP while the block runs, then deliver the first that came
    (to the handlers the process had): a cluster interrupted half-started or half-closed
    would leave worker processes behind.  Only in the main thread (where Python can)."""
    import signal

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []

    def hold(signum, frame):
        caught.append(signum)

    previous = {}
    for name in _SIGNALS:
        if hasattr(signal, name):
            signum = getattr(signal, name)
            previous[signum] = signal.signal(signum, hold)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        if caught:
            signal.raise_signal(caught[0])


_ACTIVE: contextvars.ContextVar = contextvars.ContextVar("aobake_dask_session", default=None)


def cluster(scheduler: str | None = None, workers: int | None = None, security=None):
    """A :class:`Session` every ``--executor dask`` bake inside the block runs on (opened
    by the first bake that needs it, closed at the end of the block).

    scheduler : address of an existing scheduler (``tcp://`` or ``tls://host:port``), or
    None to start a LocalCluster of ``workers`` processes (default: one per core) on
    127.0.0.1; with a scheduler, ``workers`` is how many to wait for (default 1).
    security : a ``distributed.Security`` for a remote scheduler (default: Dask's
    configuration, ``distributed.comm.tls.*``).  Inside a session of the same scheduler (or
    of any, when none is named), that session is used.  A named scheduler is checked here,
    when the context manager is made (:meth:`Session.check`: its handshake within
    CONNECT_SECONDS), so a wrong address fails before any work.
    """
    active = _ACTIVE.get()
    if active is not None and (scheduler is None or (
            active.scheduler is not None and _same_address(scheduler, active.scheduler))):
        return contextlib.nullcontext(active)
    session = Session(scheduler, workers, security)
    session.check()
    return _active(session)


@contextlib.contextmanager
def _active(session):
    token = _ACTIVE.set(session)
    try:
        yield session
    finally:
        _ACTIVE.reset(token)
        session.close()


def _same_address(a: str, b: str) -> bool:
    def bare(address):
        return str(address).split("://", 1)[-1].rstrip("/")

    return bare(a) == bare(b)


def local_security():
    """(security, tls) for a LocalCluster: mutual TLS with credentials made in memory for
    this cluster alone (another local user cannot connect to its loopback ports and run
    code in its workers), or Dask's plain configuration without ``cryptography``."""
    from distributed import Security

    try:
        return Security.temporary(), True
    except ImportError:
        log.warning("cryptography is not installed: the local Dask cluster talks plain TCP on "
                    "127.0.0.1, which every local user can connect to; pip install "
                    "cryptography (in aobake[dask]) to make it TLS")
        return Security(), False


def _quiet(level: int) -> list:
    """Raise Dask's loggers to ``level`` for a session: [(logger, level before)].  Where the
    host configured logging first (the CLI does), Dask's records reach its handlers, and a
    cluster's routine (workers starting and closing) is not the user's business; what
    matters (a worker lost, an item that kills workers) this module reports itself."""
    saved = []
    names = ["distributed", "tornado"] + [  # and those Dask's configuration set a level on
        name for name, logger in logging.root.manager.loggerDict.items()
        if name.startswith(("distributed.", "tornado.")) and isinstance(logger, logging.Logger)
        and logger.level != logging.NOTSET]
    for name in names:
        logger = logging.getLogger(name)
        saved.append((logger, logger.level))
        logger.setLevel(max(logger.getEffectiveLevel(), level))
    return saved


def _IgnoreInterrupts():
    """A worker plugin (set up on every worker of the LocalCluster, restarted ones too):
    SIGINT ignored in the worker process.  Built here, as Dask is optional; cloudpickle
    ships the class by value."""
    from distributed import WorkerPlugin

    class IgnoreInterrupts(WorkerPlugin):
        name = "aobake-ignore-sigint"

        def setup(self, worker=None):
            import signal

            try:
                signal.signal(signal.SIGINT, signal.SIG_IGN)
            except ValueError:  # not the process's main thread: nothing to change
                pass

    return IgnoreInterrupts()


class DaskExecutor:
    """``--executor dask``: the bake's points as work items on a Dask cluster.

    workers : LocalCluster processes (default one per core) or, with ``scheduler``, the
    workers to wait for; chunk_points : points per item (default: the cost model);
    scheduler : an existing scheduler's address (default: the open :func:`cluster`
    session, else a LocalCluster for this bake); security : ``distributed.Security`` for it.
    """

    name = "dask"

    def __init__(self, workers: int | None = None, chunk_points: int | None = None,
                 scheduler: str | None = None, security=None):
        self.workers, self.chunk_points = workers, chunk_points
        self.scheduler, self.security = scheduler, security

    def estimate(self, job, method, plan, threads: int, chunk_rays: int, progress=None):
        """Estimates of every point of ``plan`` (``SamplePoints``), merged by index."""
        try:
            return self._estimate(job, method, plan, threads, chunk_rays, progress)
        finally:
            release(method)  # what the method started ahead here (the pilot may not use it)

    def _estimate(self, job, method, plan, threads, chunk_rays, progress):
        n = len(plan.points)
        if n == 0:
            return method.estimate(plan, threads, chunk_rays, progress)
        require()
        # a named scheduler is checked before any work (a wrong address fails in
        # milliseconds, a silent one in CONNECT_SECONDS), even where the pilot finishes
        session_here = cluster(self.scheduler, self.workers, self.security)
        wall = time.perf_counter()
        # a key no other client of a shared cluster has (it names the workers' cache entry)
        job = replace(job, key=f"{job.key}-{uuid.uuid4().hex[:12]}")
        whole = whole_item(job, plan)  # (its arrays as the plan holds them: cut per item)
        result = merged(method, plan)
        start, pilot_s, per_point = 0, 0.0, None
        if not self.chunk_points:
            clock = time.perf_counter()
            start, per_point = _pilot(method, whole, n, job.rays_per_point, chunk_rays,
                                      progress, result)
            pilot_s = time.perf_counter() - clock
            if (n - start) * per_point / threads < MIN_ITEM_SECONDS:
                # less than an item's worth is left: shipping the scene to a worker, which
                # rebuilds its acceleration structure, costs more than tracing it here
                if start < n:
                    result.add(start, n, method.estimate(_cut(whole, start, n).sample_points(),
                                                         threads, chunk_rays))
                    if progress:
                        progress(n, n)
                log.info("dask executor: %d points, all estimated here (less than %g s of "
                         "tracing left after the pilot)", n, MIN_ITEM_SECONDS)
                return result.result()
        release(method)  # the rest is estimated on the cluster
        with session_here as session:
            if self.chunk_points:
                size = self.chunk_points
                ranges = [(a, min(n, a + size)) for a in range(0, n, size)]
            else:
                nthreads = list(session.workers().values()) or [1]
                ranges = split(n, start, per_point, len(nthreads),
                               int(np.median(nthreads)))
            stats = {"points": n, "pilot_points": start, "pilot_s": pilot_s,
                     "items": len(ranges),
                     "per_item": max((b - a for a, b in ranges), default=0)}
            _run_items(session, job, whole, ranges, chunk_rays, progress, start, n, stats,
                       result)
            stats["wall_s"] = time.perf_counter() - wall
            session.stats.append(stats)
        return result.result()


def _cut(whole, start: int, stop: int):
    """Points start..stop-1 of ``whole`` (the WorkItem of every point): the per-point
    arrays cut as ``executors.base.items`` cuts them, the rest whole."""
    rows = {name: getattr(whole, name)[start:stop] for name in _PER_POINT
            if getattr(whole, name) is not None}
    return replace(whole, start=start, stop=stop, **rows)


def split(n: int, start: int, seconds_per_point: float, workers: int, threads: int) -> list:
    """The (start, stop) ranges of points start..n-1 from the cost model: items of about
    ITEM_SECONDS of one worker (``threads`` threads), at least ITEMS_PER_WORKER per worker
    when each still carries MIN_ITEM_SECONDS, and at most MAX_ITEM_POINTS points.
    seconds_per_point : one thread's."""
    rest = n - start
    if rest <= 0:
        return []
    per_second = threads / max(seconds_per_point, 1e-12)  # points one worker does per second
    balanced = rest / (max(1, workers) * ITEMS_PER_WORKER)
    size = max(min(ITEM_SECONDS * per_second, balanced), MIN_ITEM_SECONDS * per_second)
    size = min(max(1, math.ceil(size)), MAX_ITEM_POINTS)
    return [(a, min(n, a + size)) for a in range(start, n, size)]


def _pilot(method, whole, n: int, rays_per_point: int, chunk_rays: int, progress, result):
    """Estimate the first points here on one thread until PILOT_SECONDS have passed, their
    rows landing in ``result`` (``records.Merged``): (points done, seconds per point on one
    thread)."""
    done, seconds = 0, 0.0
    size = max(1, math.ceil(PILOT_RAYS / max(1, rays_per_point)))
    while done < n and seconds < PILOT_SECONDS:
        stop = min(n, done + size)
        clock = time.perf_counter()
        part = method.estimate(_cut(whole, done, stop).sample_points(), 1, chunk_rays)
        seconds += time.perf_counter() - clock
        result.add(done, stop, part)
        done, size = stop, size * 4
        if progress:
            progress(done, n)
    return done, seconds / max(done, 1)


def _worker_threads() -> int:
    try:
        from distributed import get_worker

        return max(1, int(get_worker().state.nthreads))
    except (ImportError, ValueError, AttributeError):
        return 1


#: one item at a time in a worker process, on all its threads (a method's prepared state
#: is not shared between concurrent estimates; a worker with more threads than one gives
#: them to the item)
_SERIAL = threading.Lock()


def run(item, chunk_rays: int, job, image=None):
    """On a worker: (start, stop, Estimates, timings) of one item; ``image`` (a view's
    G-buffer, scattered once like the job) is put back into the item."""
    threads = _worker_threads()
    with _SERIAL:
        if image is not None:
            item = replace(item, image=image)
        if job.key not in worker._CACHE:
            worker.install(job)
        clock = time.perf_counter()
        worker.prepared(job)
        prepare_s = time.perf_counter() - clock
        cpu = time.process_time()  # the process's CPU: a worker starved of a core shows
        start, stop, part = worker.run_item(item, threads, chunk_rays)
        estimate_s = time.perf_counter() - clock - prepare_s
        cpu_s = time.process_time() - cpu
    return start, stop, part, {"prepare_s": prepare_s, "estimate_s": estimate_s,
                               "estimate_cpu_s": cpu_s}


def _run_items(session, job, whole, ranges, chunk_rays, progress, done, n, stats,
               result) -> None:
    """Run the items ``ranges`` of ``whole`` on the session's cluster, their rows landing in
    ``result`` (``records.Merged``) as each is gathered; at most IN_FLIGHT_PER_WORKER items
    per worker are submitted at a time (each cut as it is submitted).  ``stats`` gets the
    workers' seconds and the reships."""
    import distributed
    from distributed.client import FutureCancelledError

    client = session.client
    image = getattr(whole, "image", None)
    if image is not None:  # a view's whole G-buffer: shipped once, not with every item
        whole = replace(whole, image=None)
    stats.update(prepare_s=0.0, estimate_s=0.0, estimate_cpu_s=0.0, reships=0,
                 workers=len(session.workers()))
    before = set(session.workers())
    window = IN_FLIGHT_PER_WORKER * max(1, len(before))
    shipped = []
    todo, attempt = collections.deque(ranges), 0
    since = time.time()
    # The LocalCluster started here runs its scheduler in this process: data scattered
    # through it would be received here whole (a copy of the scene, growing with it) before
    # it goes on to a worker, so it goes to a worker directly (then worker to worker as
    # before).  A remote scheduler is left to forward it: its workers may not be reachable
    # from here.
    direct = session.cluster is not None or None
    try:
        while todo:
            job_future = client.scatter(job, broadcast=True, hash=False, direct=direct)
            shipped.append(job_future)
            image_future = None
            if image is not None:
                image_future = client.scatter(image, broadcast=True, hash=False,
                                              direct=direct)
                shipped.append(image_future)
            futures: dict = {}
            running = distributed.as_completed(loop=client.loop)

            def submit():
                item = _cut(whole, *todo.popleft())
                future = client.submit(run, item, chunk_rays, job_future, image_future,
                                       key=f"aobake-item-{item.start}-{attempt}-{job.key}",
                                       pure=False, retries=RETRIES)
                futures[future] = item
                running.add(future)

            for _ in range(min(window, len(todo))):
                submit()
            lost = []
            try:
                for future in running:
                    item = futures.pop(future)
                    try:
                        first, stop, part, timing = future.result()
                    except FutureCancelledError:
                        lost.append(item)  # its job's data died with every worker holding it
                        continue
                    except distributed.KilledWorker as exc:
                        raise ClusterError(_killed(item, exc.allowed_failures)) from None
                    future.release()  # the worker frees it: the result lives here now
                    result.add(first, stop, part)
                    del part
                    for name in ("prepare_s", "estimate_s", "estimate_cpu_s"):
                        stats[name] += timing[name]
                    done += stop - first
                    if progress:
                        progress(done, n)
                    if todo and not lost:  # (once the job is lost, none is sent after it)
                        submit()
            finally:
                client.cancel(list(futures))  # nothing left running on an error or interrupt
            if lost:
                todo.extendleft((item.start, item.stop) for item in reversed(lost))
            attempt += 1
            if lost:
                # Every worker holding the job died (two workers a poisonous item killed in
                # turn, say): the scheduler cannot count those deaths against the items any
                # more, so count them from its log of removed workers.
                deaths = _deaths(client, job.key, since)
                worst = max(lost, key=lambda item: deaths.get(item.start, 0))
                allowed = _allowed_failures(client)
                if deaths.get(worst.start, 0) > allowed:
                    raise ClusterError(_killed(worst, allowed))
                stats["reships"] += 1
                if stats["reships"] > MAX_RESHIPS:
                    raise ClusterError(
                        f"the Dask cluster lost the scene {stats['reships']} times (every "
                        f"worker holding it died); {len(todo)} work items were left")
                log.warning("dask: every worker holding the scene died; sending it again and "
                            "re-running %d work items", len(todo))
    finally:
        with contextlib.suppress(Exception):
            client.cancel(shipped)
    _forget(client, job.key)
    left = before - set(session.workers())
    if left:
        log.warning("dask: %d of %d workers left during the bake (died or were stopped); "
                    "their unfinished items ran elsewhere: the values are unaffected",
                    len(left), len(before))
    log.info("dask executor: %d points, %d estimated here, %d items of <= %d points on %d "
             "workers", n, stats["pilot_points"], stats["items"], stats["per_item"],
             stats["workers"])


def _killed(item, allowed: int) -> str:
    """The message of an item that killed every worker it ran on."""
    return (f"points {item.start}..{item.stop - 1} of the bake killed every Dask worker that "
            f"ran them ({allowed + 1} workers; distributed.scheduler.allowed-failures = "
            f"{allowed}): a crash in native code or running out of memory that repeats; the "
            "bake was stopped")


def _deaths(client, key: str, since: float) -> dict:
    """item start -> how many workers died (not closed on purpose) while running one of the
    job ``key``'s items since ``since`` (time.time()), from the scheduler's log of removed
    workers; {} where the scheduler will not say."""
    def count(dask_scheduler=None):
        # nested (pickled by value): runs on a scheduler that need not have aobake
        deaths = {}
        for stamp, message in dask_scheduler.get_events("all"):
            if stamp < since or not isinstance(message, dict) or \
                    message.get("action") != "remove-worker" or message.get("expected"):
                continue
            for name in message.get("processing-tasks") or ():
                name = str(name)
                if name.startswith("aobake-item-") and name.endswith(key):
                    start = int(name.split("-")[2])
                    deaths[start] = deaths.get(start, 0) + 1
        return deaths

    try:
        return dict(client.run_on_scheduler(count))
    except Exception:  # noqa: BLE001 - run_on_scheduler blocked on a hardened scheduler
        return {}


def _allowed_failures(client) -> int:
    """The scheduler's distributed.scheduler.allowed-failures (ALLOWED_FAILURES for the
    LocalCluster started here; Dask's setting here where a scheduler will not say)."""
    def allowed(dask_scheduler=None):
        return dask_scheduler.allowed_failures

    try:
        return int(client.run_on_scheduler(allowed))
    except Exception:  # noqa: BLE001 - run_on_scheduler blocked on a hardened scheduler
        import dask

        return int(dask.config.get("distributed.scheduler.allowed-failures", 3))


def _forget(client, key: str) -> None:
    """Every worker drops the job from its cache (best effort: a worker that cannot answer
    drops it when new jobs arrive, ``worker.KEEP_JOBS``)."""
    with contextlib.suppress(Exception):
        client.run(worker.forget, key, wait=True, on_error="ignore")


__all__ = ["ALLOWED_FAILURES", "DaskExecutor", "ITEM_SECONDS", "Session", "ClusterError",
           "cluster", "local_security", "require", "split"]
