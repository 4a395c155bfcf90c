"""A child Python process imports exactly the aobake its parent runs (issue 21): not one
that happens to sit in its current directory, as a checkout's source tree does when the
installed aobake is run from the checkout's root."""

import json
import os
import subprocess
import sys

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
