"""Samplers and warps: distributions, determinism, stratification."""

import numpy as np
import pytest
from scipy import stats

from aobake.rays import RayGenerator
from aobake.rng import hash_uniform
from aobake.samplers import sample_set, shifts, sobol_2d
from aobake.warp import frames, warp


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


def test_shifted_samples_are_uniform(sampler):
    """Each u = frac(b + s) is exactly uniform: KS test over many points."""
    s = sample_set(sampler, 64, seed=1)
    sh = shifts(1, np.arange(4000), s.groups)  # (k, R, 2)
    u = (s.base[None, None, :, :] + sh[:, :, None, :]) % 1.0
    for dim in range(2):
        assert stats.kstest(u[..., dim].ravel(), "uniform").pvalue > 1e-4


def test_stratified_base_has_one_point_per_stratum():
    s = sample_set("stratified", 256, seed=4)  # 8 replicates of 32 = 4 x 8 grid
    m = len(s.base)
    nx = 4
    cells = (np.floor(s.base[:, 0] * nx) + nx * np.floor(s.base[:, 1] * (m // nx))).astype(int)
    assert sorted(cells) == list(range(m))


def test_sobol_base_is_a_net():
    s = sample_set("sobol", 256, seed=0)  # m = 32 = 2^5: a (0,5,2)-net
    for k in range(6):
        cols, rows = 2**k, 2 ** (5 - k)
        cells = np.floor(s.base[:, 0] * cols) + cols * np.floor(s.base[:, 1] * rows)
        assert len(np.unique(cells)) == 32


def test_rays_rounding_and_replicates():
    assert sample_set("random", 100, 0).rays == 100
    assert sample_set("sobol", 100, 0).rays == 104  # 8 replicates of 13
    assert sample_set("sobol", 1, 0).rays == 1


def test_warp_chi_square_against_pdf(weighting):
    """Histogram of cos(theta) and phi of generated world directions vs the pdf."""
    rng = np.random.default_rng(0)
    normal = rng.normal(size=3)
    normal /= np.linalg.norm(normal)
    # One point per seed: the elevation part is shared by the points of one bake,
    # so independent samples of it need independent seeds.
    d = []
    for seed in range(200):
        gen = RayGenerator(sample_set("random", 256, seed), weighting, seed=seed)
        d.append(gen.rays(np.zeros((1, 3)), normal[None], np.array([seed])).directions.reshape(-1, 3))
    d = np.concatenate(d).astype(np.float64)
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
    np.testing.assert_allclose(d[0], [0.5, 0, np.sqrt(0.75)])
    np.testing.assert_allclose(d[1], [0, 0, 1], atol=1e-12)


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
    samples = sample_set(sampler, 100, 11)
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
