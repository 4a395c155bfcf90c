"""The library's refit and compare take paths and names, and say so (issue 35): a path that
is None, an int, a dict or a result object raised TypeError; ``quantities='ao'`` was read
letter by letter; an unknown quantity was said to "need the ray directions"; and a refit of
a refit failed, its kept distances reaching beyond its own max distance."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import aobake
from aobake.compare import compare, read
from aobake.refit import refit
from conftest import run_cli

BAKED = dict(rays=16, seed=5, keep_distances=True, quantities=("ao", "obscurance"))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("refit")
    mesh = tmp / "bowl.ply"
    trimesh.creation.icosphere(2).export(mesh)
    baked = aobake.bake(mesh, **BAKED)
    aobake.write(baked, tmp / "kept.npz")
    aobake.write(aobake.bake(mesh, rays=16, seed=5), tmp / "ao.ply")  # no kept distances
    return mesh, baked, tmp / "kept.npz", tmp / "ao.ply"


NOT_PATHS = [None, 5, {"path": "x.npz"}, b"kept.npz"]


@pytest.mark.parametrize("value", NOT_PATHS, ids=lambda v: type(v).__name__)
def test_refit_of_no_path_is_an_input_error(value):
    with pytest.raises(aobake.InputError, match="refit: bake must be a BakeResult"):
        refit(value)


@pytest.mark.parametrize("value", NOT_PATHS + ["result"], ids=lambda v: str(type(v).__name__))
@pytest.mark.slow
def test_compare_of_no_path_is_an_input_error(files, value):
    if value == "result":
        value = files[1]
    for role, args in (("reference", (value, files[3])), ("candidate", (files[3], value))):
        with pytest.raises(aobake.InputError, match=f"compare: the {role} must be a file path"):
            compare(*args)
    with pytest.raises(aobake.InputError, match="file path"):
        read(value)


def test_compare_names_a_result_object(files):
    with pytest.raises(aobake.InputError, match=r"BakeResult \(write it with aobake.write"):
        compare(files[1], files[3])


def test_refit_quantities_a_name_is_one_quantity(files):
    again = refit(files[2], quantities="ao", tau=1.0)
    assert again.report["config"]["quantities"] == ["ao"]
    assert set(again.values) >= {"ao"} and "obscurance" not in again.values


@pytest.mark.parametrize("quantities, words", [
    ("foo", "unknown quantity 'foo'"),
    (["ao", "nonsense"], "unknown quantity 'nonsense'"),
    ("bent_normal", "bent_normal needs the ray directions"),
    (5, "quantities must be a name or a list of names"),
    ([5], "quantities must be a name or a list of names")])
def test_refit_quantities_are_checked(files, quantities, words):
    with pytest.raises(aobake.InputError, match=words):
        refit(files[2], quantities=quantities)


def _same(a, b):
    assert a.values.keys() == b.values.keys()
    for name in a.values:
        np.testing.assert_array_equal(a.values[name], b.values[name], err_msg=name)


def test_a_refit_of_a_refit_equals_the_refit_and_a_fresh_bake(files):
    mesh, baked, _, _ = files
    first = refit(baked, max_distance="20%", tau=1.0)
    second = refit(first, max_distance="5%")
    _same(second, refit(baked, max_distance="5%", tau=1.0))
    fresh = aobake.bake(mesh, **dict(BAKED, max_distance="5%", tau=1.0))
    _same(second, fresh)
    # the kept distances are the fresh bake's too: hits below 5 %, the rest misses
    np.testing.assert_array_equal(second.kept["ray_distances"],
                                  np.where(np.isfinite(fresh.kept["ray_distances"]),
                                           fresh.kept["ray_distances"], np.inf))


def test_cli_refit_of_a_refit(files, tmp_path):
    first, second = tmp_path / "first.npz", tmp_path / "second.npz"
    result = run_cli("refit", files[2], "--max-distance", "20%", "--out", first)
    assert result.exit_code == 0, result.output
    result = run_cli("refit", first, "--max-distance", "5%", "--out", second)
    assert result.exit_code == 0, result.output
    assert second.exists()
