"""Closed-form scenes: estimates within k standard errors of the exact value.

k comes from the distribution of (estimate - exact) / stderr (Student-t with the
stderr's degrees of freedom, Bonferroni over the points tested, family-wise
false-failure rate 1e-4): see ``analytic.z_bound``.

For the i.i.d. ``random`` sampler every point is tested on its own.  For the
randomised-QMC samplers the per-point stderr comes from 8 replicates, whose
means are quantised at 1/m: a per-point t-test on the stderr alone is not valid
there (the intervals are, see tests/test_coverage.py); they are tested on the
mean over points.  Every point is randomised independently (aobake.samplers), so
the mean of N point errors has standard deviation sqrt(sum se^2) / N, and that is
the tolerance (the calibration tests check the per-point stderr over seeds).

Every test runs once per tracing backend (the ``backend`` fixture): Embree, and the float64
numpy reference, which is slow (every ray against every face) but these scenes have at most
24 triangles, so it needs no reduced workload here.
"""

import math

import numpy as np
import pytest

import aobake
from analytic import (ceiling_obscurance, dof_for, floor_and_ceiling, floor_points, polygon,
                      polygon_form_factor, quad, solid_angle, up, z_bound)


def check(estimate, stderr, exact, sampler, rays):
    """Per-point test for i.i.d. sampling, mean-over-points test for the QMC samplers."""
    estimate, stderr = np.asarray(estimate), np.asarray(stderr)
    if sampler == "random":
        assert_within(estimate, stderr, exact, z_bound(len(estimate), dof_for(sampler, rays)))
    else:
        error = np.mean(estimate - exact)
        # Independent points: sd(mean) = sqrt(sum se^2) / N.
        stderr_mean = np.sqrt(np.sum(np.square(stderr))) / len(stderr)
        k = z_bound(1, dof_for(sampler, rays))  # conservative: dof of a single point's stderr
        assert abs(error) <= k * stderr_mean, (error, stderr_mean, k)


def assert_within(estimate, stderr, exact, k):
    estimate, stderr = np.asarray(estimate), np.asarray(stderr)
    bad = np.abs(estimate - exact) > k * stderr
    assert not bad.any(), (
        f"{bad.sum()} points off by more than {k:.2f} stderr: "
        f"estimates {estimate[bad][:5]}, stderr {stderr[bad][:5]}, exact {exact}")


@pytest.mark.slow
def test_open_plane_is_fully_open(sampler, backend):
    mesh = quad([0, 0, 0], 5, 5)
    pts, nrm = floor_points(16, 4.0)
    res = aobake.bake_points(mesh, pts, nrm, backend=backend, rays=64, sampler=sampler,
                             quantities=("ao", "obscurance", "bent-normal"))
    assert res.report["parameters"]["backend"] == backend
    # Every ray escapes, but nothing proves the hemisphere empty: the error is the
    # resolution of n rays, and the interval the rule of three (aobake.stats.error_bars).
    n = res.rays[0]
    h0 = 1 - 0.05 ** (1 / n)
    assert np.all(res.ao == 1.0) and np.all(res.ao_stderr == 1 / n)
    np.testing.assert_allclose(res.ao_ci_low, 1 - h0, rtol=1e-12)
    assert np.all(res.ao_ci_high == 1.0)
    assert np.all(res.obscurance == 1.0) and np.all(res.obscurance_stderr == 1 / n)
    np.testing.assert_allclose(np.linalg.norm(res.bent_normal, axis=1), 1.0, atol=1e-12)
    # Bent normal of an open hemisphere is the normal itself (up to the sampling noise).
    assert np.all(res.bent_normal[:, 2] > 0.9)


@pytest.mark.slow
def test_inside_closed_box_is_fully_occluded(sampler, backend):
    import trimesh

    box = trimesh.creation.box(extents=[2, 2, 2])
    rng = np.random.default_rng(2)
    pts = rng.uniform(-0.8, 0.8, size=(20, 3))
    nrm = rng.normal(size=(20, 3))
    res = aobake.bake_points(box, pts, nrm, backend=backend, rays=128, sampler=sampler,
                             quantities=("ao", "obscurance", "bent-normal"))
    n = res.rays[0]
    assert np.all(res.ao == 0.0) and np.all(res.ao_stderr == 1 / n)
    assert np.all(res.ao_ci_low == 0.0)
    np.testing.assert_allclose(res.ao_ci_high, 1 - 0.05 ** (1 / n), rtol=1e-12)
    # No escaping ray: the bent normal falls back to the normal.
    np.testing.assert_allclose(res.bent_normal, nrm / np.linalg.norm(nrm, axis=1)[:, None])
    # ... and its angular error is the no-information pi/2.
    np.testing.assert_array_equal(res.bent_normal_stderr, np.pi / 2)
    # Obscurance inside: every rho(L) < 1, so strictly below 1 and above 0.
    assert np.all((res.obscurance > 0) & (res.obscurance < 1))


def test_floor_under_ceiling_with_max_distance(sampler, weighting, backend):
    # The escape indicator is a step in the elevation sample; a Sobol replicate of 32
    # rays counts floor or ceil of 32 x (escape fraction) escapes.  d is chosen so that
    # 32 (h/d) = 14.5 and 32 (h/d)^2 = 6.6 are far from integers: the replicates then
    # differ and the test sees a stderr (at an integer the net integrates the step
    # exactly, with zero spread).
    h, d = 1.0, 2.2
    # A ray at cos(theta) = c reaches the ceiling at h / c: it escapes iff c < h / d.
    # Cosine measure: P(c < h/d) = (h/d)^2; uniform (c uniform on [0, 1]): h / d.
    exact = (h / d) ** 2 if weighting == "cosine" else h / d
    # The ceiling covers every direction with L <= d from the sampled floor region.
    reach = math.sqrt(d * d - h * h) + 1.0
    mesh = floor_and_ceiling(h, reach + 1)
    pts, nrm = floor_points(32, 0.5)
    rays = 256
    res = aobake.bake_points(mesh, pts, nrm, backend=backend, rays=rays, max_distance=d, sampler=sampler,
                             weighting=weighting)
    check(res.ao, res.ao_stderr, exact, sampler, rays)
    assert np.any(res.ao_stderr > 0)


@pytest.mark.slow
def test_floor_under_tessellated_disc(sampler, backend):
    h, radius, sides = 0.7, 1.3, 24
    disc = polygon([0, 0, h], radius, sides)
    corners = disc.vertices[1:]
    rng = np.random.default_rng(3)
    pts = np.zeros((24, 3))
    pts[:, :2] = rng.uniform(-2.0, 2.0, size=(24, 2))
    pts[0] = 0.0
    nrm = up(len(pts))
    res = aobake.bake_points(disc, pts, nrm, backend=backend, rays=512, sampler=sampler)
    exact = np.array([1 - polygon_form_factor(p, [0, 0, 1], corners) for p in pts])
    check(res.ao - exact, res.ao_stderr, 0.0, sampler, 512)
    # Sanity of the oracle: the coaxial point matches the disc's h^2 / (h^2 + R^2)
    # up to the tessellation (the polygon is inside the disc, so it occludes less).
    assert exact[0] >= h**2 / (h**2 + radius**2)


def test_uniform_weighting_is_the_open_solid_angle(sampler, backend):
    """--weighting uniform (libigl's and xNormal's convention) estimates (1/2pi) int V dw: under a
    polygon that is 1 - solid angle / 2pi (cosine AO would be 1 - form factor)."""
    h, radius, sides = 0.7, 1.3, 24
    disc = polygon([0, 0, h], radius, sides)
    corners = disc.vertices[1:]
    pts = np.zeros((16, 3))
    pts[1:, :2] = np.random.default_rng(4).uniform(-1.5, 1.5, size=(15, 2))
    nrm = up(len(pts))
    res = aobake.bake_points(disc, pts, nrm, backend=backend, rays=512, sampler=sampler, weighting="uniform")
    exact = np.array([1 - solid_angle(p, corners) / (2 * math.pi) for p in pts])
    check(res.ao - exact, res.ao_stderr, 0.0, sampler, 512)
    cosine = np.array([1 - polygon_form_factor(p, [0, 0, 1], corners) for p in pts])
    # A different quantity, not a resampling: under the centre, cos(a) against cos^2(a).
    assert exact[0] - cosine[0] > 0.2
    assert res.report["conventions"]["ao"].startswith("uniform-weighted visibility")


@pytest.mark.parametrize("tau", [0.5, 3.0])
def test_obscurance_under_ceiling_exponential_integrals(tau, weighting, backend):
    h, d = 0.5, 1.5
    reach = math.sqrt(d * d - h * h) + 1.0
    mesh = floor_and_ceiling(h, reach + 1)
    pts, nrm = floor_points(32, 0.5)
    res = aobake.bake_points(mesh, pts, nrm, backend=backend, rays=256, max_distance=d, tau=tau,
                             quantities=("obscurance",), sampler="random", weighting=weighting)
    assert res.ao is None and res.bent_normal is None  # only what was asked
    exact = ceiling_obscurance(h, d, tau, weighting)
    assert_within(res.obscurance, res.obscurance_stderr, exact, z_bound(len(pts), None))


def test_bent_normal_beside_wall_tilts_by_atan_2_over_pi(backend):
    # A wall (plane x = 0) far larger than the distance to it: the unoccluded set
    # is the half-hemisphere x > 0.
    wall = quad([0, 0, 50], 1e3, 50, axis_u=1, axis_v=2)
    n = 64
    pts = np.zeros((n, 3))
    pts[:, 0] = 1e-3
    pts[:, 1] = np.linspace(-1, 1, n)
    nrm = up(n)
    res = aobake.bake_points(wall, pts, nrm, backend=backend, rays=1024, sampler="random",
                             quantities=("ao", "bent-normal"))
    assert_within(res.ao, res.ao_stderr, 0.5, z_bound(n, None))
    angle = np.arctan2(res.bent_normal[:, 0], res.bent_normal[:, 2])
    assert np.all(res.bent_normal[:, 0] > 0)  # tilts away from the wall
    # Points are independent (different ids): the error of the mean angle follows from their spread.
    stderr_mean = angle.std(ddof=1) / math.sqrt(n)
    k = z_bound(1, n - 1)
    assert abs(angle.mean() - math.atan(2 / math.pi)) <= k * stderr_mean
    assert abs(np.mean(res.bent_normal[:, 1])) <= k * res.bent_normal[:, 1].std(ddof=1) / math.sqrt(n)
    # Per point, against the reported angular error: the error is a 2-D angle whose squared
    # length has expectation stderr^2; the 1-D normal bound is the conservative one.
    tilt = math.atan(2 / math.pi)
    exact = np.array([math.sin(tilt), 0.0, math.cos(tilt)])
    error = np.arccos(np.clip(res.bent_normal @ exact, -1.0, 1.0))
    assert np.all(error <= z_bound(n, None) * res.bent_normal_stderr)
    # (The points share elevation samples, so their errors are correlated: the calibration
    # of the angular error over independent seeds is in test_calibration.)
