"""``--executor processes`` leaves nothing behind and prints nothing of its own (issue 35):
no child process outlives a bake (the hemicube's OpenGL child started ahead in the caller
included), no ``Popen.__del__`` or resource warning at the caller's exit, and a bake
signalled while its pool starts exits 130 (SIGINT) or 143 (SIGTERM) with one line: no
worker's ``KeyboardInterrupt`` or ``UnpicklingError`` traceback, no "leaked semaphore
objects", no process left.  Processes are listed with psutil (skipped without it).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import trimesh

psutil = pytest.importorskip("psutil")

ROOT = Path(__file__).resolve().parents[1]
#: multiprocessing's resource tracker: one per interpreter, started by its first spawned
#: pool and kept for the next (it ignores signals and ends with the interpreter); not a
#: process of the bake's
TRACKER = "multiprocessing.resource_tracker"

_LIBRARY = """\
import json, sys, time
import psutil, trimesh
import aobake

if __name__ == "__main__":
    mesh = trimesh.creation.icosphere(2)
    result = aobake.bake(mesh, method="hemicube", executor="processes", workers=2,
                         threads=2, hemicube_resolution=8)
    time.sleep(0.5)  # a child being ended has had time to go
    left = [" ".join(p.cmdline())[-60:] for p in psutil.Process().children(recursive=True)
            if p.status() != psutil.STATUS_ZOMBIE
            and "multiprocessing.resource_tracker" not in " ".join(p.cmdline())]
    print(json.dumps({"points": len(result.ao), "left": left}))
"""


def _gl():
    pytest.importorskip("moderngl")
    from aobake.methods.hemicube import available

    ok, why = available()
    if not ok:
        pytest.skip(why)


@pytest.mark.slow
def test_library_hemicube_on_processes_leaves_no_child(tmp_path):
    """``aobake.bake(mesh, method='hemicube', executor='processes')`` in a program of its
    own (ResourceWarnings shown): after the call no child of the caller is left (the GL
    child the method started ahead was never used here: the workers draw), and the
    interpreter exits with nothing on stderr."""
    _gl()
    script = tmp_path / "bake_hemicube.py"  # a file: spawned workers re-import __main__
    script.write_text(_LIBRARY)
    proc = subprocess.run([sys.executable, "-W", "always::ResourceWarning", str(script)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["points"] > 0 and out["left"] == [], out
    assert proc.stderr == "", proc.stderr


# ------------------------------------------------------------------ signals


def _mesh(tmp_path) -> Path:
    """10,242 vertices: a few seconds of work on two workers, so the signal lands while
    the pool starts or early in its items."""
    path = tmp_path / "ico.ply"
    trimesh.creation.icosphere(5).export(path)
    return path


def _command(mesh, out, *extra):
    return [sys.executable, "-m", "aobake", str(mesh), "--out", str(out), "--executor",
            "processes", "--workers", "2", "--rays", "64", *extra]


def _when_pool_starts(parent, seconds: float = 120.0) -> None:
    """Return as soon as the first worker process of ``parent`` exists."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            if any("spawn_main" in " ".join(p.cmdline()) for p in parent.children()):
                return
        except psutil.Error:
            pass
        time.sleep(0.002)
    pytest.fail("no worker process started")


def _family(parent) -> dict:
    try:
        return {p.pid: p for p in parent.children(recursive=True)}
    except psutil.Error:
        return {}


def _left(family: dict) -> list:
    time.sleep(0.5)
    return [pid for pid, p in family.items()
            if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]


@pytest.mark.slow
@pytest.mark.parametrize("delay", [0.0, 0.03, 0.15])
@pytest.mark.parametrize("how", ["SIGINT to the group", "SIGTERM to the process"])
def test_a_signal_while_the_pool_starts(tmp_path, how, delay):
    """A terminal's Ctrl-C (SIGINT to the whole process group: the workers get it too) or
    SIGTERM to aobake alone, ``delay`` seconds after its first worker process appeared:
    exit 130 / 143, the one line, no output file, every process of the bake gone."""
    name, whom = how.split(" to the ")
    signum = getattr(signal, name)
    out = tmp_path / "out.npz"
    process = subprocess.Popen(_command(_mesh(tmp_path), out), cwd=ROOT,
                               stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        parent = psutil.Process(process.pid)
        _when_pool_starts(parent)
        time.sleep(delay)
        family = _family(parent)
        (os.killpg if whom == "group" else os.kill)(process.pid, signum)
        code = process.wait(60)
        family.update(_family(parent))
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    err = process.stderr.read()
    word = "interrupted" if signum == signal.SIGINT else "terminated"
    assert code == 128 + signum, err
    assert err == f"aobake: error: {word} ({name}): no output written\n", err
    assert not out.exists()
    assert _left(family) == [], "processes left behind"


@pytest.mark.slow
def test_a_worker_killed_is_one_line(tmp_path):
    """A worker process killed outright (the out-of-memory killer, say) fails the bake
    with one line naming its points: no BrokenProcessPool traceback, nothing left."""
    out = tmp_path / "out.npz"
    process = subprocess.Popen(_command(_mesh(tmp_path), out), cwd=ROOT,
                               stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        parent = psutil.Process(process.pid)
        _when_pool_starts(parent)
        family = _family(parent)
        worker = next(p for p in family.values() if "spawn_main" in " ".join(p.cmdline()))
        time.sleep(0.3)
        worker.kill()
        code = process.wait(60)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    err = process.stderr.read()
    assert code == 1, err
    assert err.startswith("aobake: error: a worker process died while points ") \
        and err.count("\n") == 1, err
    assert not out.exists()
    assert _left(family) == [], "processes left behind"


_FAILING_TARGET = """\
import json, sys, time
import psutil, trimesh
import aobake
from aobake.targets import TARGETS

class Failing(TARGETS["vertices"]):
    def sample(self, scene, config, occluders, *args, **kwargs):
        occluders()        # the build is done; the method prepares right after it
        time.sleep(2.0)    # ... and has started its GL child ahead by now
        raise aobake.InputError("the target failed after the method was prepared")

if __name__ == "__main__":
    try:
        aobake.run(aobake.BakeConfig(hemicube_resolution=8), trimesh.creation.icosphere(2),
                   Failing(), method="hemicube")
    except aobake.InputError as exc:
        said = str(exc)
        # a caller that keeps the error (a log, a retry loop) keeps the frames: the method
        # is not collected, so only the composition root can end its child
        kept = exc.__traceback__
    time.sleep(0.5)
    left = [" ".join(p.cmdline())[-60:] for p in psutil.Process().children(recursive=True)
            if p.status() != psutil.STATUS_ZOMBIE]
    print(json.dumps({"said": said, "left": left}))
"""


@pytest.mark.slow
def test_a_target_failing_after_the_method_was_prepared_leaves_no_gl_child(tmp_path):
    """The composition root ends what a prepared method started (the hemicube's GL child)
    when the bake fails after the preparation, not when the method is collected."""
    _gl()
    script = tmp_path / "failing.py"
    script.write_text(_FAILING_TARGET)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    record = json.loads(done.stdout.strip().splitlines()[-1])
    assert record["said"].startswith("the target failed")
    assert record["left"] == [], record["left"]
