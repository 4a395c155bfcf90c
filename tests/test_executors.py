"""Methods and executors: any split of the points, on any executor, gives the same bits.

Each point's estimate is a pure function of that point (position, normal, size,
sample-stream id) and the seed, so the arrays of a bake must not depend on how its
points are cut into work items, nor on whether threads or processes estimate them.
"""

from __future__ import annotations

import numpy as np
import pytest

import aobake
from aobake.records import Estimates, merge
from aobake.executors import EXECUTORS
from aobake.methods import METHODS

from analytic import combine, floor_and_ceiling, polygon, quad


def _scene():
    """A floor with a ceiling and a disc: points from fully open to well occluded."""
    return combine(floor_and_ceiling(0.5, 2.0), polygon([0.5, 0.3, 0.2], 0.3, 24),
                   quad([-1.0, 0.0, 0.25], 0.2, 0.2, flip=True))


def _same(a, b):
    assert a.keys() == b.keys()
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def _values(result):
    if hasattr(result, "channels"):
        return dict(result.channels)
    return {**result.values, "rays": result.rays, **result.kept}


def _report(result):
    """The report's parameters without timings (the bits of every number stated)."""
    return result.report["parameters"], result.report.get("tolerance")


CASES = {
    "fixed": dict(rays=24, quantities=("ao", "obscurance", "bent_normal"), max_distance="40%"),
    "tolerance": dict(rays=16, tolerance=0.08, max_rays=128, quantities=("ao", "obscurance")),
    "keep": dict(rays=8, quantities=("obscurance",), keep_distances=True),
}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.slow
def test_vertex_bake_is_the_same_for_every_split_and_executor(case):
    mesh = _scene()
    options = CASES[case]
    base = aobake.bake(mesh, seed=3, threads=2, **options)
    runs = [dict(executor="threads", chunk_points=1, threads=1),
            dict(executor="threads", chunk_points=7, threads=2),
            dict(executor="processes", workers=2, chunk_points=5)]
    for run in runs:
        other = aobake.bake(mesh, seed=3, **options, **run)
        _same(_values(base), _values(other))
        assert _report(base) == _report(other), run
        assert other.report["executor"]["name"] == run["executor"]


@pytest.mark.slow
def test_lightmap_and_view_are_the_same_on_processes():
    import trimesh

    mesh = trimesh.creation.torus(1.0, 0.4, major_sections=24, minor_sections=12)
    options = dict(rays=8, resolution=32, seed=5, quantities=("ao", "bent_normal"))
    base = aobake.bake_texels(mesh, threads=1, **options)
    other = aobake.bake_texels(mesh, executor="processes", workers=2, chunk_points=97,
                               **options)
    _same(_values(base), _values(other))
    view = dict(rays=8, seed=2, size=(40, 30))
    a = aobake.bake_view(mesh, threads=2, **view)
    b = aobake.bake_view(mesh, executor="processes", workers=2, chunk_points=33, **view)
    _same(_values(a), _values(b))


@pytest.mark.slow
def test_numpy_path_is_carried_to_worker_processes(kernel):
    """A bake asked for on the numpy path runs it in the workers too (the report says so),
    with the same bits."""
    from aobake import _native

    mesh = _scene()
    with _native.numpy_only():
        base = aobake.bake(mesh, rays=16, threads=1)
        other = aobake.bake(mesh, rays=16, executor="processes", workers=2, chunk_points=9)
    _same(_values(base), _values(other))
    assert other.report["parameters"]["kernels"]["ray_generation"] == "numpy"


def _part(n, offset):
    return Estimates({"ao": np.arange(n, dtype=np.float64) + offset},
                     np.full(n, 4, dtype=np.int32), {"ray_offset": np.zeros(n)})


def test_merge_lands_rows_by_index_whatever_the_order():
    a, b = _part(3, 0.0), _part(2, 10.0)
    merged = merge([(np.array([4, 0]), b), (np.array([1, 2, 3]), a)], 5)
    np.testing.assert_array_equal(merged.fields["ao"], [11.0, 0.0, 1.0, 2.0, 10.0])
    assert merged.rays_cast == 20


def test_merge_refuses_gaps_and_overlaps():
    with pytest.raises(ValueError, match="exactly once"):
        merge([(np.array([0, 1]), _part(2, 0.0))], 3)
    with pytest.raises(ValueError, match="exactly once"):
        merge([(np.array([0, 1]), _part(2, 0.0)), (np.array([1, 2]), _part(2, 0.0))], 3)


def test_registries_name_their_parts():
    assert "rays" in METHODS and METHODS["rays"].casts_rays
    assert {"threads", "processes"} <= set(EXECUTORS)


def test_unknown_method_executor_and_bad_workers_are_input_errors():
    mesh = _scene()
    with pytest.raises(aobake.InputError, match="unknown method"):
        aobake.bake(mesh, rays=4, method="nope")
    with pytest.raises(aobake.InputError, match="unknown executor"):
        aobake.bake(mesh, rays=4, executor="nope")
    for bad in (0, -1, 1.5, "2", True):
        with pytest.raises(aobake.InputError, match="workers"):
            aobake.bake(mesh, rays=4, workers=bad)


@pytest.mark.slow
def test_cli_executor_processes_matches_threads(tmp_path):
    from conftest import run_cli

    mesh = tmp_path / "scene.ply"
    _scene().export(mesh)
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    assert run_cli(mesh, "--out", a, "--rays", "16", "--quiet").exit_code == 0
    result = run_cli(mesh, "--out", b, "--rays", "16", "--quiet", "--executor", "processes",
                     "--workers", "2", "--chunk-points", "11")
    assert result.exit_code == 0, result.output
    with np.load(a) as x, np.load(b) as y:
        for key in ("ao", "ao_stderr", "rays"):
            np.testing.assert_array_equal(x[key], y[key])


@pytest.mark.parametrize("method", ["discs", "hemicube"])
@pytest.mark.slow
def test_approximations_are_the_same_for_every_split_and_executor(method):
    """A method that casts no rays merges by index like the rays: the same bits whatever
    the split and executor (hemicube: where an EGL context can be made)."""
    if method == "hemicube":
        pytest.importorskip("moderngl")
        from aobake.methods.hemicube import available

        ok, why = available()
        if not ok:
            pytest.skip(why)
    mesh = _scene()
    options = dict(method=method, hemicube_resolution=8)
    base = aobake.bake(mesh, threads=1, **options)
    for run in (dict(executor="threads", chunk_points=5, threads=2),
                dict(executor="processes", workers=2, chunk_points=9)):
        other = aobake.bake(mesh, **options, **run)
        _same(base.values, other.values)
        assert base.rays is None and other.rays is None


@pytest.mark.parametrize("executor", ["threads", "processes"])
@pytest.mark.slow
def test_every_executor_releases_what_the_method_started_here(monkeypatch, executor):
    """What a method holds for estimating in this process (``close``: the hemicube's GL
    child started ahead) is released when the executor's estimate returns: no process a
    bake started outlives it, whichever executor ran it (issue 35)."""
    from aobake.methods.discs import DiscsMethod

    closed = []
    monkeypatch.setattr(DiscsMethod, "close", lambda self: closed.append(self),
                        raising=False)
    aobake.bake(_scene(), method="discs", executor=executor, workers=2, chunk_points=9)
    assert len(closed) >= 1 and all(isinstance(m, DiscsMethod) for m in closed)
