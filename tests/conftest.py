"""Shared fixtures and helpers of the test suite.

- ``tests/`` is importable (``analytic``, ``readers``);
- ``run_cli(*args)`` (``from conftest import run_cli``) runs the command line through
  click's CliRunner;
- ``box_ply`` writes a unit box as PLY (a mesh without UVs);
- ``backend``, ``sampler``, ``weighting`` run a test once per registered tracing backend,
  sampler and hemisphere weighting (a test that means a subset parametrises its own);
- ``method_name``, ``executor_name``, ``target_name`` run a test once per line of the
  METHODS, EXECUTORS and TARGETS registries, so a new line gets the split, bit-identity
  and refusal tests the day it is added;
- ``kernel`` skips a test where ``aobake._kernels`` was not built (``.ci/run``
  asserts separately that CI built it).
"""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from click.testing import CliRunner  # noqa: E402

from aobake import _native  # noqa: E402
from aobake.backends import BACKENDS  # noqa: E402
from aobake.executors import EXECUTORS  # noqa: E402
from aobake.methods import METHODS  # noqa: E402
from aobake.targets import TARGETS  # noqa: E402
from aobake.samplers import SAMPLERS  # noqa: E402
from aobake.warp import WEIGHTINGS  # noqa: E402


def run_cli(*args):
    """Invoke ``aobake`` with ``args`` (anything str() takes); returns click's Result."""
    from aobake.cli import main

    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture
def box_ply(tmp_path):
    import trimesh

    path = tmp_path / "box.ply"
    trimesh.creation.box().export(path)
    return path


@pytest.fixture(params=sorted(BACKENDS))
def backend(request):
    """Each registered backend's name (the closed-form tests run on every one; one whose
    optional extra is missing here skips with the reason: CI installs every extra)."""
    from aobake.backends import unavailable

    missing = unavailable(request.param)
    if missing:
        pytest.skip(missing)
    return request.param


@pytest.fixture(params=list(SAMPLERS))
def sampler(request):
    """Each registered sampler's name (random, stratified, sobol)."""
    return request.param


@pytest.fixture(params=list(WEIGHTINGS))
def weighting(request):
    """Each hemisphere weighting's name (cosine, uniform)."""
    return request.param


@pytest.fixture(params=list(METHODS))
def method_name(request):
    """Each registered method's name (``aobake.methods.METHODS``)."""
    return request.param


@pytest.fixture(params=list(EXECUTORS))
def executor_name(request):
    """Each registered executor's name (``aobake.executors.EXECUTORS``)."""
    return request.param


@pytest.fixture(params=list(TARGETS))
def target_name(request):
    """Each registered target's name (``aobake.targets.TARGETS``)."""
    return request.param


@pytest.fixture
def kernel():
    """The compiled module; skips the test where it was not built."""
    if not _native.built():
        pytest.skip("aobake._kernels was not built (no C compiler at install)")
    return _native.kernels()
