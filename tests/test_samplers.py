"""Samplers and warps: distributions, determinism, stratification, independence between points."""

import numpy as np
import pytest
from scipy import stats

from aobake.rays import RayGenerator
from aobake.rng import hash_uniform
from aobake.samplers.base import REPLICATES
from aobake.samplers import point_key, replicate_keys, sample_set, sobol_2d
from aobake.samplers.sobol import owen_scramble, reverse_bits
from aobake.warp import cos_sin_2pi, frames, warp


def test_hash_is_pure_function_of_ids():
    ids = np.arange(1000)
    a = hash_uniform(7, 1, ids, 0)
    b = hash_uniform(7, 1, ids[::-1], 0)[::-1]
    assert np.array_equal(a, b)
    assert not np.array_equal(a, hash_uniform(8, 1, ids, 0))
    assert not np.array_equal(a, hash_uniform(7, 1, ids, 1))
    assert a.min() >= 0 and a.max() < 1


def test_hash_is_uniform():
    u = hash_uniform(3, 5, np.arange(100_000), 0)
    assert stats.kstest(u, "uniform").pvalue > 1e-4


def test_sobol_matches_scipy():
    qmc = pytest.importorskip("scipy.stats.qmc")
    ours = sobol_2d(64)
    ref = qmc.Sobol(d=2, scramble=False).random(64)
    np.testing.assert_array_equal(ours, ref)


def _values(sampler, n_rays, ids, seed=1, replicates=REPLICATES):
    """(k, R, m, 2) sample values of points ``ids`` and their SampleSet."""
    s = sample_set(sampler, n_rays, replicates)
    return s.values(replicate_keys(point_key(seed), np.asarray(ids), s.groups), 0, s.m), s


def test_samples_are_uniform(sampler):
    """Every sample value is uniform on [0, 1): KS test over many points, per dimension."""
    u, _ = _values(sampler, 64, np.arange(4000))
    for dim in range(2):
        assert stats.kstest(u[..., dim].ravel(), "uniform").pvalue > 1e-4
    assert u[..., 0].max() < 1.0


def test_samples_are_a_pure_function_of_point_and_seed(sampler):
    ids = np.array([5, 2**40, 7, 5])
    u, _ = _values(sampler, 64, ids)
    again, _ = _values(sampler, 64, ids[::-1])
    np.testing.assert_array_equal(u, again[::-1])
    np.testing.assert_array_equal(u[0], u[3])  # the same point, the same samples
    assert not np.array_equal(u, _values(sampler, 64, ids, seed=2)[0])


@pytest.mark.slow
def test_no_sample_value_is_shared_between_points_or_replicates(sampler):
    """Independence: distinct points (and replicates) never share a random number, and the
    estimates of a step function at different points are uncorrelated across seeds."""
    u, s = _values(sampler, 64, np.arange(200))
    for dim in range(2):
        flat = u[..., dim].ravel()
        assert len(np.unique(flat)) == len(flat), "a value repeats between points or replicates"
    # The fraction of samples with u0 > 0.37 at 200 points over 300 seeds: correlation of
    # two points' errors has sd ~ 1/sqrt(300); test all pairs' mean and the worst pair.
    est = np.array([(_values(sampler, 64, np.arange(200), seed)[0][..., 0] > 0.37).mean(axis=(1, 2))
                    for seed in range(300)])
    corr = np.corrcoef(est.T)[np.triu_indices(200, 1)]
    bound = stats.norm.ppf(1 - 1e-4 / 2) / np.sqrt(300)
    assert abs(corr.mean()) < bound / np.sqrt(len(corr)) * 5 and np.abs(corr).max() < 2.5 * bound


def test_stratified_replicate_has_one_sample_per_cell():
    u, s = _values("stratified", 256, np.arange(10), replicates=8)  # 8 of 32 = 4 x 8 grid
    nx, ny = s.grid
    assert (nx, ny) == (4, 8)
    cells = (np.floor(u[..., 0] * nx) + nx * np.floor(u[..., 1] * ny)).astype(int)
    assert np.all(np.sort(cells, axis=-1) == np.arange(32))


@pytest.mark.parametrize("k", range(6))
def test_owen_scrambled_sobol_replicate_is_a_net(k):
    """Owen scrambling keeps the (0, 5, 2)-net property in every replicate: every
    2^k x 2^(5-k) elementary box holds exactly one of the 32 samples."""
    u, _ = _values("sobol", 256, np.arange(10), replicates=8)  # m = 32 = 2^5
    cols, rows = 2**k, 2 ** (5 - k)
    cells = np.floor(u[..., 0] * cols) + cols * np.floor(u[..., 1] * rows)
    assert np.all(np.sort(cells, axis=-1) == np.arange(32))


def test_owen_scramble_is_a_bijection_keeping_prefixes():
    """Nested uniform scrambling permutes the integers and maps intervals [a 2^j, (a+1) 2^j)
    onto such intervals (the net property rests on it)."""
    x = np.arange(2**16, dtype=np.uint32) << np.uint32(16)
    y = owen_scramble(x, np.uint32(0x9E3779B9))
    assert len(np.unique(y)) == len(x)
    top = (y >> np.uint32(24)).reshape(256, 256)  # inputs sharing their top 8 bits ...
    assert np.all(top == top[:, :1])  # ... share them after scrambling
    assert np.array_equal(reverse_bits(reverse_bits(x)), x)


def test_cos_sin_polynomial_is_accurate():
    u = np.concatenate([np.random.default_rng(3).random(200_000), [0.0, 0.25, 0.5, 0.75]])
    c, s = cos_sin_2pi(u)
    # Truncation error of the Taylor polynomials at |x| = pi/4 (aobake.warp): < 2e-9.
    np.testing.assert_allclose(c, np.cos(2 * np.pi * u), rtol=0, atol=2e-9)
    np.testing.assert_allclose(s, np.sin(2 * np.pi * u), rtol=0, atol=2e-9)


def test_rays_rounding_and_replicates():
    assert REPLICATES == 4  # the default (benchmarks/bench_replicates.py, docs/accuracy.md)
    assert sample_set("random", 100).rays == 100
    assert sample_set("sobol", 100).rays == 128  # 4 replicates of 32 (a power of two)
    assert sample_set("sobol", 100, 8).rays == 128  # 8 replicates of 16
    assert sample_set("stratified", 100).rays == 100  # 4 replicates of 25 = a 5 x 5 grid
    assert sample_set("stratified", 100, 8).rays == 104  # 8 replicates of 13
    assert sample_set("sobol", 1).rays == 1


def test_warp_chi_square_against_pdf(weighting):
    """Histogram of cos(theta) and phi of generated world directions vs the pdf."""
    rng = np.random.default_rng(0)
    normal = rng.normal(size=3)
    normal /= np.linalg.norm(normal)
    # Points are independent: 200 points of one bake give 200 independent sample sets.
    gen = RayGenerator(sample_set("random", 256), weighting, seed=0)
    d = gen.rays(np.zeros((200, 3)), np.tile(normal, (200, 1)), np.arange(200)).directions
    d = d.reshape(-1, 3).astype(np.float64)
    t, b = frames(normal[None])
    z = d @ normal
    phi = np.arctan2(d @ b[0], d @ t[0])
    bins = 20
    # theta part: cos(theta) = z.  Cosine: P(z < c) = c^2; uniform: P(z < c) = c.
    edges = np.linspace(0, 1, bins + 1)
    cdf = edges**2 if weighting == "cosine" else edges
    observed, _ = np.histogram(z, edges)
    expected = np.diff(cdf) * len(z)
    assert stats.chisquare(observed, expected).pvalue > 1e-4
    observed, _ = np.histogram(phi, np.linspace(-np.pi, np.pi, bins + 1))
    assert stats.chisquare(observed).pvalue > 1e-4
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    assert z.min() > 0


def test_warp_reference_matches_generator_layout():
    u = np.array([[0.25, 0.0], [0.0, 0.5]])
    d = warp(u, "cosine")
    np.testing.assert_allclose(d[0], [0.5, 0, np.sqrt(0.75)], atol=2e-9)
    np.testing.assert_allclose(d[1], [0, 0, 1], atol=2e-9)


def test_frames_are_orthonormal():
    rng = np.random.default_rng(5)
    n = rng.normal(size=(1000, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    n[0] = [0, 0, -1]
    n[1] = [0, 0, 1]
    t, b = frames(n)
    for a, c in ((t, b), (t, n), (b, n)):
        np.testing.assert_allclose(np.einsum("ij,ij->i", a, c), 0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", np.cross(t, b), n), 1, atol=1e-12)


def test_compiled_rays_equal_numpy_rays_bit_for_bit(sampler, weighting, kernel):
    """Both implementations of ray generation do the same IEEE operations in the same order."""
    rng = np.random.default_rng(7)
    normals = rng.normal(size=(300, 3))
    normals[:4] = [[0, 0, -1], [0, 0, 1], [1, 0, 0], [0, -1e-12, -1]]  # frame seam and axes
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    origins = rng.normal(size=(300, 3)) * np.array([1e-4, 1.0, 1e5])
    ids = rng.integers(0, 2**40, size=300)
    samples = sample_set(sampler, 100)
    gen = RayGenerator(samples, weighting, seed=11, compiled=True)
    assert gen.compiled
    a = gen.rays(origins, normals, ids)
    b = RayGenerator(samples, weighting, seed=11, compiled=False).rays(origins, normals, ids)
    assert a.origins.dtype == b.origins.dtype == np.float32
    assert a.directions.dtype == b.directions.dtype == np.float32
    assert a.origins.shape == b.origins.shape == (300 * gen.samples.rays, 3)
    assert a.directions.shape == b.directions.shape
    np.testing.assert_array_equal(a.origins, b.origins)
    np.testing.assert_array_equal(a.directions, b.directions)
    assert np.all(np.abs(np.linalg.norm(a.directions.astype(np.float64), axis=-1) - 1) < 1e-6)
    # Every direction lies in the hemisphere of its normal.
    cos = np.einsum("kgmi,ki->kgm", a.directions.astype(np.float64), normals)
    assert cos.min() > 0


def test_compiled_escape_counts_equal_numpy(kernel):
    from aobake.quantities.ao import escape_counts

    occluded = np.random.default_rng(2).random((37, 8, 13)) < 0.3
    expected = (13 - np.count_nonzero(occluded, axis=2)).astype(np.float64)
    np.testing.assert_array_equal(escape_counts(occluded, kernel), expected)
    np.testing.assert_array_equal(escape_counts(occluded), expected)
    np.testing.assert_array_equal(escape_counts(occluded[:0], kernel), expected[:0])
