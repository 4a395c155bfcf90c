"""``aobake view --pixel-filter box``: each pixel's value estimates the mean AO over its area.

These tests are of ``--box-sampling positions`` (each position a sample point of its own:
what every method that casts no rays uses) unless they say otherwise; the joint estimator
(the ray-traced method's default) has its own, tests/test_view_box_stratified.py, on the
same scene.

The oracle is a scene whose every pixel's area mean is known in closed form.  Seen straight
down from z = 0.4, a floor strip (z = 0, x < its edge) under an infinite ceiling at height
h = 0.5, with max distance D = h / sqrt(0.5): the cosine-weighted AO under a parallel
ceiling is (h / D)^2 = 0.5 everywhere on it.  Below, at z = -1 (farther than D from
everything), strips of AO exactly 1.  The strip's edge crosses one column of pixels at a
fraction f of their width, and the lower strips fill the bottom fraction g of every row, so
that column's pixels hold a step *inside* the pixel (0.5 on the left f, 1 on the right) and,
for g < 1, a silhouette (the rest sees nothing): coverage f + (1 - f) g, covered mean
(0.5 f + (1 - f) g) / coverage.  Pixels left of it are interior (0.5), right of it a
silhouette of AO 1 with coverage g.  Pixels of one column are independent trials of the
same truth, so one bake gives a hundred.

Tolerances: coverage of the 95% interval over n trials from binomial statistics (at least
0.95 - 3.5 sqrt(0.05 0.95 / n)); the stderr's calibration mean(e^2) / mean(se^2) at most
1.3 (its own noise over ~1000 trials is ~0.1).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import aobake
from aobake import occluders
from aobake.compare import compare
from aobake.scene import load_scene
from aobake.settings import BakeConfig
from aobake.targets.view import Footprint, ViewTarget, pool

import analytic
from conftest import run_cli

CEILING, EYE = analytic.STEP_CEILING, analytic.STEP_EYE
#: AO = (CEILING / D)^2 = 0.5 on the floor strip under the ceiling; the lower strips' drop
D = CEILING / math.sqrt(0.5)
DROP = max(1.0, 1.5 * D)
SIZE = (8, 128)
COLUMN = 3


def step_scene(f=0.35, g=1.0, size=SIZE, column=COLUMN):
    """(mesh, camera, truths) of ``analytic.step_scene`` with the strip's AO 0.5."""
    return analytic.step_scene(0.5, f, g, size, column)[:3]


COLUMNS = {"left": slice(0, COLUMN), "mixed": slice(COLUMN, COLUMN + 1),
           "right": slice(COLUMN + 1, None)}


def test_positions_are_a_pure_function_of_seed_pixel_and_position():
    config = BakeConfig(pixel_filter="box", pixel_samples=16, replicates=4)
    footprint = Footprint.of(config)
    assert (footprint.groups, footprint.per_group, footprint.grid) == (4, 4, (2, 2))
    every = footprint.offsets(7, np.arange(50))
    some = footprint.offsets(7, np.array([31, 2, 17]))
    np.testing.assert_array_equal(some, every[[31, 2, 17]])
    assert every.shape == (50, 16, 2) and (every >= 0).all() and (every < 1).all()
    # replicate g's position j lies in cell j of its 2 x 2 grid
    cells = np.floor(every * 2).astype(int)
    j = np.arange(16) % 4
    np.testing.assert_array_equal(cells[..., 0], np.broadcast_to(j % 2, (50, 16)))
    np.testing.assert_array_equal(cells[..., 1], np.broadcast_to(j // 2, (50, 16)))
    assert not np.array_equal(footprint.offsets(8, np.arange(50)), every)
    # i.i.d. positions with the i.i.d. sampler; sizes round up to whole replicates
    assert Footprint.of(BakeConfig(pixel_filter="box", sampler="random",
                                   pixel_samples=5)).positions == 5
    odd = Footprint.of(BakeConfig(pixel_filter="box", pixel_samples=5, replicates=4))
    assert (odd.groups, odd.per_group) == (4, 2)
    assert Footprint.of(BakeConfig()).positions == 1


def test_a_centre_view_says_so_and_is_unchanged():
    mesh, cam, _ = step_scene()
    centre = aobake.bake_view(mesh, camera=cam, rays=8, max_distance=D, seed=2)
    same = aobake.bake_view(mesh, camera=cam, rays=8, max_distance=D, seed=2,
                            pixel_filter="center")
    for name, channel in centre.channels.items():
        np.testing.assert_array_equal(channel, same.channels[name])
    record = centre.report["camera"]
    assert record["pixel_filter"] == "center"
    assert record["pixel_footprint"]["positions"] == 1
    assert set(record["pixel_footprint"]) == set(
        aobake.bake_view(mesh, camera=cam, rays=8, max_distance=D, pixel_filter="box",
                         pixel_samples=4).report["camera"]["pixel_footprint"])


def test_box_pixels_are_the_pooled_positions_bake_points_values():
    mesh, cam, _ = step_scene(size=(8, 6))
    config = BakeConfig(rays=16, seed=5, max_distance=D, pixel_filter="box", pixel_samples=8,
                        box_sampling="positions")
    target = ViewTarget(cam)
    view = aobake.bake_view(mesh, config, camera=cam)
    scene = load_scene(mesh)
    built = occluders.build(scene, config)
    plan = target.sample(scene, config, lambda: built, 1, {}, [])
    assert len(plan.ids) == len(np.unique(plan.ids))  # no two positions share a stream
    assert (plan.ids // 8 == plan.state["pixel"]).all()
    points = aobake.bake_points(mesh, plan.points, plan.normals, config,
                                rays=target.rays_per_point(config), point_ids=plan.ids,
                                point_sizes=plan.sizes)
    fields, rays = pool(config, plan.state["footprint"], plan.state,
                        _estimates(points), 48, scene.diagonal)
    covered = view.covered.ravel()
    for name in ("ao", "ao_stderr", "ao_ci_low", "ao_ci_high"):
        np.testing.assert_array_equal(view.channels[name].ravel()[covered],
                                      fields[name].astype(np.float32))
    np.testing.assert_array_equal(view.channels["rays"].ravel()[covered], rays)
    assert view.report["rays_cast"] == int(points.rays.sum())


def _estimates(result):
    from aobake.records import Estimates

    return Estimates(dict(result.values), result.rays)


def test_coverage_is_the_fraction_of_positions_and_the_g_buffer_stays_at_the_centre():
    # g = 0.3: right of the edge, the pixel's centre (half way down) sees nothing, its
    # bottom 30% the lower strips
    mesh, cam, truths = step_scene(f=0.35, g=0.3)
    view = aobake.bake_view(mesh, camera=cam, rays=4, max_distance=D, pixel_filter="box",
                            pixel_samples=16, seed=1, box_sampling="positions")
    ch = view.channels
    for region, (cover, _) in truths.items():
        got = ch["coverage"][:, COLUMNS[region]].astype(np.float64)
        # per pixel: 4 replicates of a 2 x 2 grid; the binomial's spread bounds theirs
        bound = 4 * math.sqrt(cover * (1 - cover) / 16 / got.size) + 1e-12
        assert abs(got.mean() - cover) <= bound, region
    np.testing.assert_array_equal(view.covered, ch["coverage"] > 0)
    # the G-buffer: the centre's hit (the floor at depth 0.4), else a position's (depth 1.4)
    left = ch["depth"][:, COLUMNS["left"]]
    np.testing.assert_allclose(left, EYE, rtol=1e-6)
    right = ch["depth"][:, COLUMNS["right"]][view.covered[:, COLUMNS["right"]]]
    np.testing.assert_allclose(right, EYE + DROP, rtol=1e-6)
    assert (ch["object_id"][view.covered] == 0).all()
    assert (ch["object_id"][~view.covered] == -1).all()
    assert (ch["depth"][~view.covered] == 0).all() and (ch["ao"][~view.covered] == 0).all()
    assert (ch["ao"][:, COLUMNS["right"]][view.covered[:, COLUMNS["right"]]] == 1).all()


@pytest.mark.parametrize("sampling", ["positions", "joint"])
def test_threads_and_chunks_change_no_bit(sampling):
    mesh, cam, _ = step_scene(size=(8, 16), g=0.5)
    options = dict(camera=cam, rays=8, max_distance=D, pixel_filter="box", pixel_samples=8,
                   seed=3, box_sampling=sampling)
    one = aobake.bake_view(mesh, threads=1, **options)
    two = aobake.bake_view(mesh, threads=2, chunk_rays=64, **options)
    for name, channel in one.channels.items():
        np.testing.assert_array_equal(channel, two.channels[name], err_msg=name)


@pytest.mark.slow
def test_command_line_report_camera_file_and_compare(tmp_path):
    mesh, cam, _ = step_scene(size=(8, 12), g=0.5)
    path = tmp_path / "steps.ply"
    mesh.export(path)
    camera = ["--look-from", "0,0,0.4", "--look-at", "0,0,0", "--up", "0,1,0", "--fov", "20",
              "--size", "8x12", "--max-distance", str(D)]
    truth, report = tmp_path / "truth.exr", tmp_path / "truth.json"
    result = run_cli("view", path, "--out", truth, "--report", report, "--pixel-filter", "box",
                     "--box-sampling", "positions", "--pixel-samples", "4", "--rays", "16",
                     *camera)
    assert result.exit_code == 0, result.output
    recorded = json.loads(report.read_text())
    assert recorded["config"]["pixel_filter"] == "box"
    assert recorded["config"]["pixel_samples"] == 4
    assert recorded["camera"]["pixel_filter"] == "box"
    assert recorded["camera"]["pixel_footprint"]["positions"] == 4
    assert recorded["camera"]["pixel_footprint"]["estimator"] == "positions"
    side = json.loads((tmp_path / "truth.camera.json").read_text())
    assert side["camera"]["pixel_filter"] == "box"
    look = tmp_path / "look.exr"
    assert run_cli("view", path, "--out", look, "--pixel-filter", "box", "--rays", "16",
                   "--seed", "1", *camera).exit_code == 0
    scored = compare(truth, look)
    assert scored["target"] == "view" and scored["n"] > 0
    assert scored["rmse_in_reference_se"] < 3


@pytest.mark.parametrize("args, code, message", [
    (["-q", "bent_normal"], 2, "not -q bent_normal"),
    (["--box-sampling", "stripes"], 2, "stripes"),
    (["--tolerance", "0.05"], 2, "not with --pixel-filter box"),
    (["--method", "gtao"], 2, "not with --pixel-filter box"),
])
def test_what_a_box_filter_cannot_do_is_refused(tmp_path, args, code, message):
    mesh, _, _ = step_scene(size=(8, 6))
    path = tmp_path / "steps.ply"
    mesh.export(path)
    result = run_cli("view", path, "--out", tmp_path / "v.exr", "--size", "8x6", "--rays", "4",
                     "--pixel-filter", "box", *args)
    assert result.exit_code == code, result.output
    assert message in result.output


def test_pixel_samples_without_a_box_filter_is_a_warning():
    mesh, cam, _ = step_scene(size=(8, 6))
    view = aobake.bake_view(mesh, camera=cam, rays=4, pixel_samples=4)
    assert any("--pixel-samples 4 is for --pixel-filter box" in w
               for w in view.report["warnings"])


#: (f, g): a step inside full pixels; a silhouette over nothing; both in one pixel
SCENES = [(0.35, 1.0), (0.9, 0.0), (0.5, 0.5)]


@pytest.mark.slow
@pytest.mark.parametrize("sampler", ["sobol", "random"])
@pytest.mark.parametrize("positions, rays", [(16, 16), (64, 64)])
@pytest.mark.parametrize("f, g", SCENES)
def test_the_interval_covers_the_pixel_mean(sampler, positions, rays, f, g):
    """(--box-sampling positions; the joint estimator: test_view_box_stratified.py)"""
    """Coverage of the 95% interval and calibration of the stderr over 8 seeds x 128 rows:
    interior pixels, a step inside the pixel, silhouettes."""
    mesh, cam, truths = step_scene(f=f, g=g)
    errors = {region: [] for region in truths}
    for seed in range(8):
        view = aobake.bake_view(mesh, camera=cam, rays=rays, max_distance=D, seed=seed,
                                sampler=sampler, pixel_filter="box", pixel_samples=positions,
                                box_sampling="positions")
        ch = view.channels
        for region, columns in COLUMNS.items():
            seen = ch["coverage"][:, columns] > 0
            value = ch["ao"][:, columns][seen].astype(np.float64)
            errors[region].append(np.stack([
                value - truths[region][1], ch["ao_stderr"][:, columns][seen],
                ch["ao_ci_low"][:, columns][seen] <= truths[region][1],
                ch["ao_ci_high"][:, columns][seen] >= truths[region][1]]))
    for region in ("left", "mixed"):
        error, se, above, below = np.concatenate(errors[region], axis=1)
        n = error.size
        covered = np.mean(above.astype(bool) & below.astype(bool))
        assert covered >= 0.95 - 3.5 * math.sqrt(0.05 * 0.95 / n), (region, covered)
        assert np.mean(error ** 2) <= 1.3 * np.mean(se ** 2), region


@pytest.mark.parametrize("sampling", ["joint", "positions"])
def test_pixels_on_faces_that_only_occlude_get_no_information_quietly(sampling):
    """--occluder-only faces cast no rays: a pixel whose positions all land there holds the
    no-information values (0.5, stderr 0.5, interval [0, 1]), with no warning on the way
    (joint: the target finds the faces from the patterns, ``view_box.receiving_faces``)."""
    import warnings
    from pathlib import Path

    still_life = Path(__file__).resolve().parents[1] / "assets" / "still_life.obj"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        view = aobake.bake_view(still_life, size=(24, 18), rays=8, pixel_filter="box",
                                pixel_samples=4, occluder_only=("floor",),
                                box_sampling=sampling)
    ch = view.channels
    blind = view.covered & (ch["rays"] == 0)
    assert blind.any() and (view.covered & (ch["rays"] > 0)).any()
    assert (ch["ao"][blind] == 0.5).all() and (ch["ao_stderr"][blind] == 0.5).all()
    assert (ch["ao_ci_low"][blind] == 0).all() and (ch["ao_ci_high"][blind] == 1).all()
