"""Seam erasure (``--seams erase``, aobake/targets/texels/seams.py): bilinear lookups from
the two sides of every UV seam agree after the bake, texels away from the seams keep their
bits, and the error channels stay honest.  Generated meshes only."""

import functools
import tempfile
from pathlib import Path

import numpy as np
import pytest
import trimesh

from aobake.api import bake_texels
from aobake.settings import CHOICES, DEFAULTS, BakeConfig
from aobake.errors import InputError
from aobake.targets.texels import seams
from aobake.targets.texels.seams import (SeamMesh, bilinear, bilinear_stencil, seam_edges,
                                         seam_points, seam_system, solve)

VALUES = ("ao", "obscurance")


def torus_obj(path, n_major=16, n_minor=8, major=1.0, minor=0.6):
    """A torus with shared positions (one ``v`` per grid point) and UVs from its
    parametrisation in [0, 1] (``vt`` duplicated at u = 1 and v = 1): seams where u and v
    wrap.  Its inner side is occluded by the rest, so AO varies across the seams."""
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    a, b = 2 * np.pi * i / n_major, 2 * np.pi * j / n_minor
    v = np.stack([(major + minor * np.cos(b)) * np.cos(a), minor * np.sin(b),
                  (major + minor * np.cos(b)) * np.sin(a)], -1).reshape(-1, 3)
    uv = [(i / n_major, j / n_minor) for i in range(n_major + 1) for j in range(n_minor + 1)]
    lines = ([f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in v]
             + [f"vt {x:.17g} {y:.17g}" for x, y in uv])
    for i in range(n_major):
        for j in range(n_minor):
            quad = [(i, j), (i, j + 1), (i + 1, j + 1), (i + 1, j)]  # outward
            for tri in ((0, 1, 2), (0, 2, 3)):
                corners = [quad[k] for k in tri]
                lines.append("f " + " ".join(
                    f"{(ci % n_major) * n_minor + cj % n_minor + 1}/{ci * (n_minor + 1) + cj + 1}"
                    for ci, cj in corners))
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def torus(tmp_path_factory):
    return torus_obj(tmp_path_factory.mktemp("seams") / "torus.obj")


OPTIONS = dict(resolution=40, rays=32, texel_samples=2, padding=2,
               quantities=("ao", "obscurance", "bent-normal"), unwrap="never")


@functools.lru_cache(maxsize=None)
def _bake(path, mode, seed, **extra):
    return bake_texels(path, seams=mode, seed=seed, **{**OPTIONS, **extra})


def bakes(path, mode, seeds=(0, 1, 2), **extra):
    return [_bake(str(path), mode, seed, **extra) for seed in seeds]


def seam_mesh(result):
    atlas = result.atlas
    return SeamMesh(atlas.positions, atlas.normals, atlas.faces, atlas.uv, atlas.faces,
                    atlas.wrap)


def random_seam_points(mesh, n=7, seed=1):
    """Points along every seam edge at random parameters (not the solve's quadrature
    points): (uv_a (p, 2), uv_b (p, 2))."""
    ua, ub = seam_edges(mesh)
    t = np.random.default_rng(seed).random((len(ua), n))[..., None]
    pa = (1 - t) * ua[:, None, 0] + t * ua[:, None, 1]
    pb = (1 - t) * ub[:, None, 0] + t * ub[:, None, 1]
    return pa.reshape(-1, 2), pb.reshape(-1, 2)


def differences(result, name, points):
    mesh = seam_mesh(result)
    image = result.channels[name]
    return bilinear(image, points[0], mesh.wrap) - bilinear(image, points[1], mesh.wrap)


def lookup_noise(result, name, points):
    """The sd the two sides' stderrs give a lookup difference (independent sides)."""
    wrap = seam_mesh(result).wrap
    se = result.channels[name + "_stderr"]
    return np.hypot(bilinear(se, points[0], wrap), bilinear(se, points[1], wrap))


# --- the lookups agree -----------------------------------------------------------------


@pytest.mark.parametrize("name", VALUES)
@pytest.mark.slow
def test_lookups_agree_across_seams_after_erasure_and_not_without(torus, name):
    off, erased = bakes(torus, "off"), bakes(torus, "erase")
    points = random_seam_points(seam_mesh(off[0]))
    assert len(points[0]) > 100
    for a, b in zip(off, erased):
        noise = lookup_noise(a, name, points)
        d_off, d_erased = differences(a, name, points), differences(b, name, points)
        # Without erasure the sides differ at the level of their noise (measured 0.5-0.6
        # of the stderrs' sum in quadrature, which the 1/n floor of open texels inflates).
        assert np.sqrt(np.mean((d_off / noise) ** 2)) > 0.3
        # With it, by a small fraction of the noise: the seam term weighs a difference of
        # one of its standard errors KAPPA (5000) times a texel's; measured at 2000
        # 0.0001-0.0002 of the noise, 3500-4500 times less than without (KAPPA = 100:
        # 0.002-0.004).
        assert np.sqrt(np.mean((d_erased / noise) ** 2)) < 0.02
        assert np.sqrt(np.mean(d_erased ** 2)) < np.sqrt(np.mean(d_off ** 2)) / 30


def test_agreement_is_limited_only_by_the_seam_weight(torus, monkeypatch):
    """With a stiff seam term the lookups agree to 1e-3 everywhere along the seams, at
    points the solve never saw: the quadrature makes the whole seam agree, not samples."""
    monkeypatch.setattr(seams, "KAPPA", 1e6)
    result = bake_texels(torus, seams="erase", seed=0, **OPTIONS)
    points = random_seam_points(seam_mesh(result), n=11, seed=2)
    for name in VALUES:
        d = differences(result, name, points)
        assert np.max(np.abs(d)) < 1e-3, (name, np.max(np.abs(d)))


@pytest.mark.slow
def test_new_atlas_seams_agree():
    """An xatlas atlas (a sphere under a plate): its charts' seams are erased too."""
    mesh = sphere_under_plate()
    opts = dict(resolution=64, rays=32, texel_samples=2, padding=2, unwrap="always")
    off = bake_texels(mesh, seams="off", **opts)
    erased = bake_texels(mesh, seams="erase", **opts)
    points = random_seam_points(seam_mesh(off))
    assert len(points[0]) > 100
    d_off, d_erased = differences(off, "ao", points), differences(erased, "ao", points)
    assert np.sqrt(np.mean(d_erased ** 2)) < np.sqrt(np.mean(d_off ** 2)) / 10
    assert "seams_s" in erased.report["timings"] and "seams_s" not in off.report["timings"]


# --- what does not change ------------------------------------------------------------


def _unknowns(result):
    """(H, W) bool: the texels the solve may change (covered or gutter)."""
    mesh = seam_mesh(result)
    h, w = result.covered.shape
    system = seam_system(seam_points(mesh, w, h), result.covered, mesh.wrap)
    mask = np.zeros(h * w, dtype=bool)
    mask[system.texels] = True
    return mask.reshape(h, w)


def test_texels_away_from_seams_keep_their_bits(torus):
    off, erased = bakes(torus, "off"), bakes(torus, "erase")
    for a, b in zip(off, erased):
        assert list(a.channels) == list(b.channels)  # same channels, same order
        moved = _unknowns(a)
        far = a.covered & ~moved
        assert far.sum() > 0.5 * a.covered.sum()
        for name, image in a.channels.items():
            assert np.array_equal(image[far], b.channels[name][far]), name
        changed = a.channels["ao"] != b.channels["ao"]
        assert changed[a.covered].any()
        assert not (changed & a.covered & ~moved).any()
        for name in ("rays", "coverage"):  # never filled, never erased
            assert np.array_equal(a.channels[name], b.channels[name])


def test_padding_zero_and_off_change_nothing(torus):
    """Without gutter rings the lookups at chart edges read push-pull fill: no erasure."""
    off = bakes(torus, "off", seeds=(0,), padding=0)[0]
    erased = bakes(torus, "erase", seeds=(0,), padding=0)[0]
    for name, image in off.channels.items():
        assert np.array_equal(image, erased.channels[name]), name


def test_tangent_space_bent_normals_are_not_erased(torus):
    """A tangent frame turns across a seam: its components are left as baked."""
    off = bakes(torus, "off", seeds=(0,), bent_space="tangent")[0]
    erased = bakes(torus, "erase", seeds=(0,), bent_space="tangent")[0]
    for label in ("bent_normal.X", "bent_normal.Y", "bent_normal.Z", "bent_normal_stderr"):
        assert np.array_equal(off.channels[label], erased.channels[label]), label
    assert not np.array_equal(off.channels["ao"], erased.channels["ao"])


def test_object_space_bent_normals_are_erased_and_stay_unit(torus):
    off, erased = bakes(torus, "off", seeds=(0,))[0], bakes(torus, "erase", seeds=(0,))[0]
    labels = ("bent_normal.X", "bent_normal.Y", "bent_normal.Z")
    bent = np.stack([erased.channels[label] for label in labels], axis=-1)
    length = np.linalg.norm(bent[erased.covered], axis=-1)
    assert np.allclose(length, 1.0, atol=1e-5)
    points = random_seam_points(seam_mesh(off))
    d_off = np.stack([differences(off, label, points) for label in labels])
    d_erased = np.stack([differences(erased, label, points) for label in labels])
    # Agreement up to the renormalisation of the adjusted texels.
    assert np.sqrt(np.mean(d_erased ** 2)) < np.sqrt(np.mean(d_off ** 2)) / 3


# --- honest error channels -------------------------------------------------------------


def test_error_channels_present_finite_and_intervals_hold_the_values(torus):
    off, erased = bakes(torus, "off"), bakes(torus, "erase")
    for a, b in zip(off, erased):
        for name, image in b.channels.items():
            assert np.all(np.isfinite(image)), name
        moved = _unknowns(a) & a.covered
        for name in VALUES:
            value, low, high = (b.channels[name + s] for s in ("", "_ci_low", "_ci_high"))
            se = b.channels[name + "_stderr"]
            assert np.all(se >= 0) and np.all((value >= 0) & (value <= 1))
            assert np.all((low <= value) & (value <= high)), name  # every texel, fill too
            # A covered texel keeps its stderr; its interval still holds the baked value.
            assert np.array_equal(se[a.covered], a.channels[name + "_stderr"][a.covered])
            baked = a.channels[name][moved]
            assert np.all((low[moved] <= baked) & (baked <= high[moved])), name
            assert np.all(low[moved] <= a.channels[name + "_ci_low"][moved])
            assert np.all(high[moved] >= a.channels[name + "_ci_high"][moved])


def _unerased_case(torus, case, torus_resolution, atlas_resolution):
    """A bake without erasure (the torus's own UVs, or a sphere under a plate in a new atlas)
    and its seam system: (result, system, rows (t,), cols (t,) of the system's texels)."""
    if case == "torus-own-uvs":
        result = bake_texels(torus, seams="off", seed=0,
                             **{**OPTIONS, "resolution": torus_resolution})
    else:
        result = bake_texels(sphere_under_plate(1), seams="off", resolution=atlas_resolution,
                             rays=32, texel_samples=2, padding=2, unwrap="always")
    mesh = seam_mesh(result)
    h, w = result.covered.shape
    system = seam_system(seam_points(mesh, w, h), result.covered, mesh.wrap)
    return (result, system, *np.divmod(system.texels, w))


def sphere_under_plate(subdivisions=2):
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    plate = trimesh.creation.box(extents=[0.8, 0.8, 0.1])
    plate.apply_translation([0, 0, 1.3])  # some occlusion so AO varies over the sphere
    return trimesh.util.concatenate([sphere, plate])


@pytest.mark.slow
@pytest.mark.parametrize("case", ["torus-own-uvs", "sphere-xatlas"])
def test_kept_stderr_bounds_the_adjusted_values_noise(torus, case):
    """The adjusted covered values are linear in the baked ones, x = K b.  With the
    baked texels' errors independent, Var(x_i) = sum_j K_ij^2 se_j^2, and the module's
    claim is that this never exceeds se_i^2 (the seam and tie terms involve x only, so K
    is a contraction in units of the errors): the kept stderr is an upper bound.  The
    torus's seams lie on the image border (no gutter unknowns); the atlas's have gutters."""
    result, system, rows, cols = _unerased_case(torus, case, torus_resolution=24,
                                                atlas_resolution=32)
    se = result.channels["ao_stderr"][rows, cols].astype(np.float64)
    covered = ~system.gutter
    n = len(system.texels)
    assert 50 < covered.sum() < 600
    assert system.gutter.any() == (case == "sphere-xatlas")
    # Columns of K: the solve of each unit vector (gutter inputs are ignored by solve).
    basis = np.eye(n)[:, covered]
    k, info = solve(basis, se, system, tolerance=1e-10, max_iterations=20000)
    assert info["converged"]
    k = k[covered]  # (covered unknowns, covered unknowns)
    b = result.channels["ao"][rows, cols].astype(np.float64)[:, None]
    x, _ = solve(b, se, system, tolerance=1e-10, max_iterations=20000)
    assert np.allclose(k @ b[covered, 0], x[covered, 0], atol=1e-8)  # linear in b
    sd = np.sqrt((k ** 2) @ se[covered] ** 2)
    ratio = sd / se[covered]
    assert np.all(ratio <= 1 + 1e-8), ratio.max()
    assert ratio.min() < 0.9  # the solve averages across the seam: the bound is not idle


# --- pieces ----------------------------------------------------------------------------


def test_quadrature_integrates_the_seam_difference_exactly(torus):
    """The Gauss points (3 per piece between texel-centre crossings) integrate
    (L_A - L_B)^2 along every seam exactly, for any image."""
    mesh = seam_mesh(bakes(torus, "off", seeds=(0,))[0])
    w, h = 13, 9  # coarse, odd: many pieces end inside edges
    image = np.random.default_rng(0).random((h, w))
    points = seam_points(mesh, w, h)
    d = bilinear(image, points.uv_a, mesh.wrap) - bilinear(image, points.uv_b, mesh.wrap)
    exact = np.bincount(points.edge, weights=points.weight * d ** 2, minlength=points.n_edges)
    ua, ub = seam_edges(mesh)
    t = (np.arange(4000) + 0.5) / 4000  # midpoint rule, fine
    length = 0.5 * (np.linalg.norm((ua[:, 1] - ua[:, 0]) * [w, h], axis=1)
                    + np.linalg.norm((ub[:, 1] - ub[:, 0]) * [w, h], axis=1))
    for e in range(0, len(ua), max(1, len(ua) // 12)):
        pa = (1 - t)[:, None] * ua[e, 0] + t[:, None] * ua[e, 1]
        pb = (1 - t)[:, None] * ub[e, 0] + t[:, None] * ub[e, 1]
        de = bilinear(image, pa, mesh.wrap) - bilinear(image, pb, mesh.wrap)
        assert exact[e] == pytest.approx(np.mean(de ** 2) * length[e], rel=1e-5, abs=1e-12)


def _two_triangles(uv_b, normal_b=(0, 0, 1), wrap="clamp"):
    """Two triangles sharing the edge (0,0,0)-(1,0,0); the second face's UVs of that edge
    are ``uv_b`` (2, 2)."""
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0], [1, 0, 0], [0, -1, 0]],
                         float)
    normals = np.array([[0, 0, 1]] * 3 + [normal_b] * 3, float)
    faces = np.array([[0, 1, 2], [4, 3, 5]])
    uv = np.array([[0.1, 0.5], [0.4, 0.5], [0.1, 0.8], uv_b[0], uv_b[1], [0.6, 0.2]], float)
    return SeamMesh(positions, normals, faces, uv, faces.copy(), wrap)


def test_seam_edges_need_different_uvs_and_the_same_normals():
    ua, ub = seam_edges(_two_triangles([[0.6, 0.5], [0.9, 0.5]]))
    assert len(ua) == 1
    assert np.allclose(ua[0], [[0.1, 0.5], [0.4, 0.5]]) and np.allclose(ub[0], [[0.6, 0.5],
                                                                              [0.9, 0.5]])
    assert len(seam_edges(_two_triangles([[0.1, 0.5], [0.4, 0.5]]))[0]) == 0  # no seam
    # A hard edge (normals 90 degrees apart): the values may differ there on purpose.
    assert len(seam_edges(_two_triangles([[0.6, 0.5], [0.9, 0.5]], (0, 1, 0)))[0]) == 0
    # A whole tile apart: the same texels under repeat, a seam under clamp.
    shifted = [[1.1, 0.5], [1.4, 0.5]]
    assert len(seam_edges(_two_triangles(shifted, wrap="repeat"))[0]) == 0
    assert len(seam_edges(_two_triangles(shifted, wrap="clamp"))[0]) == 1


def test_bilinear_follows_the_texel_convention():
    w, h = 8, 4
    r, c = 1, 5
    centre = [[(c + 0.5) / w, 1 - (r + 0.5) / h]]  # row 0 at the top (v near 1)
    texel, weight = bilinear_stencil(centre, w, h)
    assert weight[0, 0] == 1.0 and texel[0, 0] == r * w + c
    assert np.allclose(weight.sum(axis=1), 1.0)
    image = np.arange(w * h, dtype=float).reshape(h, w)
    assert bilinear(image, [[0.0, 0.5]], "clamp")[0] == pytest.approx(image[1:3, 0].mean())
    assert bilinear(image, [[0.0, 0.5]], "repeat")[0] == pytest.approx(
        image[1:3, [0, w - 1]].mean())


def test_config_field():
    assert DEFAULTS["seams"] == "erase" and CHOICES["seams"] == ("erase", "off")
    config = BakeConfig(seams="off")
    assert BakeConfig.from_dict(config.to_dict()) == config
    with pytest.raises(InputError, match="seams"):
        BakeConfig(seams="blend")


@pytest.mark.slow
@pytest.mark.parametrize("case", ["torus-own-uvs", "sphere-xatlas"])
def test_compiled_solve_gives_the_numpy_bits(torus, case, kernel):
    """The seam solve's kernel (group sums and conjugate gradients) repeats the numpy
    formulation operation for operation: the same iterations and the same bits, for
    several channels at once, with gutter unknowns and on any number of threads."""
    result, system, rows, cols = _unerased_case(torus, case, torus_resolution=OPTIONS["resolution"],
                                                atlas_resolution=48)
    b = np.stack([result.channels[name][rows, cols] for name in ("ao", "ao_ci_low")], axis=1)
    se = result.channels["ao_stderr"][rows, cols].astype(np.float64)
    assert system.gutter.any() == (case == "sphere-xatlas")
    for bounds in (None, (0.0, 1.0)):  # and the bounded solve's rounds
        slow, slow_info = solve(b, se, system, compiled=False, bounds=bounds)
        for threads in (1, 2, 3, 7):  # the kernel's threads split texels and groups
            fast, fast_info = solve(b, se, system, compiled=True, threads=threads,
                                    bounds=bounds)
            assert fast_info["iterations"] > 5 and fast_info == slow_info
            np.testing.assert_array_equal(fast, slow)


@pytest.mark.slow
@pytest.mark.parametrize("case", ["torus-own-uvs", "sphere-xatlas"])
def test_assembled_matrix_is_the_normal_matrix(torus, case, kernel):
    """The solve's CSR matrix is W + P^T G^T Lambda G P over the covered unknowns, made
    here densely from the system's definition (P the first dilation ring, G the seam
    points' lookup differences); the kernel's assembly is the numpy one bit for bit, for
    any number of threads."""
    from aobake.targets.texels.seams import _assemble_numpy

    result, system, rows, cols = _unerased_case(torus, case, torus_resolution=OPTIONS["resolution"],
                                                atlas_resolution=48)
    s = system
    n, m = len(s.texels), len(s.group)
    rng = np.random.default_rng(5)
    lam, w = rng.uniform(0.5, 2.0, m), np.where(s.gutter, 0.0, rng.uniform(0.5, 2.0, n))
    starts = np.r_[np.nonzero(np.r_[True, s.group[1:] != s.group[:-1]])[0], m].astype(np.int64)
    parts = (np.ascontiguousarray(s.coef), lam, starts, np.ascontiguousarray(s.slots),
             np.ascontiguousarray(s.gutter), s.fill_to, s.fill_from, s.fill_weight, w)
    reference = _assemble_numpy(*parts)
    P = np.diag(np.where(s.gutter, 0.0, 1.0))
    np.add.at(P, (s.fill_to, s.fill_from), s.fill_weight)
    G = np.zeros((m, n))
    np.add.at(G, (np.repeat(np.arange(m), 8), s.slots[s.group].reshape(-1)), s.coef.reshape(-1))
    covered = ~s.gutter
    GP = (G @ P)[:, covered]
    dense = np.diag(w[covered]) + GP.T @ (lam[:, None] * GP)
    nc = int(covered.sum())
    ours = np.zeros((nc, nc))
    ours[np.repeat(np.arange(nc), np.diff(reference.indptr)), reference.indices] = \
        reference.data
    row = np.repeat(np.arange(nc), np.diff(reference.indptr))
    assert np.all(np.diff(reference.indices)[np.diff(row) == 0] > 0)  # ascending in a row
    np.testing.assert_allclose(ours, dense, rtol=1e-12, atol=1e-12 * np.abs(dense).max())
    for threads in (1, 2, 3):
        ptr, idx = (np.frombuffer(b, t) for b, t in
                    zip(kernel.seam_pattern(*parts[2:7], threads), (np.int64, np.int32)))
        data = kernel.seam_values(*parts, ptr, idx, threads)
        np.testing.assert_array_equal(ptr, reference.indptr)
        np.testing.assert_array_equal(idx, reference.indices)
        np.testing.assert_array_equal(np.frombuffer(data, np.float64).view(np.uint64),
                                      reference.data.view(np.uint64))


@pytest.mark.parametrize("wrap", ["clamp", "repeat"])
def test_group_key_orders_points_as_a_lexsort_of_their_stencils(wrap):
    """seam_system sorts the points by one key instead of a lexsort of the 8 texels they
    read: the same order, also where stencils are clamped or wrapped at the image's edges
    and in images one texel wide or tall."""
    from aobake.targets.texels.seams import _side_key

    rng = np.random.default_rng(11)
    for width, height in ((16, 12), (1, 7), (5, 1), (1, 1)):
        uv_a = rng.uniform(-0.3, 1.3, (4000, 2))
        uv_b = np.where(rng.random((4000, 1)) < 0.5, uv_a, rng.uniform(-0.3, 1.3, (4000, 2)))
        uv_a[::3] = np.round(uv_a[::3] * 8) / 8  # on texel centres and edges
        ta, _ = bilinear_stencil(uv_a, width, height, wrap)
        tb, _ = bilinear_stencil(uv_b, width, height, wrap)
        texel = np.concatenate([ta, tb], axis=1)
        expected = np.lexsort(texel.T[::-1])
        key = (_side_key(uv_a, width, height, wrap) << np.int64(30)
               | _side_key(uv_b, width, height, wrap))
        assert (np.argsort(key, kind="stable") == expected).all(), (width, height)


def test_system_made_on_its_thread_is_the_one_used(torus, monkeypatch):
    """The seam system is made once, on its own thread while the values are splatted, and
    the bake matches the cached one."""
    calls = []
    original = seams.prepare

    def counting(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(seams, "prepare", counting)
    result = bake_texels(str(torus), seams="erase", seed=0, **OPTIONS)
    assert len(calls) == 1
    assert result.report["timings"]["seam_system_s"] > 0
    cached = _bake(str(torus), "erase", 0)
    for name, image in cached.channels.items():
        assert np.array_equal(image, result.channels[name]), name


def test_a_system_for_other_covered_texels_is_made_again(torus):
    """erase_seams with a prepared system for different covered texels makes its own."""
    result = _bake(str(torus), "off", 0)
    mesh = seam_mesh(result)
    covered = result.covered
    other = covered.copy()
    other[np.argwhere(covered)[0][0], np.argwhere(covered)[0][1]] = False
    wrong = seams.prepare(mesh, other, 2)

    def erased(prepared):
        images = {"ao": result.channels["ao"].astype(np.float64),
                  "ao_stderr": result.channels["ao_stderr"].astype(np.float64)}
        done = seams.erase_seams(images, [seams.SeamChannel(("ao",), "ao_stderr")], mesh,
                                 covered, 2, prepared=prepared)
        return images["ao"], done.info

    (a, info_a), (b, info_b) = erased(None), erased(wrong)
    assert np.array_equal(a, b) and info_a == info_b
    assert not np.array_equal(a, result.channels["ao"])


def test_a_system_that_failed_on_its_thread_is_made_again(torus, monkeypatch):
    """A failure while the system is made on its own thread (memory, say) is not the
    bake's: the erasure makes it again, and the bake is the same."""
    import threading

    original = seams.prepare

    def failing_off_the_main_thread(*args, **kwargs):
        if threading.current_thread() is not threading.main_thread():
            raise MemoryError("no memory on the seam thread")
        return original(*args, **kwargs)

    monkeypatch.setattr(seams, "prepare", failing_off_the_main_thread)
    result = bake_texels(str(torus), seams="erase", seed=0, **OPTIONS)
    cached = _bake(str(torus), "erase", 0)
    for name, image in cached.channels.items():
        assert np.array_equal(image, result.channels[name]), name
    assert "seam_system_s" not in result.report["timings"]


# --- seams that escaped the erasure (issue 21, the ogre) -------------------------------


def floor_with_hidden_seam(path, n=8, degenerate=True):
    """A floor z = 0 over [-1, 1]^2 in two UV charts that meet at x = 0 (their seam), under a
    plate that shades it unevenly, with one T-junction on the seam as xatlas leaves it on
    the ogre: the left face's seam edge a-b faces two right faces, on a-c and c-b (c its
    midpoint), and a zero-area face (b, a, c) between them, whose three UVs are one point
    outside both charts.  Returns (path, the hidden seam: a, b, c as (3, 3) positions and
    the left face's UVs of a and b, the right faces' UVs of a, c and b)."""
    xs = np.linspace(-1.0, 1.0, 2 * n + 1)
    lines, vt, faces = [], [], []
    vid = {}

    def v(p):
        key = tuple(np.round(p, 12))
        if key not in vid:
            vid[key] = len(vid) + 1
            lines.append("v %.17g %.17g %.17g" % key)
        return vid[key]

    def t(x, y, chart):  # chart 0: x in [-1, 0] -> u in [0.05, 0.45]; 1: [0, 1] -> [0.55, 0.95]
        vt.append((0.05 + 0.4 * (x + 1) if chart == 0 else 0.55 + 0.4 * x, 0.05 + 0.45 * (y + 1)))
        return len(vt)

    j0 = n // 2 + 1  # the row of the T-junction (away from the plate's edge)
    a, b = (0.0, xs[j0], 0.0), (0.0, xs[j0 + 1], 0.0)
    c = (0.0, 0.5 * (xs[j0] + xs[j0 + 1]), 0.0)
    for i in range(2 * n):
        chart = 0 if i < n else 1
        for j in range(2 * n):
            q = [(xs[i], xs[j]), (xs[i + 1], xs[j]), (xs[i + 1], xs[j + 1]), (xs[i], xs[j + 1])]
            if degenerate and i == n and j == j0:  # the right quad on a-b: split at c
                x1 = xs[i + 1]
                tri = [[(0.0, xs[j]), (x1, xs[j]), (0.0, c[1])],
                       [(0.0, c[1]), (x1, xs[j]), (x1, xs[j + 1])],
                       [(0.0, c[1]), (x1, xs[j + 1]), (0.0, xs[j + 1])]]
            else:
                tri = [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
            for corners in tri:
                faces.append([(v((x, y, 0.0)), t(x, y, chart)) for x, y in corners])
    if degenerate:  # (b, a, c): no area, its UVs one point, as xatlas leaves such faces
        vt.extend([(0.98, 0.98)] * 3)
        faces.append([(v(p), len(vt) - 2 + m) for m, p in enumerate((b, a, c))])
    plate = trimesh.creation.box(extents=[0.8, 2.4, 0.05])
    plate.apply_translation([0.15, 0.0, 0.35])
    for k, face in enumerate(plate.faces):  # the plate: a little UV island per triangle
        u0 = 0.02 + 0.075 * (k % 12)
        vt.extend([(u0, 0.005), (u0 + 0.03, 0.005), (u0, 0.03)])
        faces.append([(v(plate.vertices[p]), len(vt) - 2 + m) for m, p in enumerate(face)])
    lines += ["vt %.17g %.17g" % uv for uv in vt]
    lines += ["f " + " ".join(f"{p}/{q}" for p, q in face) for face in faces]
    path.write_text("\n".join(lines) + "\n")
    left = [t_uv(p, 0) for p in (a, b)]
    right = [t_uv(p, 1) for p in (a, c, b)]
    return path, (np.array([a, b, c]), np.array(left), np.array(right))


def t_uv(p, chart):
    x, y = p[0], p[1]
    return (0.05 + 0.4 * (x + 1) if chart == 0 else 0.55 + 0.4 * x, 0.05 + 0.45 * (y + 1))


def _hidden_seam_points(hidden, n=64):
    """Points along the seam the zero-area face hides: the left face's edge a-b against
    the right faces' a-c and c-b, as (uv_left (n, 2), uv_right (n, 2))."""
    _, left, right = hidden
    t = (np.arange(n) + 0.5) / n
    uv_left = (1 - t)[:, None] * left[0] + t[:, None] * left[1]
    s = np.where(t < 0.5, 2 * t, 2 * t - 1)[:, None]  # c is the midpoint of a-b
    uv_right = np.where(t[:, None] < 0.5, (1 - s) * right[0] + s * right[1],
                        (1 - s) * right[1] + s * right[2])
    return uv_left, uv_right


def test_seam_behind_a_zero_area_face_is_found():
    """A zero-area face on a seam (the ogre has four; xatlas gives each one UV for its three
    corners, outside every chart) is no side of a seam: the faces it separates meet, in
    pieces, and no seam edge reads its collapsed UVs."""
    path, hidden = floor_with_hidden_seam(Path(tempfile.mkdtemp()) / "floor.obj")
    result = _bake(str(path), "off", 0, **FLOOR)
    mesh = seam_mesh(result)
    assert seams.degenerate_faces(mesh.positions, mesh.faces).sum() == 1
    ua, ub = seam_edges(mesh)
    collapsed = np.array([0.98, 0.98])
    assert not np.any(np.all(np.isclose(ua, collapsed), axis=2)
                      | np.all(np.isclose(ub, collapsed), axis=2))
    _, left, right = hidden
    c_left = 0.5 * (left[0] + left[1])
    pieces = {(tuple(np.round(x[0], 9)), tuple(np.round(x[1], 9)))
              for x in np.concatenate([ua, ub])}
    for piece in ([left[0], c_left], [c_left, left[1]], [right[0], right[1]],
                  [right[1], right[2]]):
        ends = tuple(tuple(np.round(p, 9)) for p in piece)
        assert ends in pieces or ends[::-1] in pieces, ends
    points = seam_system(seam_points(mesh, *result.covered.shape[::-1]), result.covered)
    assert points.dropped == 0


FLOOR = dict(resolution=64, rays=64, texel_samples=4, padding=2, unwrap="never",
             quantities=("ao",))


@pytest.mark.slow
def test_seam_behind_a_zero_area_face_is_erased(monkeypatch):
    """The failing class of issue 21: before, the seam the zero-area face hides was never
    erased (its lookups were paired with the face's collapsed UVs, points the solve drops).
    Now it agrees like the floor's other seam edges: its difference, in units of the
    lookups' noise, is within the range of theirs in the same solve (each edge's rms at 16
    points; measured 0.0002-0.0005 for it, a median of 0.0004 and at most 0.014-0.019 for
    them), where without the pieces it keeps a step of the order of the noise (0.26-0.36)."""
    path, hidden = floor_with_hidden_seam(Path(tempfile.mkdtemp()) / "floor.obj")
    points = _hidden_seam_points(hidden)
    t = (np.arange(16) + 0.5) / 16

    def in_noise(result, off, pair):
        noise = lookup_noise(off, "ao", pair)
        return np.sqrt(np.mean((differences(result, "ao", pair) / noise) ** 2))

    worst = {}
    for seed in (0, 1):
        off = _bake(str(path), "off", seed, **FLOOR)
        erased = _bake(str(path), "erase", seed, **FLOOR)
        ua, ub = seam_edges(seam_mesh(off))
        floor = np.all(ua[..., 1] > 0.04, axis=1) & np.all(ub[..., 1] > 0.04, axis=1)
        assert floor.sum() == 2 * 8 + 1  # the seam's rows, one of them in two pieces
        edges = [in_noise(erased, off, ((1 - t)[:, None] * ua[e, 0] + t[:, None] * ua[e, 1],
                                        (1 - t)[:, None] * ub[e, 0] + t[:, None] * ub[e, 1]))
                 for e in np.nonzero(floor)[0]]
        worst[seed] = max(edges)
        # unerased: a step of the order of the noise (0.26-0.36 of it), ten times what the
        # erasure leaves on the worst of the floor's other seam edges
        assert in_noise(off, off, points) > 10 * worst[seed]
        assert in_noise(erased, off, points) <= worst[seed]
    monkeypatch.setattr(seams, "degenerate_faces", lambda p, f: np.zeros(len(f), bool))
    before = bake_texels(str(path), seams="erase", seed=0, **FLOOR)
    assert in_noise(before, _bake(str(path), "off", 0, **FLOOR), points) > 10 * worst[0]


@pytest.mark.slow
def test_bounded_solve_is_the_minimum_within_0_1(torus, monkeypatch):
    """The other class of issue 21: where baked values sit at 0 or 1 next to a steep change
    (buried or open texels: 27% of the ogre's), the unbounded minimum leaves [0, 1] and
    clipping it brought the seam's step back.  The bounded solve, its active set let run to
    the end, meets the Karush-Kuhn-Tucker conditions of the minimum over [0, 1] (the
    problem is convex: that is the minimum): the gradient A x - rhs, in the units of the
    stopping test (divided by the diagonal), is within the solver's tolerance of zero at
    free texels and points outwards at held ones.  And its lookups agree better than the
    clipped unbounded minimum's."""
    result, system, rows, cols = _unerased_case(torus, "sphere-xatlas", torus_resolution=24,
                                                atlas_resolution=48)
    # values with a fifth at each bound and steps of the whole range between neighbours
    # (the ogre's buried and open texels side by side): the unbounded minimum overshoots
    b = np.clip(np.random.default_rng(3).normal(0.5, 0.6, (len(rows), 1)), 0.0, 1.0)
    se = result.channels["ao_stderr"][rows, cols].astype(np.float64)
    covered = ~system.gutter
    # at one seam weight (these made-up steps would otherwise raise it: SEAM_TARGET)
    monkeypatch.setattr(seams, "KAPPA_RANGE", 1.0)
    free_x, _ = solve(b, se, system)
    assert (free_x[covered] < 0).any() and (free_x[covered] > 1).any()
    captured = {}
    original = seams._bounded

    def capture(matrix, diag, rhs, *rest):
        captured.update(matrix=matrix, diag=diag, rhs=rhs)
        return original(matrix, diag, rhs, *rest)

    monkeypatch.setattr(seams, "_bounded", capture)
    monkeypatch.setattr(seams, "MAX_ROUNDS", 50)
    x, info = solve(b, se, system, bounds=(0.0, 1.0))
    xc = x[covered, 0]
    assert np.all((xc >= 0) & (xc <= 1)) and info["bound_texels"] > 0
    m = captured["matrix"]
    dense = np.zeros((len(xc), len(xc)))
    dense[np.repeat(np.arange(len(xc)), np.diff(m.indptr)), m.indices] = m.data
    scaled = (dense @ xc - captured["rhs"]) / captured["diag"]
    tol = 2 * seams.TOLERANCE
    assert np.all(np.abs(scaled[(xc > 0) & (xc < 1)]) <= tol)
    assert np.all(scaled[xc == 0] >= -tol) and np.all(scaled[xc == 1] <= tol)
    rms = lambda v: np.sqrt(np.sum(system.weight * system.differences(v) ** 2)  # noqa: E731
                            / np.sum(system.weight))
    clipped = np.clip(free_x[:, 0], 0, 1)
    assert rms(x[:, 0]) < rms(clipped)
    # The default, one round (MAX_ROUNDS), goes most of the way from the clipped minimum
    # to the bounded one (in energy, 1/2 x.A x - rhs.x, the unbounded minimum's the least).
    monkeypatch.setattr(seams, "MAX_ROUNDS", 1)
    one, _ = solve(b, se, system, bounds=(0.0, 1.0))
    energy = lambda v: 0.5 * v @ dense @ v - captured["rhs"] @ v  # noqa: E731
    e_clip, e_one, e_min = (energy(v[covered]) for v in (clipped, one[:, 0], x[:, 0]))
    assert e_min <= e_one <= e_clip and e_one - e_min < 0.1 * (e_clip - e_min), \
        (e_clip, e_one, e_min)


#: issue 21's target for the systematic step across the seams (rms of the lookup difference)
SEAM_TARGET = 0.002


def _systematic(mesh_or_path, seeds, **options):
    """The seams' systematic step over ``seeds`` bakes (as benchmarks/bench_seams.py): the
    rms over the seam (weighted by length) of the mean difference of the lookups, raw (an
    upper bound in expectation: raw^2 = systematic^2 + random^2 / S) and with the seeds'
    noise taken out."""
    d = []
    for seed in seeds:
        result = bake_texels(mesh_or_path, seams="erase", seed=seed, **options)
        mesh = seam_mesh(result)
        points = seam_points(mesh, *result.covered.shape[::-1])
        ao = result.channels["ao"]
        d.append(bilinear(ao, points.uv_a, mesh.wrap) - bilinear(ao, points.uv_b, mesh.wrap))
    d, w = np.array(d), points.weight
    mean = d.mean(axis=0)
    rms = lambda v: np.sqrt(np.sum(w * v ** 2) / np.sum(w))  # noqa: E731
    raw, random = rms(mean), rms(np.sqrt(np.sum((d - mean) ** 2, axis=0) / (len(d) - 1)))
    return raw, np.sqrt(max(raw ** 2 - random ** 2 / len(d), 0.0))


@pytest.mark.slow
def test_parts_through_parts_meet_the_seam_target(monkeypatch):
    """The ogre's remaining class (issue 21): a part through another (a sphere half in a
    box, a new atlas), texels buried (AO 0) a texel from open ones, seams across the
    intersection.  The systematic step stays below the target, by its raw estimate (an
    upper bound: measured 0.0008); with the erasure as it was (seam weight 100, clipped
    after the solve) it is above it, noise taken out (measured 0.0026; unerased 0.048)."""
    sphere = trimesh.creation.icosphere(subdivisions=3)
    box = trimesh.creation.box(extents=[3, 3, 1.0])
    box.apply_translation([0, 0, -0.3])
    scene = trimesh.util.concatenate([sphere, box])
    options = dict(resolution=128, rays=64, texel_samples=2, padding=2, unwrap="always",
                   quantities=("ao",))
    raw, _ = _systematic(scene, range(4), **options)
    assert raw < SEAM_TARGET, raw
    monkeypatch.setattr(seams, "KAPPA", 100.0)
    monkeypatch.setattr(seams, "KAPPA_RANGE", 1.0)  # one weight, as it was
    monkeypatch.setattr(seams, "HOLD_TOLERANCE", seams.TOLERANCE)
    monkeypatch.setattr(seams, "_bounded", lambda matrix, diag, rhs, x, left, bounds, *rest:
                        (np.clip(x, *bounds), 0, left, 0))
    _, before = _systematic(scene, range(4), **options)
    assert before > SEAM_TARGET, before


def _sphere_through_box():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    box = trimesh.creation.box(extents=[3, 3, 1.0])
    box.apply_translation([0, 0, -0.3])
    return trimesh.util.concatenate([sphere, box])


@pytest.mark.slow
def test_a_map_coarse_for_its_charts_meets_the_seam_target(monkeypatch):
    """The ogre at 512^2, scaled down: the sphere through the box at 48^2, its charts
    finer than the texels, so its steps across the seams are steep and a fixed weight
    leaves a fixed fraction of them (measured 0.0023 at 2000 and 0.0022 at 5000, 4 seeds).
    The weight rises until each solve's seams meet the target: below it, and above it
    when the weight may not rise (KAPPA_RANGE 1)."""
    scene = _sphere_through_box()
    options = dict(resolution=48, rays=64, texel_samples=2, padding=2, unwrap="always",
                   quantities=("ao",))
    raw, _ = _systematic(scene, range(4), **options)
    assert raw < SEAM_TARGET, raw
    monkeypatch.setattr(seams, "KAPPA_RANGE", 1.0)
    _, fixed = _systematic(scene, range(4), **options)
    assert fixed > SEAM_TARGET, fixed


@pytest.mark.slow
def test_the_report_says_which_seam_weight_ran():
    """texture.seams.kappa: KAPPA where the seams met the target at once, higher where the
    weight had to rise (the 48^2 map above)."""
    scene = _sphere_through_box()
    options = dict(rays=64, texel_samples=2, padding=2, unwrap="always", quantities=("ao",),
                   seed=0)
    fine = bake_texels(scene, seams="erase", resolution=128, **options).report
    coarse = bake_texels(scene, seams="erase", resolution=48, **options).report
    assert fine["texture"]["seams"]["kappa"] == seams.KAPPA
    assert coarse["texture"]["seams"]["kappa"] > seams.KAPPA
    assert coarse["texture"]["seams"]["rms_after"] <= seams.SEAM_TARGET


@pytest.mark.slow
def test_seam_rounds_stop_at_the_range_or_where_a_round_no_longer_helps(monkeypatch):
    """With no target met (SEAM_TARGET 0) the weight rises to KAPPA x KAPPA_RANGE; a round
    that leaves more than PLATEAU of the last one's difference is the last (PLATEAU 0: the
    round after the first)."""
    scene = _sphere_through_box()
    options = dict(rays=16, texel_samples=1, padding=2, unwrap="always", quantities=("ao",),
                   seed=0, resolution=48, seams="erase")
    monkeypatch.setattr(seams, "SEAM_TARGET", 0.0)
    monkeypatch.setattr(seams, "KAPPA_RANGE", 16.0)
    ran = bake_texels(scene, **options).report["texture"]["seams"]
    assert ran["kappa"] == 16 * seams.KAPPA
    monkeypatch.setattr(seams, "PLATEAU", 0.0)
    ran = bake_texels(scene, **options).report["texture"]["seams"]
    assert ran["kappa"] == 4 * seams.KAPPA
