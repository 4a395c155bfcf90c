"""``-q thickness``: the mean distance through the inside to the back side, against closed
forms, with error bars that cover.

* a slab of thickness t under a max distance (cap) C >= t: a ray at angle theta to -n runs
  t / cos theta, capped at C, so T = t (2 - t / C) (cosine weighting) and
  T = t (1 + ln(C / t)) (uniform); exact for the box baked (its walls lie beyond C);
* the rays start inward of the point by its ray offset and are measured from there: behind
  a parallel surface each is short by offset / cos theta, 2 x offset on average (cosine), a
  bias every tolerance allows (``offset_bias``: from the report's largest offset);
* a sphere of radius r: the chord at angle theta is 2 r cos theta, T = 4 r / 3 (cosine).  The
  icosphere's facets lie inside the sphere by at most s (computed from the mesh), which
  shortens a chord by at most s / cos theta: a bias of at most 2 s under cosine weighting,
  added to every tolerance;
* the 95% intervals mean -+ 1.96 stderr cover the exact value in >= 93% of (point, seed)
  pairs, and RMS(error) / RMS(stderr) lies within its chi-square bounds;
* an open surface with nothing behind it: every ray misses, T is the cap exactly, its
  stderr the resolution C / n (never 0: not exact by construction);
* bit-identical for threads, executors and chunks; streamed (> 65536 rays) equals whole.

Tolerances are statistical bounds at a family-wise false-failure rate ``FWER`` per test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from scipy import stats

import aobake
from analytic import dof_for, z_bound

FWER = 1e-4
PROMISED = 0.93
THREADS = 2
#: the slab: thickness T_SLAB, cap C_SLAB, half-width beyond the cap's reach of the points
T_SLAB, C_SLAB, HALF = 0.2, 0.5, 1.5


def slab():
    return trimesh.creation.box(extents=(2 * HALF, 2 * HALF, T_SLAB))


def top_points(n, seed=3):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.5, 0.5, (n, 2))
    return np.column_stack([xy, np.full(n, T_SLAB / 2)]), np.tile([0.0, 0.0, 1.0], (n, 1))


def slab_exact(weighting):
    t, c = T_SLAB, C_SLAB
    return t * (2 - t / c) if weighting == "cosine" else t * (1 + math.log(c / t))


def sphere_points(n):
    mesh = trimesh.creation.icosphere(subdivisions=5)
    rng = np.random.default_rng(5)
    pick = rng.choice(len(mesh.vertices), n, replace=False)
    points = np.asarray(mesh.vertices)[pick]
    normals = points / np.linalg.norm(points, axis=1)[:, None]
    # the facets' largest depth below the unit sphere: r - the nearest facet plane's distance
    depth = 1.0 - float(np.einsum("ij,ij->i", mesh.face_normals,
                                  mesh.vertices[mesh.faces[:, 0]]).min())
    return mesh, points, normals, depth


def offset_bias(result) -> float:
    """The most the inward offset shortens a point's thickness on average: 2 x its offset."""
    return 2.0 * result.report["parameters"]["ray_offset_range"][1]


def thickness(mesh, points, normals, **options):
    return aobake.bake_points(mesh, points, normals, quantities=("thickness",),
                              threads=THREADS, **options)


@pytest.mark.parametrize("weighting", ["cosine", "uniform"])
@pytest.mark.parametrize("sampler", ["random", "sobol"])
def test_slab_with_a_cap_is_its_closed_form(sampler, weighting):
    rays, n = 1024, 40
    points, normals = top_points(n)
    result = thickness(slab(), points, normals, rays=rays, max_distance=C_SLAB,
                       sampler=sampler, weighting=weighting)
    assert result.report["parameters"]["thickness_cap"] == C_SLAB
    k = z_bound(4 * n, dof_for(sampler, rays), FWER)
    error = np.abs(result.thickness - slab_exact(weighting))
    # uniform weighting: E[offset / cos] over the uncapped rays is offset ln(C / t) < 2 offset
    assert (error <= k * result.thickness_stderr + offset_bias(result)).all()


def test_sphere_is_four_thirds_of_its_radius():
    mesh, points, normals, depth = sphere_points(40)
    rays = 4096
    result = thickness(mesh, points, normals, rays=rays)
    k = z_bound(len(points), dof_for("sobol", rays), FWER)
    error = np.abs(result.thickness - 4.0 / 3.0)
    assert (error <= k * result.thickness_stderr + 2 * depth + offset_bias(result)).all()
    assert 2 * depth < 1e-3  # the bias allowed is small against the value


@pytest.mark.slow
def test_intervals_cover_and_stderr_is_calibrated():
    """(point, seed) pairs of i.i.d. bakes at 64 rays: slab (capped) and sphere."""
    mesh, sphere_at, sphere_n, depth = sphere_points(60)
    slab_at, slab_n = top_points(60)
    errors, stderrs, margins = [], [], []
    for seed in range(10):
        for scene, at, n, exact, margin, cap in ((slab(), slab_at, slab_n,
                                                  slab_exact("cosine"), 0.0, C_SLAB),
                                                 (mesh, sphere_at, sphere_n, 4 / 3, 2 * depth,
                                                  math.inf)):
            result = thickness(scene, at, n, rays=64, sampler="random", seed=seed,
                               max_distance=cap)
            errors.append(result.thickness - exact)
            stderrs.append(result.thickness_stderr)
            margins.append(np.full(len(at), margin + offset_bias(result)))
    e, se, margin = map(np.concatenate, (errors, stderrs, margins))
    covered = int(np.count_nonzero(np.abs(e) <= stats.t.ppf(0.975, 63) * se + margin))
    assert stats.binom.cdf(covered, len(e), PROMISED) > FWER / 2, covered / len(e)
    # sum e^2 / se^2 ~ chi-square with len(e) degrees of freedom (approximately: se is
    # estimated from 64 rays, so the bounds are widened by the t(63) variance 63/61)
    ratio = float(np.sum(e ** 2) / np.sum(se ** 2))
    z = stats.norm.ppf(1 - FWER / 4)
    width = z * math.sqrt(2.0 / len(e)) * 63 / 61 + 2 * margin.max() / se.mean()
    assert 1 - width < ratio < 63 / 61 + width, ratio


def test_an_open_surface_counts_every_miss_at_the_cap():
    plane = trimesh.Trimesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]],
                            [[0, 1, 2], [0, 2, 3]], process=False)
    points, normals = np.array([[0.1, 0.2, 0.0], [-0.3, 0.0, 0.0]]), np.tile([0, 0, 1.0], (2, 1))
    for cap, expected in ((0.25, 0.25), (math.inf, math.sqrt(8.0))):  # else the diagonal
        result = thickness(plane, points, normals, rays=256, max_distance=cap)
        # every ray counts the cap: the mean of equal values, up to its float64 rounding
        np.testing.assert_allclose(result.thickness, expected, rtol=1e-15)
        np.testing.assert_allclose(result.thickness_stderr, expected / 256, rtol=1e-12)


@pytest.mark.slow
def test_bit_identical_for_threads_executors_chunks_and_streaming():
    points, normals = top_points(30)
    base = aobake.bake_points(slab(), points, normals, quantities=("ao", "thickness"),
                              rays=256, max_distance=C_SLAB, threads=1)
    for kw in ({"threads": 2, "chunk_rays": 1000}, {"executor": "processes", "workers": 2,
                                                    "chunk_points": 7}):
        other = aobake.bake_points(slab(), points, normals, quantities=("ao", "thickness"),
                                   rays=256, max_distance=C_SLAB, **kw)
        for name in ("thickness", "thickness_stderr", "ao"):
            np.testing.assert_array_equal(getattr(other, name), getattr(base, name))
    # more rays than one piece: streamed in pieces, the same moments as one pass up to
    # the summation order (Chan's update), so equal to float rounding
    many = thickness(slab(), points[:2], normals[:2], rays=1 << 17, max_distance=C_SLAB)
    error = np.abs(many.thickness - slab_exact("cosine"))
    k = z_bound(2, dof_for("sobol", 1 << 17), FWER)
    assert (error <= k * many.thickness_stderr + offset_bias(many)).all()


@pytest.mark.slow
def test_thickness_is_written_and_known_to_the_cli(tmp_path):
    from conftest import run_cli

    path = tmp_path / "slab.ply"
    slab().export(path)
    out = tmp_path / "t.npz"
    result = run_cli(path, "-q", "thickness", "--rays", 16, "--out", out)
    assert result.exit_code == 0, result.output
    with np.load(out) as data:
        assert np.isfinite(data["thickness"]).all() and (data["thickness"] > 0).all()
        assert "thickness_stderr" in data.files


@pytest.mark.slow
def test_a_lightmap_of_thickness_is_neither_clipped_nor_biased():
    """Texels average their samples' thickness; seam erasure keeps values above 1."""
    mesh = trimesh.creation.icosphere(subdivisions=3)
    depth = 1.0 - float(np.einsum("ij,ij->i", mesh.face_normals,
                                  mesh.vertices[mesh.faces[:, 0]]).min())
    plain = aobake.bake_texels(mesh, quantities=("thickness",), rays=64, resolution=64,
                               seams="off", threads=THREADS, sampler="random")
    value = plain.channels["thickness"][plain.covered].astype(np.float64)
    se = plain.channels["thickness_stderr"][plain.covered].astype(np.float64)
    # the texels' samples are disjoint: independent errors, so their mean's stderr is
    # sqrt(sum se^2) / N; the tessellation and offset biases are added
    mean_se = math.sqrt(float(np.sum(se ** 2))) / len(se)
    bias = 2 * depth + offset_bias(plain)
    assert abs(value.mean() - 4 / 3) <= z_bound(1, None, FWER) * mean_se + bias
    erased = aobake.bake_texels(mesh, quantities=("thickness",), rays=64, resolution=64,
                                threads=THREADS)
    assert erased.channels["thickness"][erased.covered].min() > 1.0
