"""--tolerance: coverage of the final interval and stopping bias at true values from 0 to 1,
for every sampler, on closed-form scenes; the extremes (tolerance 0, >= 0.5, a one-ray
pilot); the report's accounting.

A point at the origin under a coaxial 64-gon of radius a at height 1 sees AO ~ 1 / (1 + a^2)
(exact: Lambert's polygon formula at its ray origin, ``test_coverage.exact_ao``); AO 0 is a
point inside a closed box, AO 1 a point above a floor with nothing over it.  N points at the
same place with distinct ids are N independent trials.
"""

import math

import numpy as np
import pytest
import trimesh
from scipy import stats

import aobake
from aobake.samplers import SAMPLERS
from analytic import up
from conftest import run_cli
from test_coverage import FWER, coverage_p_value, disc, exact_ao

TRUE_AO = (0.0, 1e-3, 0.01, 0.1, 0.5, 0.9, 0.999, 1.0)
E = 0.02
POINTS = 500
PILOT = 64
MAX_RAYS = 16384


def scene(ao: float):
    """(mesh, points (POINTS, 3), exact AO function of the result or None when exact by
    construction)."""
    points = np.zeros((POINTS, 3))
    if ao == 0.0:
        return trimesh.creation.box(extents=(2.0, 2.0, 2.0)), points, None
    if ao == 1.0:
        return disc([0.0, 0.0, -1.0], 1.0, 16), points, None
    mesh = disc([0.0, 0.0, 1.0], math.sqrt(1.0 / ao - 1.0), 64)
    return mesh, points, mesh.vertices[1:]


@pytest.mark.slow
@pytest.mark.parametrize("ao", TRUE_AO)
def test_final_interval_covers_and_is_unbiased(sampler, ao):
    mesh, points, ring = scene(ao)
    normals = up(POINTS)
    res = aobake.bake_points(mesh, points, normals, rays=PILOT, tolerance=E, max_rays=MAX_RAYS,
                             sampler=sampler, threads=2)
    exact = np.full(POINTS, ao) if ring is None else exact_ao(ring, points, normals,
                                                              res.report, mesh)
    if ring is not None:  # the polygon is close to the disc it stands for
        assert abs(exact.mean() - ao) < 0.05 * max(ao, 1 - ao)
    covered = (res.ao_ci_low <= exact) & (exact <= res.ao_ci_high)
    tests = len(SAMPLERS) * len(TRUE_AO)
    alpha = FWER / (2 * tests)
    k = int(covered.sum())
    assert coverage_p_value(k, POINTS) >= alpha, f"coverage {k / POINTS:.3f}"
    # Stopping bias at most 0.1 E: the mean error, up to its own sampling noise.
    error = res.ao - exact
    z = stats.norm.ppf(1 - alpha / 2)
    assert abs(error.mean()) <= 0.1 * E + z * error.std(ddof=1) / math.sqrt(POINTS)
    # The accounting: every point met E, missed or was capped; rays = pilot + its stages,
    # each stage at most MAX_RAYS and a further one at least twice the one before, so all
    # the stages together stay below twice the cap.
    t = res.report["tolerance"]
    assert t["points_met"] + t["points_missed"] + t["points_capped"] >= POINTS
    assert t["rays_total"] == int(res.rays.astype(np.int64).sum())
    assert t["final_rays"]["max"] <= MAX_RAYS
    assert res.rays.min() > PILOT and res.rays.max() < PILOT + 2 * MAX_RAYS
    reach = np.maximum(res.ao - res.ao_ci_low, res.ao_ci_high - res.ao)
    assert t["points_met"] == int(np.count_nonzero(reach <= E))
    # Most points meet E in one go (the variance bound is a 75% one).
    assert t["points_met"] >= 0.5 * POINTS


@pytest.mark.slow
def test_exact_values_meet_the_tolerance_without_the_cap():
    """A point exactly 0 or 1: every ray agrees, the rule of three alone bounds it."""
    for ao in (0.0, 1.0):
        mesh, points, _ = scene(ao)
        res = aobake.bake_points(mesh, points[:10], up(10), rays=PILOT, tolerance=E)
        assert np.all(res.ao == ao)
        assert res.report["tolerance"]["points_met"] == 10
        assert np.all(np.maximum(res.ao - res.ao_ci_low, res.ao_ci_high - res.ao) <= E)


def test_tolerance_zero_stops_at_the_cap():
    mesh, points, _ = scene(0.5)
    res = aobake.bake_points(mesh, points[:4], up(4), rays=8, tolerance=0.0, max_rays=512)
    t = res.report["tolerance"]
    assert t["points_capped"] == 4 and t["points_met"] == 0
    assert np.all(res.rays == 8 + 512)


def test_one_ray_pilot():
    mesh, points, ring = scene(0.5)
    res = aobake.bake_points(mesh, points[:50], up(50), rays=1, tolerance=0.05)
    assert res.report["tolerance"]["points_met"] + res.report["tolerance"]["points_missed"] == 50
    assert np.all(res.rays > 1)


def test_final_rays_are_independent_of_the_pilot():
    """The final stage draws from its own key stream: its rays are not the pilot's."""
    from aobake.samplers import point_key

    assert point_key(0, 1) != point_key(0, 0)


@pytest.mark.parametrize("value", ["0.5", "0.7", "-0.1"])
def test_tolerance_out_of_range_is_a_usage_error(box_ply, tmp_path, value):
    res = run_cli(box_ply, "--out", tmp_path / "x.npz", "--tolerance", value)
    assert res.exit_code == 2 and "--tolerance" in res.output
    with pytest.raises(aobake.InputError, match="tolerance"):
        aobake.BakeConfig(tolerance=float(value))


@pytest.mark.slow
def test_cli_reports_the_tolerance(box_ply, tmp_path):
    import json

    res = run_cli(box_ply, "--out", tmp_path / "x.npz", "--tolerance", "0.05", "--max-rays",
                  "2048", "--report", tmp_path / "r.json")
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["config"]["tolerance"] == 0.05 and report["tolerance"]["max_rays"] == 2048
    rays = np.load(tmp_path / "x.npz")["rays"]
    assert report["tolerance"]["rays_total"] == report["rays_cast"]
    assert rays.max() <= report["config"]["rays"] + 2048


@pytest.mark.slow
def test_lightmap_with_a_tolerance(tmp_path):
    """Texel samples meet E on their own; a texel (the mean of K) is narrower still, and its
    rays channel counts pilot + final rays."""
    from pathlib import Path

    asset = Path(__file__).resolve().parent.parent / "assets" / "torus_uv.obj"
    res = aobake.bake_texels(asset, rays=32, tolerance=0.05, resolution=32, padding=1,
                             texel_samples=2)
    t = res.report["tolerance"]
    covered = res.covered
    ao, low, high = (res.channels[c][covered] for c in ("ao", "ao_ci_low", "ao_ci_high"))
    reach = np.maximum(ao - low, high - ao)
    assert np.all(low <= ao) and np.all(ao <= high)
    assert np.mean(reach <= 0.05) >= t["points_met"] / (t["points_met"] + t["points_missed"]
                                                       + t["points_capped"]) - 1e-9
    assert res.channels["rays"][covered].min() > 2 * 16  # every sample: a pilot and a final


@pytest.mark.slow
def test_tolerance_bakes_are_reproducible_whatever_the_threads(sampler):
    mesh, points, _ = scene(0.5)
    a = aobake.bake_points(mesh, points[:40], up(40), rays=16, tolerance=0.05, sampler=sampler,
                           threads=1, chunk_rays=100)
    b = aobake.bake_points(mesh, points[:40], up(40), rays=16, tolerance=0.05, sampler=sampler,
                           threads=2)
    for name, array in a.fields().items():
        np.testing.assert_array_equal(array, b.fields()[name], err_msg=name)


def test_met_missed_and_capped_are_disjoint_and_add_up():
    """Every traced point is in exactly one of the three counts (a capped point that met E
    anyway is met), on points and on a lightmap's samples."""
    mesh, points, _ = scene(0.5)
    res = aobake.bake_points(mesh, points[:30], up(30), rays=8, tolerance=0.02, max_rays=64)
    t = res.report["tolerance"]
    assert t["points_met"] + t["points_missed"] + t["points_capped"] == 30
    assert t["points_capped"] > 0  # 64 rays cannot reach 0.02 at AO 0.5


def test_a_tolerance_that_bounds_nothing_baked_is_refused():
    with pytest.raises(aobake.InputError, match="ao and obscurance"):
        aobake.BakeConfig(tolerance=0.05, quantities=("bent_normal",))


@pytest.mark.slow
def test_the_summary_line_says_more_when_the_tolerance_cast_more(tmp_path, box_ply):
    from conftest import run_cli

    result = run_cli(box_ply, "--out", tmp_path / "ao.npz", "--rays", "4096",
                     "--tolerance", "0.2", "--max-rays", "8")
    assert result.exit_code == 0, result.output
    assert "more than a fixed count" in result.output and "0.0x" not in result.output


def test_points_left_wide_cast_further_stages_until_met_or_capped(monkeypatch):
    """Pilots made to under-estimate (a 5% variance bound instead of 75%, i.i.d. rays) leave
    many final stages wider than E; further fresh stages (key streams 2, 3, ...) bring every
    point to E or to the cap: "missed" is gone, and the counts add up."""
    from aobake import adaptive
    from aobake.trace import Tracer

    stages = []
    original = Tracer.with_rays

    def recording(self, rays, stage):
        stages.append(stage)
        return original(self, rays, stage)

    monkeypatch.setattr(adaptive, "VARIANCE_BOUND", 0.05)
    monkeypatch.setattr(Tracer, "with_rays", recording)
    mesh, points, _ = scene(0.5)
    res = aobake.bake_points(mesh, points[:200], up(200), rays=16, tolerance=0.05,
                             max_rays=4096, sampler="random")
    t = res.report["tolerance"]
    reach = np.maximum(res.ao - res.ao_ci_low, res.ao_ci_high - res.ao)
    assert max(stages) >= 2, "no point needed a further stage: the test lost its purpose"
    assert t["points_missed"] == 0
    assert t["points_met"] == int(np.count_nonzero(reach <= 0.05))
    assert t["points_met"] + t["points_capped"] == 200
