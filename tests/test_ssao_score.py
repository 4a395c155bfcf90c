"""``aobake.screen.score``: RMSE, bias, PSNR, SSIM (Wang et al.'s settings), regions, the best
gain and errors in units of the reference's stderr."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from aobake.screen import score


def _images(seed=0, shape=(48, 64)):
    rng = np.random.default_rng(seed)
    reference = ndimage.gaussian_filter(rng.random(shape), 3)
    reference = (reference - reference.min()) / np.ptp(reference)
    candidate = np.clip(reference + 0.05 * rng.standard_normal(shape), 0, 1)
    return reference, candidate


def test_ssim_equals_wang_et_al_on_a_fully_covered_image():
    """Unmasked, away from the border, the map is Wang et al.'s: Gaussian-weighted means,
    variances and covariance (sigma 1.5, an 11 x 11 window), K1 = 0.01, K2 = 0.03, L = 1."""
    x, y = _images()
    mask = np.ones_like(x, dtype=bool)
    ours = score.ssim_map(x, y, mask)

    def g(a):  # scipy's Gaussian truncated at 5 pixels: the 11 x 11 window
        return ndimage.gaussian_filter(a, 1.5, truncate=5 / 1.5, mode="constant")

    mx, my = g(x), g(y)
    vx, vy, cxy = g(x * x) - mx ** 2, g(y * y) - my ** 2, g(x * y) - mx * my
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    wang = (2 * mx * my + c1) * (2 * cxy + c2) / ((mx ** 2 + my ** 2 + c1) * (vx + vy + c2))
    inner = (slice(5, -5), slice(5, -5))
    np.testing.assert_allclose(ours[inner], wang[inner], rtol=0, atol=1e-12)
    assert 0.2 < np.nanmean(ours) < 0.95


def test_identical_images_score_perfectly_and_masked_pixels_do_not_count():
    x, _ = _images()
    covered = np.ones_like(x, dtype=bool)
    covered[:, :10] = False
    other = x.copy()
    other[:, :10] = 1 - other[:, :10]  # differs only where nothing is covered
    result = score.score(x, other, covered)
    raw = result["regions"]["all"]["raw"]
    assert raw["rmse"] == 0 and raw["bias"] == 0 and raw["psnr"] == math.inf
    assert raw["ssim"] == pytest.approx(1.0, abs=1e-12)
    assert raw["pixels"] == covered.sum()


def test_rmse_bias_psnr_of_a_constant_offset():
    x, _ = _images()
    covered = np.ones_like(x, dtype=bool)
    result = score.score(x, x + 0.1, covered)["regions"]["all"]["raw"]
    assert result["rmse"] == pytest.approx(0.1) and result["bias"] == pytest.approx(0.1)
    assert result["psnr"] == pytest.approx(20.0)


def test_best_gain_of_the_occlusion_is_recovered_and_scored():
    x, _ = _images()
    covered = np.ones_like(x, dtype=bool)
    halved = 1 - 0.5 * (1 - x)  # an SSAO with its intensity knob at half
    result = score.score(x, halved, covered)
    assert result["gain"] == pytest.approx(2.0, rel=1e-12)
    assert result["regions"]["all"]["raw"]["rmse"] > 0.1
    assert result["regions"]["all"]["gained"]["rmse"] == pytest.approx(0.0, abs=1e-12)


def test_errors_in_units_of_the_reference_stderr():
    rng = np.random.default_rng(4)
    truth = np.full((40, 40), 0.7)
    stderr = np.full_like(truth, 0.02)
    reference = truth + stderr * rng.standard_normal(truth.shape)  # a noisy truth
    covered = np.ones_like(truth, dtype=bool)
    good = score.score(reference, truth, covered, stderr=stderr)["regions"]["all"]["raw"]
    assert 0.9 < good["z_rms"] < 1.1 and good["z_over_3"] < 0.01
    bad = score.score(reference, truth + 0.1, covered, stderr=stderr)["regions"]["all"]["raw"]
    assert bad["z_rms"] > 4 and bad["z_over_3"] > 0.9


def test_depth_edges_and_the_band_split_interior_from_edges():
    from test_ssao import _synthetic

    h, w = 30, 40
    depth = np.full((h, w), 2.0)
    depth[10:20, 15:25] = 1.5  # a box in front of a wall: its outline is a depth edge
    depth[:, 35:] = np.inf     # and the sky on the right
    normals = np.zeros((h, w, 3))
    normals[..., 2] = 1.0
    frame = _synthetic(depth, normals).frame()
    edges = score.depth_edges(frame)
    assert edges[10, 15:25].all() and edges[9, 15:25].all()  # both sides of the step
    assert edges[:, 34].all() and not edges[:, 35].any()     # the covered side only
    assert not edges[2:8, 2:12].any() and not edges[12:18, 17:23].any()
    regions = score.regions(frame.covered, edges, band=3)
    assert (regions["interior"] | regions["edges"] == frame.covered).all()
    assert not (regions["interior"] & regions["edges"]).any()
    assert regions["edges"][7, 20] and not regions["edges"][5, 20]


@pytest.mark.parametrize("shape", [(30, 40), (31, 41)])
def test_depth_edges_of_a_view_with_empty_pixels_warn_of_nothing(shape):
    """An empty pixel (depth inf) is not reconstructed: at odd sizes its centre ray has a
    zero component, and inf * 0 was 'invalid value encountered in multiply' on every
    ``aobake compare`` of such a view (an instanced set's, whose background is empty)."""
    import warnings

    from test_ssao import _synthetic

    h, w = shape
    depth = np.full((h, w), 2.0)
    depth[:, w // 2 + 5:] = np.inf   # sky through the centre row
    depth[h // 2 + 3:, :] = np.inf   # and through the centre column
    normals = np.zeros((h, w, 3))
    normals[..., 2] = 1.0
    frame = _synthetic(depth, normals).frame()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        edges = score.depth_edges(frame)
    covered = np.isfinite(depth)
    # the wall's border with the sky, its covered side only; nothing inside the wall
    border = covered & ~np.pad(covered, 1, constant_values=True)[2:, 1:-1] \
        | covered & ~np.pad(covered, 1, constant_values=True)[1:-1, 2:]
    np.testing.assert_array_equal(edges, border)


@pytest.mark.slow
def test_compare_of_views_with_empty_pixels_prints_no_numpy_warning(tmp_path):
    """``aobake compare truth.exr look.exr`` of odd-sized views with sky through the centre
    row and column: the scores, and no 'RuntimeWarning' line from the depth edges."""
    import trimesh
    from analytic import combine, quad
    from conftest import run_cli

    mesh = tmp_path / "pair.ply"
    combine(quad([0, 0, 0], 1.0, 1.0), trimesh.creation.icosphere(2, 0.3)).export(mesh)
    truth, look = tmp_path / "truth.exr", tmp_path / "look.exr"
    for out, method in ((truth, "rays"), (look, "crytek")):
        made = run_cli("view", mesh, "--method", method, "--out", out, "--size", "21x15",
                       "--rays", "2")
        assert made.exit_code == 0, made.output
    result = run_cli("compare", truth, look)
    assert result.exit_code == 0, result.output
    assert "RuntimeWarning" not in result.output and "invalid value" not in result.output
