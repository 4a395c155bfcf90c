"""A child Python process imports exactly the aobake its parent runs (issue 21): not one
that happens to sit in its current directory, as a checkout's source tree does when the
installed aobake is run from the checkout's root.  And it never outlives that parent
(issue 35)."""

import json
import os
import subprocess
import sys
import time

import pytest
import trimesh

import aobake
from aobake import child
from aobake.errors import InputError
from aobake.targets.texels import unwrap as unwrapping

REPORT = "import json, sys, aobake; print(json.dumps([aobake.__file__, sys.argv[1:]]))"


@pytest.fixture
def shadowing_dir(tmp_path):
    """A directory holding another package named aobake, unusable as this one: each of its
    modules on the unwrap's import path raises (the unwrap's child imports ``aobake.child``
    and ``aobake.targets.texels.unwrap`` without running the packages' ``__init__``)."""
    fake = tmp_path / "aobake" / "targets" / "texels"
    fake.mkdir(parents=True)
    for module in (fake.parent.parent / "__init__.py", fake.parent.parent / "child.py",
                   fake.parent / "__init__.py", fake / "__init__.py", fake / "unwrap.py",
                   fake / "charts.py", fake / "packing.py"):
        module.write_text("raise ImportError('the aobake of the current directory')\n")
    return tmp_path


def test_plain_child_would_import_the_current_directory(shadowing_dir):
    """The trap the helper avoids (so the tests below can fail): ``python -c`` imports the
    current directory's aobake."""
    proc = subprocess.run([sys.executable, "-c", REPORT], cwd=shadowing_dir,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0 and "the aobake of the current directory" in proc.stderr


def test_child_imports_the_parents_aobake(shadowing_dir):
    spec = child.python_child(REPORT, ["a b", 3])
    proc = subprocess.run(spec.argv, env=spec.env, cwd=shadowing_dir, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    file, args = json.loads(proc.stdout)
    assert os.path.samefile(file, aobake.__file__)
    assert args == ["a b", "3"]
    assert os.path.samefile(child.PACKAGE_ROOT, os.path.dirname(os.path.dirname(aobake.__file__)))


def test_child_imports_the_parents_aobake_despite_pythonpath(shadowing_dir):
    """... also when the environment points elsewhere first."""
    env = dict(os.environ, PYTHONPATH=str(shadowing_dir))
    spec = child.python_child(REPORT, env=env)
    proc = subprocess.run(spec.argv, env=spec.env, cwd=shadowing_dir, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert os.path.samefile(json.loads(proc.stdout)[0], aobake.__file__)


@pytest.mark.parametrize("prestarted", [False, True])
@pytest.mark.slow
def test_unwrap_from_a_directory_holding_another_aobake(shadowing_dir, monkeypatch, prestarted):
    """The issue's case: the unwrap's child (fresh or prestarted) runs from a directory with
    another aobake in it, and unwraps with this one."""
    monkeypatch.chdir(shadowing_dir)
    mesh = trimesh.creation.box()
    try:
        if prestarted:
            unwrapping.prestart()
            assert child.waiting(unwrapping.WORKER) is not None
        try:
            result = unwrapping.unwrap(mesh.vertices, mesh.faces, 32, 1)
        except InputError as exc:
            pytest.fail(f"the child imported the wrong aobake: {exc}")
        assert result.charts > 0
        assert child.waiting(unwrapping.WORKER) is None  # taken (when prestarted) and gone
    finally:
        unwrapping.discard_prestarted()


SLEEPY = "import time\n\n\ndef work(inputs):\n    time.sleep(600)\n    return {}\n"

MIDDLE = """\
import numpy as np
from aobake import child
print("started", flush=True)
child.run(child.worker("sleepy", "sleepy", "work"), {"x": np.zeros(1)}, 600)
"""


@pytest.mark.slow
def test_a_child_ends_when_its_parent_is_killed(tmp_path):
    """A parent killed outright (a pool worker ended by its pool, the out-of-memory killer)
    cannot end the child it runs work in: the child sees its parent gone within
    ``WATCH_SECONDS``, removes the parent's temporary directory of the work and ends,
    instead of working on for the rest of its time limit."""
    psutil = pytest.importorskip("psutil")
    kids = []
    (tmp_path / "sleepy.py").write_text(SLEEPY)
    temp = tmp_path / "temp"
    temp.mkdir()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(tmp_path), *filter(None, [os.environ.get("PYTHONPATH")])]), TMPDIR=str(temp))
    middle = subprocess.Popen([sys.executable, "-c", MIDDLE], env=env,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert middle.stdout.readline() == "started\n"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (kids and list(temp.iterdir())):
            kids = psutil.Process(middle.pid).children()
            time.sleep(0.05)
        assert len(kids) == 1 and [p.name for p in temp.iterdir()][0].startswith(
            "aobake-sleepy-"), "the child never started"
        time.sleep(0.5)  # past its imports: it is in the work
        middle.kill()
        middle.wait(10)
        gone = kids[0].wait(child.WATCH_SECONDS + 5)  # raises psutil.TimeoutExpired
        assert gone is None or gone == 1
        assert list(temp.iterdir()) == [], "the work's directory was left"
    finally:
        if middle.poll() is None:
            middle.kill()
            middle.wait()
        for orphan in kids:  # handed to init: not among this process's children
            if orphan.is_running():
                orphan.kill()
