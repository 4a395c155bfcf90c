"""``--scheduler`` at an address where no Dask scheduler answers (issue 35): another kind
of service, a port that accepts and stays silent, a peer that announces an absurd frame.
Each is one clear error (InputError: "no Dask scheduler answered at ADDRESS (got ...)")
within a bound derived from ``CONNECT_SECONDS``, through the library, ``aobake`` and
``aobake batch``: no traceback, no 3 EiB allocation, no hang, also not at the interpreter's
exit (a ``distributed.Client`` that failed to start used to wait 60 s there, then print a
traceback).  The servers run on 127.0.0.1 in this process.  Skipped where Dask is not
installed.
"""

from __future__ import annotations

import http.server
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import trimesh

distributed = pytest.importorskip("distributed")

import aobake  # noqa: E402
from aobake.errors import InputError  # noqa: E402
from aobake.executors import dask as dask_executor  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: what a process needs beyond a scheduler's wait: the interpreter's start, aobake's and
#: Dask's imports, the mesh, on a loaded 2-core machine
START_SECONDS = 20.0
#: the library's tests shorten the wait to this (the command line's keep the constant)
SHORT_CONNECT = 2.0


class Server:
    """A TCP server on 127.0.0.1 (``address``) answering each connection with
    ``reply(connection)`` in a thread of its own; connections are held open until close."""

    def __init__(self, reply):
        self.reply, self.held = reply, []
        self.socket = socket.create_server(("127.0.0.1", 0))
        self.address = f"tcp://127.0.0.1:{self.socket.getsockname()[1]}"
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                connection, _ = self.socket.accept()
            except OSError:
                return
            self.held.append(connection)
            threading.Thread(target=self._answer, args=(connection,), daemon=True).start()

    def _answer(self, connection):
        try:
            self.reply(connection)
        except OSError:
            pass

    def close(self):
        self.socket.close()
        for connection in self.held:
            connection.close()


def _silent(connection):
    """Accept, read what comes, never write."""
    while connection.recv(4096):
        pass


def _garbage(connection):
    """An HTTP answer at once, whatever was asked: "HTTP/1.1" read as a Dask frame's
    length is 3.07 EiB."""
    connection.sendall(b"HTTP/1.1 200 OK\r\nContent-Length: 7\r\n\r\ngarbage")
    _silent(connection)


def _huge(connection):
    """A frame length of 2^64 - 1, then silence."""
    connection.sendall(b"\xff" * 8)
    _silent(connection)


def _dask_then_silent(connection):
    """A Dask handshake (as a scheduler writes it when it accepts), then silence: passes
    the probe; the client's start then times out."""
    import msgpack

    body = msgpack.dumps({"compression": None, "python": list(sys.version_info[:3]),
                          "pickle-protocol": 5})
    connection.sendall(struct.pack("QQQ", 16 + len(body), 1, len(body)) + body)
    _silent(connection)


class _Http:
    """A real HTTP server (the standard library's), which waits for a request's head."""

    def __init__(self):
        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0),
                                                      http.server.BaseHTTPRequestHandler)
        self.server.RequestHandlerClass.log_message = lambda *args: None
        self.address = f"tcp://127.0.0.1:{self.server.server_address[1]}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self):
        self.server.shutdown()
        self.server.server_close()


#: kind -> (server factory, how long an answer may take: "at once" or the full wait)
KINDS = {"silent": (lambda: Server(_silent), "wait"),
         "garbage": (lambda: Server(_garbage), "at once"),
         "huge": (lambda: Server(_huge), "at once"),
         "http": (_Http, "at once")}
FAST = sorted(kind for kind, (_, speed) in KINDS.items() if speed == "at once")


@pytest.fixture
def server(request):
    made = KINDS[request.param][0]()
    yield made
    made.close()


def _bounded(function, seconds: float):
    """``function()`` in a thread, failing the test if it runs longer than ``seconds`` (a
    hang must not hang the suite); returns (its exception or None, seconds taken)."""
    out: list = []

    def call():
        clock = time.monotonic()
        try:
            function()
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            out.append(exc)
        else:
            out.append(None)
        out.append(time.monotonic() - clock)

    thread = threading.Thread(target=call, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"still running after {seconds:g} s"
    return out[0], out[1]


def _bake(address, **options):
    """The issue's library call: a tiny mesh (the pilot alone would finish it)."""
    return aobake.bake(trimesh.creation.box(), rays=8, executor="dask", scheduler=address,
                       **options)


def _one_error_line(stderr: str) -> str:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("aobake: error: "), stderr
    assert "Traceback" not in stderr and "Warning" not in stderr, stderr
    return lines[0]


# ------------------------------------------------------------------ the library


@pytest.mark.parametrize("server", FAST, indirect=True)
@pytest.mark.slow
def test_library_refuses_another_service_at_once(server, monkeypatch):
    """Another service's answer is an InputError naming the address and what came, well
    before the wait is over; so for a split that reaches the cluster."""
    monkeypatch.setattr(dask_executor, "CONNECT_SECONDS", SHORT_CONNECT)
    for options in ({}, {"chunk_points": 3}):
        error, took = _bounded(lambda: _bake(server.address, **options), 60)
        assert isinstance(error, InputError), repr(error)
        assert f"no Dask scheduler answered at {server.address} (got " in str(error)
        assert took < SHORT_CONNECT, took


@pytest.mark.slow
@pytest.mark.parametrize("server", ["silent"], indirect=True)
def test_library_refuses_a_silent_port_after_the_wait(server, monkeypatch):
    """A port that accepts and never writes: InputError once CONNECT_SECONDS have passed."""
    monkeypatch.setattr(dask_executor, "CONNECT_SECONDS", SHORT_CONNECT)
    error, took = _bounded(lambda: _bake(server.address), SHORT_CONNECT + 30)
    assert isinstance(error, InputError), repr(error)
    assert str(error) == (f"no Dask scheduler answered at {server.address} (got nothing in "
                          f"{SHORT_CONNECT:g} s)")
    assert SHORT_CONNECT <= took < SHORT_CONNECT + 5, took


def test_the_errors_say_what_answered():
    garbage, huge = Server(_garbage), Server(_huge)
    try:
        with pytest.raises(InputError, match=r"got an HTTP reply, 'HTTP/1\.1 200 OK', not a "
                                             r"Dask handshake"):
            dask_executor.probe(garbage.address, timeout=SHORT_CONNECT)
        with pytest.raises(InputError, match=r"got the bytes ff ff ff ff ff ff ff ff, not a "
                                             r"Dask handshake \(18446744073709551615 bytes"):
            dask_executor.probe(huge.address, timeout=SHORT_CONNECT)
    finally:
        garbage.close()
        huge.close()


def test_a_real_scheduler_passes_the_probe():
    """The probe reads a real scheduler's handshake (this Dask's framing) and leaves it
    working: a client connects afterwards."""
    with distributed.LocalCluster(n_workers=0, processes=False, protocol="tcp://",
                                  host="127.0.0.1", dashboard_address=None,
                                  scheduler_kwargs={"dashboard": False,
                                                    "dashboard_address": "127.0.0.1:0"}
                                  ) as local:
        answer = dask_executor.probe(local.scheduler_address)
        assert tuple(answer["python"]) == tuple(sys.version_info[:3])
        with distributed.Client(local.scheduler_address, set_as_default=False) as client:
            assert client.scheduler_info()["address"] == local.scheduler_address


_SCRIPT = """\
import sys, time, trimesh, aobake
from aobake.executors import dask as dask_executor
dask_executor.CONNECT_SECONDS = float(sys.argv[2])
clock = time.monotonic()
try:
    aobake.bake(trimesh.creation.box(), rays=8, executor="dask", scheduler=sys.argv[1],
                chunk_points=3)
except aobake.AobakeError as exc:
    print(type(exc).__name__, round(time.monotonic() - clock, 2), exc)
"""


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["huge", "dask_then_silent"])
def test_library_caller_exits_at_once_after_the_error(kind):
    """The library in a program of its own: the error, then the interpreter's exit, all
    within the bound and silent on stderr.  With a peer that passes the probe (a Dask
    handshake, then nothing) the client's own start fails: it is closed on the spot, not
    at the exit by ``Client.__del__``."""
    server = Server(_huge if kind == "huge" else _dask_then_silent)
    try:
        clock = time.monotonic()
        proc = subprocess.run([sys.executable, "-c", _SCRIPT, server.address,
                               str(SHORT_CONNECT)], cwd=ROOT, capture_output=True,
                              text=True, timeout=2 * SHORT_CONNECT + START_SECONDS + 30)
        took = time.monotonic() - clock
    finally:
        server.close()
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    name, seconds, message = proc.stdout.split(" ", 2)
    assert name == ("InputError" if kind == "huge" else "ClusterError"), proc.stdout
    assert float(seconds) < 2 * SHORT_CONNECT + dask_executor.CLOSE_SECONDS, proc.stdout
    assert took < 2 * SHORT_CONNECT + dask_executor.CLOSE_SECONDS + START_SECONDS, took


# ------------------------------------------------------------------ the command line


def _cli(*args, bound: float):
    clock = time.monotonic()
    try:
        proc = subprocess.run([sys.executable, "-m", "aobake", *map(str, args)], cwd=ROOT,
                              capture_output=True, text=True, timeout=bound + 60)
    except subprocess.TimeoutExpired:
        pytest.fail(f"aobake {' '.join(map(str, args))} still running after {bound + 60:g} s")
    return proc, time.monotonic() - clock


@pytest.mark.slow
@pytest.mark.parametrize("server", sorted(KINDS), indirect=True)
def test_cli_refuses_with_one_line(server, request, tmp_path):
    """``aobake MESH --executor dask --scheduler ADDRESS``: exit 1, one line, no
    traceback, ended (interpreter exit included) within the bound: at once for another
    service, CONNECT_SECONDS for a silent port."""
    mesh = tmp_path / "box.ply"
    trimesh.creation.box().export(mesh)
    kind = request.node.callspec.params["server"]
    wait = dask_executor.CONNECT_SECONDS if KINDS[kind][1] == "wait" else 0.0
    proc, took = _cli(mesh, "--out", tmp_path / "out.npz", "--executor", "dask",
                      "--scheduler", server.address, bound=wait + START_SECONDS)
    assert proc.returncode == 1, proc.stderr
    line = _one_error_line(proc.stderr)
    assert f"no Dask scheduler answered at {server.address} (got " in line
    assert took < wait + START_SECONDS, took
    assert not (tmp_path / "out.npz").exists()


@pytest.mark.slow
def test_batch_refuses_with_one_line(tmp_path):
    """``aobake batch ... --executor dask --scheduler ADDRESS``: the scheduler is checked
    before the first asset; one line, exit 1."""
    folder = tmp_path / "in"
    folder.mkdir()
    trimesh.creation.box().export(folder / "a.ply")
    server = Server(_garbage)
    try:
        proc, took = _cli("batch", folder, "--out-dir", tmp_path / "out", "--format", "npz",
                          "--executor", "dask", "--scheduler", server.address,
                          bound=START_SECONDS)
    finally:
        server.close()
    assert proc.returncode == 1, proc.stderr
    assert f"no Dask scheduler answered at {server.address}" in _one_error_line(proc.stderr)
    assert took < START_SECONDS, took
    assert not (tmp_path / "out" / "a.npz").exists()
