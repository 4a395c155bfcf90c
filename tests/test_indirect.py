"""``-q indirect``: the ray-traced truth of indirect light, against a closed form.

Two facing planes, a floor (normal +z) and a ceiling at height h (normal -z), both far
wider than the max distance D > h, so within D they are infinite.  From either plane a
cosine ray hits the other within D with probability 1 - a, a = (h/D)^2 (the cosine AO of
a point under an infinite ceiling with max distance D).  A path from the floor escapes
after exactly k reflections with probability (1 - a)^k a, so with albedo rho and N
bounces the indirect light is sum_{k=1..N} rho^k (1 - a)^k a (uniform first rays: the
first hit has probability 1 - h/D instead of 1 - a).
"""

from __future__ import annotations

import numpy as np
import pytest

import aobake

from analytic import combine, quad
from test_coverage import FWER, coverage_p_value

H, D, HALF = 0.5, 1.0, 12.0
POINTS = 300
SEEDS = 4


def _planes():
    return combine(quad([0, 0, 0], HALF, HALF), quad([0, 0, H], HALF, HALF, flip=True))


def exact(rho: float, bounces: int, weighting: str = "cosine") -> float:
    a = (H / D) ** 2
    first = 1 - a if weighting == "cosine" else 1 - H / D
    return sum(first * (1 - a) ** (k - 1) * rho ** k * a for k in range(1, bounces + 1))


def _points(n):
    points = np.zeros((n, 3))
    points[:, 0] = np.linspace(-1.0, 1.0, n)
    points[:, 1] = np.linspace(0.5, -0.5, n)
    return points, np.tile([0.0, 0.0, 1.0], (n, 1))


@pytest.mark.parametrize("sampler", ["random", "sobol"])
@pytest.mark.parametrize("rho, bounces, weighting", [(0.5, 1, "cosine"), (0.8, 3, "cosine"),
                                                     (0.5, 2, "uniform")])
def test_intervals_cover_the_closed_form(sampler, rho, bounces, weighting):
    """The 95% intervals of independent points over seeds cover the exact value in at least
    93% of trials (one-sided binomial test at FWER / cases), with 32 rays; and the mean
    over all points is unbiased within its own standard error (z at the same level)."""
    from scipy import stats

    mesh = _planes()
    points, normals = _points(POINTS)
    truth = exact(rho, bounces, weighting)
    covered, values, errors = 0, [], []
    for seed in range(SEEDS):
        res = aobake.bake_points(mesh, points, normals, rays=32, seed=seed, sampler=sampler,
                                 quantities=("indirect",), max_distance=D, albedo=rho,
                                 bounces=bounces, weighting=weighting)
        covered += int(np.count_nonzero((res.indirect_ci_low <= truth)
                                        & (truth <= res.indirect_ci_high)))
        values.append(res.indirect)
        errors.append(res.indirect_stderr)
    cases = 2 * 3
    n = POINTS * SEEDS
    assert coverage_p_value(covered, n) >= FWER / cases, f"coverage {covered / n:.3f}"
    values = np.concatenate(values)
    z = stats.norm.ppf(1 - FWER / cases / 2)
    assert abs(values.mean() - truth) <= z * values.std(ddof=1) / np.sqrt(n)


def test_a_black_world_has_no_indirect_light_exactly():
    points, normals = _points(20)
    res = aobake.bake_points(_planes(), points, normals, rays=16, quantities=("indirect",),
                             max_distance=D, albedo=0.0)
    assert (res.indirect == 0).all() and (res.indirect_stderr == 0).all()


def test_an_open_point_sees_no_indirect_light():
    """Nothing above a lone floor: every first ray escapes (that is AO, not indirect)."""
    points, normals = _points(10)
    res = aobake.bake_points(quad([0, 0, 0], HALF, HALF), points, normals, rays=16,
                             quantities=("ao", "indirect"), albedo=0.9)
    assert (res.ao == 1).all() and (res.indirect == 0).all()


def test_indirect_with_backfaces_ignored_is_refused():
    with pytest.raises(aobake.InputError, match="backfaces"):
        aobake.BakeConfig(quantities=("indirect",), backfaces="ignore")
    for bad in (dict(albedo=1.5), dict(albedo=-0.1), dict(bounces=0)):
        with pytest.raises(aobake.InputError):
            aobake.BakeConfig(quantities=("indirect",), **bad)


@pytest.mark.slow
def test_indirect_is_the_same_for_any_threads_and_split():
    points, normals = _points(40)
    options = dict(rays=16, quantities=("ao", "indirect"), max_distance=D, albedo=0.7,
                   bounces=2, seed=9)
    a = aobake.bake_points(_planes(), points, normals, threads=1, **options)
    b = aobake.bake_points(_planes(), points, normals, threads=2, chunk_rays=48,
                           executor="processes", workers=2, chunk_points=7, **options)
    for name in ("indirect", "indirect_stderr", "ao"):
        np.testing.assert_array_equal(a.values[name], b.values[name])


def test_streamed_points_give_the_unstreamed_values(monkeypatch):
    """A point whose rays exceed one piece streams them; the path samples follow the sample
    index, so the result equals one piece's up to the order of the float sums (Chan's
    update, ~1e-16 relative, as obscurance's in test_streaming)."""
    from aobake.samplers import base

    points, normals = _points(3)
    options = dict(rays=256, quantities=("indirect",), max_distance=D, albedo=0.6)
    whole = aobake.bake_points(_planes(), points, normals, **options)
    monkeypatch.setattr(base, "PIECE_RAYS", 64)
    pieces = aobake.bake_points(_planes(), points, normals, **options)
    np.testing.assert_allclose(pieces.indirect, whole.indirect, rtol=1e-12, atol=1e-14)
    assert whole.indirect.min() > 0
