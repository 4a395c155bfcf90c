"""One bake, many falloffs: ``aobake refit`` from kept ray distances equals a fresh bake of
the same seed with the new max distance and tau, bit for bit, without tracing."""

from pathlib import Path

import numpy as np
import pytest

import aobake
from aobake.refit import refit
from aobake.samplers import SAMPLERS
from aobake.samplers import base as samplers_base
from conftest import run_cli

ASSET = Path(__file__).resolve().parent.parent / "assets" / "still_life.obj"
BAKED = dict(quantities=("ao", "obscurance"), rays=24, max_distance="40%", tau=1.0)


def _assert_same(a, b):
    assert a.fields().keys() == b.fields().keys()
    for name, array in a.fields().items():
        np.testing.assert_array_equal(array, b.fields()[name], err_msg=name)


@pytest.fixture(scope="module")
def kept():
    """One bake per sampler, keeping its distances (the fresh bakes vary tau and D)."""
    return {sampler: aobake.bake(ASSET, sampler=sampler, keep_distances=True, seed=3, **BAKED)
            for sampler in SAMPLERS}


@pytest.mark.slow
@pytest.mark.parametrize("tau, distance", [(None, None), (0.0, "40%"), (3.0, "10%"),
                                           (float("inf"), "1%"), (0.25, 0.0), (7.0, 0.3)])
def test_refit_equals_a_fresh_bake(kept, sampler, tau, distance):
    again = refit(kept[sampler], tau=tau, max_distance=distance)
    options = dict(BAKED, sampler=sampler, seed=3)
    if tau is not None:
        options["tau"] = tau
    if distance is not None:
        options["max_distance"] = distance
    _assert_same(again, aobake.bake(ASSET, **options))


@pytest.mark.slow
def test_refit_with_a_ground_plane_and_backfaces_ignored():
    options = dict(quantities=("ao", "obscurance"), rays=16, ground_plane=True,
                   backfaces="ignore", max_distance="50%", seed=1)
    first = aobake.bake(ASSET, keep_distances=True, **options)
    _assert_same(refit(first, tau=2.0, max_distance="5%"),
                 aobake.bake(ASSET, **dict(options, tau=2.0, max_distance="5%")))


def test_refit_of_streamed_points(monkeypatch):
    """Points whose rays stream in pieces: the refit folds the same pieces."""
    monkeypatch.setattr(samplers_base, "PIECE_RAYS", 64)
    import trimesh

    box = trimesh.creation.box()
    points = np.array([[0.7, 0.1, -0.5], [1.2, 0.0, -0.5]])
    normals = np.array([[0.0, 0.0, 1.0]] * 2)
    options = dict(quantities=("ao", "obscurance"), rays=512, sampler="random", seed=2)
    first = aobake.bake_points(box, points, normals, keep_distances=True, **options)
    assert aobake.samplers.sample_set("random", 512).piece < 512
    _assert_same(refit(first, tau=5.0, max_distance=0.8),
                 aobake.bake_points(box, points, normals,
                                    **dict(options, tau=5.0, max_distance=0.8)))


@pytest.mark.slow
def test_refit_through_the_cli_and_npz(tmp_path):
    baked = tmp_path / "kept.npz"
    res = run_cli(ASSET, "-o", baked, "--keep-distances", "-q", "ao", "--rays", 16,
                  "--max-distance", "30%")
    assert res.exit_code == 0, res.output
    with np.load(baked) as data:
        assert data["ray_distances"].dtype == np.float32
        assert data["ray_distances"].shape[1] == 16 and len(data["ray_point"]) == len(data["ao"])
    out = tmp_path / "refit.ply"
    res = run_cli("refit", baked, "-o", out, "--tau", "2", "--max-distance", "10%")
    assert res.exit_code == 0, res.output
    assert "no rays traced" in res.output and out.exists()
    npz = tmp_path / "refit.npz"
    assert run_cli("refit", baked, "-o", npz, "--max-distance", "10%").exit_code == 0
    fresh = aobake.bake(ASSET, rays=16, max_distance="10%")
    with np.load(npz) as data:
        np.testing.assert_array_equal(data["ao"], fresh.ao.astype(np.float32))


@pytest.mark.slow
def test_refit_refusals(tmp_path, kept):
    with pytest.raises(aobake.InputError, match="beyond the baked"):
        refit(kept["sobol"], max_distance="50%")
    with pytest.raises(aobake.InputError, match="directions"):
        refit(kept["sobol"], quantities=["bent_normal"])
    plain = tmp_path / "plain.npz"
    assert run_cli(ASSET, "-o", plain, "--rays", 8).exit_code == 0
    res = run_cli("refit", plain, "-o", tmp_path / "x.npz", "--tau", "1")
    assert res.exit_code == 1 and "--keep-distances" in res.output
    assert "Traceback" not in res.output
    res = run_cli("refit", tmp_path / "missing.npz", "-o", tmp_path / "x.npz")
    assert res.exit_code == 1 and "missing.npz" in res.output
    res = run_cli(ASSET, "-o", tmp_path / "x.ply", "--keep-distances")
    assert res.exit_code == 2 and ".npz" in res.output
    with pytest.raises(aobake.InputError, match="tolerance"):
        aobake.BakeConfig(keep_distances=True, tolerance=0.1)
    with pytest.raises(aobake.InputError, match="lightmaps"):
        aobake.bake_texels(ASSET, keep_distances=True, resolution=16)
