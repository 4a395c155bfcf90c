"""``--method depthmaps``: AO from K shared orthographic depth maps (OpenGL in a child).

The value is deterministic; its error has two parts, tested apart:

- **the directions** (K): with exact visibility the method is the quadrature
  ``A_K = sum_k V_k W_k / sum_k W_k`` over the K directions.  On the floor under a coaxial
  48-gon it is computed here in numpy (a ray meets the polygon or not) against Lambert's
  polygon form factor; its error, measured over 24 points and 8 seeds, falls as K^(-3/4)
  (the spherical-cap discrepancy of a Fibonacci lattice): max 0.287, 0.097, 0.036, 0.013,
  0.0046, 0.0015 at K = 16 .. 16384, within 2.3 K^(-3/4).  The test asserts 3 K^(-3/4) and
  the rate.
- **the maps** (N, b): the map holds each texel centre's height, so a direction is decided
  as exact visibility would decide it unless the point's line along w passes within a
  texel's half-diagonal s / sqrt 2 of the occluder's outline in the map's plane (the texel
  centre's line may then fall on the other side), the self-shadowing of the point's own
  plane being what the bias removes (b >= 1/sqrt 2, derived in ``depthmaps_gl``), and an
  occluder nearer than b s above the tangent plane being missed (none here: the disc is at
  h = 1, b s ~ 0.004).  So

      |A_GL - A_K| <= sum of W_k over the crossed directions / sum of W_k,

  computed per point with the margin widened by 1/32 for the rasteriser's 1/256-texel
  snapping and float32 rounding (the hemicube's widening).

The GL tests skip where moderngl or a GL 4.3 context is missing (a probe in a child).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

import aobake
from aobake import capabilities
from aobake.errors import InputError, UsageError
from aobake.methods import METHODS
from aobake.methods.depthmaps import (NO_INFORMATION_AO, DepthmapsError, DepthmapsMethod,
                                      available, directions, fibonacci, map_axes, rotation,
                                      traced)
from aobake.occluders import build
from aobake.records import SamplePoints, merge
from aobake.scene import load_scene
from aobake.settings import BakeConfig
from aobake.settings.depthmaps import DepthmapsOptions

from analytic import combine, floor_points, polygon, polygon_form_factors, quad
from conftest import run_cli

#: the margin's widening for the rasteriser (see the module docstring)
WIDEN = 1.0 + 1.0 / 32.0
#: float32 weights accumulated in float64: the rounding of a ratio of such sums
ROUNDING = 1e-6
SIDES, HEIGHT, RADIUS = 48, 1.0, 1.0


@pytest.fixture(scope="module")
def gl():
    """Skip unless moderngl imports and a child can make a GL 4.3 context."""
    pytest.importorskip("moderngl")
    ok, why = available()
    if not ok:
        pytest.skip(why)
    return why


def _points(points, normals) -> SamplePoints:
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    return SamplePoints(points, normals, np.arange(len(points), dtype=np.int64))


def _prepare(mesh, k=64, n=256, b=1.0, **config):
    return DepthmapsMethod.prepare(load_scene(mesh), BakeConfig(**config), None, 0,
                                   options=DepthmapsOptions(k, n, b))


# ------------------------------------------------------------------ the directions (no GL)

def test_the_lattice_is_stratified_and_the_seed_only_rotates_it():
    """K unit directions, one per equal-area stratum in z (z_i at the strata's centres);
    a seed's rotation is orthonormal with determinant 1, a pure function of the seed, and
    moves the lattice as a whole (pairwise angles kept)."""
    k = 100
    lattice = fibonacci(k)
    assert np.allclose(np.linalg.norm(lattice, axis=1), 1.0, atol=1e-15)
    strata = np.floor((1.0 - lattice[:, 2]) / 2.0 * k).astype(int)
    assert sorted(strata) == list(range(k))
    for seed in (0, 1, 2**63 - 1):
        r = rotation(seed)
        assert np.allclose(r @ r.T, np.eye(3), atol=1e-14)
        assert abs(np.linalg.det(r) - 1.0) < 1e-14
        np.testing.assert_array_equal(directions(k, seed), directions(k, seed))
        d = directions(k, seed)
        np.testing.assert_allclose(d @ d.T, lattice @ lattice.T, atol=1e-13)
    assert not np.allclose(directions(k, 0), directions(k, 1))
    axes = map_axes(directions(k, 3))
    w = directions(k, 3)
    # each map's frame (e1, e2, w) is right-handed and orthonormal
    np.testing.assert_allclose(np.cross(axes[:, 0], axes[:, 1]), w, atol=1e-14)


def _rim():
    return polygon([0, 0, HEIGHT], RADIUS, SIDES).vertices[1:]


def _inside(xy, rim):
    """(n,) bool: 2-D points inside the convex polygon ``rim`` (k, 2), counter-clockwise."""
    ok = np.ones(len(xy), dtype=bool)
    for a, b in zip(rim, np.roll(rim, -1, axis=0)):
        ok &= (b[0] - a[0]) * (xy[:, 1] - a[1]) - (b[1] - a[1]) * (xy[:, 0] - a[0]) >= 0
    return ok


def _disc_quadrature(points, w, weighting="cosine"):
    """(A_K (n,), bent_K (n, 3) unnormalised): the K-direction estimate with exact
    visibility of floor points (normal +z) under the disc."""
    rim = _rim()
    up = w[:, 2] > 0
    weight = np.where(up, w[:, 2] if weighting == "cosine" else 1.0, 0.0)
    ao, bent = [], []
    for p in points:
        t = (HEIGHT - p[2]) / np.where(up, w[:, 2], 1.0)
        hit = up & _inside(p[:2] + t[:, None] * w[:, :2], rim[:, :2])
        ao.append((weight * ~hit).sum() / weight.sum())
        bent.append(((weight * ~hit)[:, None] * w).sum(axis=0))
    return np.array(ao), np.array(bent)


def _exact(points, normals):
    return 1.0 - polygon_form_factors(points, normals, _rim())


@pytest.mark.slow
def test_the_directions_error_falls_as_k_to_the_minus_three_quarters():
    """The quadrature alone (exact visibility): within 3 K^(-3/4) for every point and seed,
    and its rms falls at least 2.5x per 4x directions (measured 2.7-3.0x)."""
    points, normals = floor_points(24, 0.7, seed=3)
    exact = _exact(points, normals)
    rms = []
    for k in (64, 256, 1024):
        errors = np.array([_disc_quadrature(points, directions(k, seed))[0] - exact
                           for seed in range(8)])
        assert np.abs(errors).max() <= 3.0 * k ** -0.75, k
        rms.append(float(np.sqrt(np.mean(errors ** 2))))
    assert rms[1] < rms[0] / 2.5 and rms[2] < rms[1] / 2.5, rms


def test_traced_is_the_quadrature_with_exact_visibility():
    """``depthmaps.traced`` (each point's K rays through the scene's backend) is the numpy
    quadrature of the disc scene: the directions' error alone, as the benchmark uses it."""
    mesh = combine(quad([0, 0, 0], 3, 3), polygon([0, 0, HEIGHT], RADIUS, SIDES))
    scene = load_scene(mesh)
    occluders = build(scene, BakeConfig())
    points, normals = floor_points(10, 0.7, seed=8)
    for weighting in ("cosine", "uniform"):
        w = directions(128, 6)
        want = _disc_quadrature(points, w, weighting)[0]
        np.testing.assert_allclose(traced(occluders, points, normals, w, weighting), want,
                                   atol=1e-12)


@pytest.mark.slow
def test_neighbouring_points_share_their_error():
    """Every point reads the same K directions, so the quadrature's errors of nearby points
    are correlated (they move with the disc's outline across the same lattice), not
    independent like a ray tracer's: along a line of 200 floor points 0.01 apart the lag-one
    correlation of the errors is about 0.9 (K = 128), and over 16 seeds the mean error of
    the line spreads 2.6x more than independent errors of the same rms would (measured: 3.3,
    2.6, 2.5 at K = 32, 128, 512: the line is worth ~30 independent points, not 200)."""
    n = 200
    points = np.zeros((n, 3))
    points[:, 0] = np.linspace(-0.5, 1.5, n)
    normals = np.tile([0.0, 0.0, 1.0], (n, 1))
    exact = _exact(points, normals)
    errors = np.array([_disc_quadrature(points, directions(128, seed))[0] - exact
                       for seed in range(16)])
    lag_one = np.mean([np.corrcoef(e[:-1], e[1:])[0, 1] for e in errors])
    assert lag_one > 0.8, lag_one
    independent = np.sqrt(np.mean(errors ** 2) / n)
    assert errors.mean(axis=1).std(ddof=1) > 1.8 * independent


# ------------------------------------------------------------------ the maps (GL)

def _crossed_weight(points, w, texel, weighting="cosine"):
    """Per floor point, the summed weight (over the total) of the directions whose line
    from the point passes within WIDEN s / sqrt 2 of the disc's outline in the map's plane,
    and the summed weight vector of those directions (for the bent normal's bound)."""
    rim = _rim()
    axes = map_axes(w)
    margin = WIDEN * texel / math.sqrt(2.0)
    up = w[:, 2] > 0
    weight = np.where(up, w[:, 2] if weighting == "cosine" else 1.0, 0.0)
    share, vector = [], []
    for p in points:
        q = np.einsum("kac,c->ka", axes, p)  # (K, 2) the point in each map
        r = np.einsum("kac,jc->kja", axes, rim)  # (K, sides, 2) the rim in each map
        a, b = r, np.roll(r, -1, axis=1)
        ab = b - a
        t = np.clip(np.einsum("kja,kja->kj", q[:, None] - a, ab)
                    / np.einsum("kja,kja->kj", ab, ab), 0.0, 1.0)
        near = np.linalg.norm(a + t[..., None] * ab - q[:, None], axis=2).min(axis=1)
        crossed = up & (near <= margin)
        share.append(weight[crossed].sum() / weight.sum())
        vector.append(np.linalg.norm((weight[crossed, None] * w[crossed]).sum(axis=0)))
    return np.array(share), np.array(vector)


@pytest.mark.slow
@pytest.mark.parametrize("weighting", ["cosine", "uniform"])
def test_floor_under_a_coaxial_disc_within_the_map_bound(gl, weighting):
    """The GL values against the same K directions with exact visibility, every point within
    its crossed directions' weight, that weight small (about K x s / (pi h) directions'
    share); the bent normal within the angle those directions can turn it by; and the whole
    error against the closed form within the quadrature's bound plus the map's."""
    k, n = 256, 512
    mesh = combine(quad([0, 0, 0], 3, 3), polygon([0, 0, HEIGHT], RADIUS, SIDES))
    method = _prepare(mesh, k, n, weighting=weighting, quantities=("ao", "bent_normal"))
    points, normals = floor_points(16, 0.7, seed=3)
    est = method.estimate(_points(points, normals), 1, 0)
    w = method.w
    quadrature, bent_k = _disc_quadrature(points, w, weighting)
    texel = method.texel / method.scale
    share, vector = _crossed_weight(points, w, texel, weighting)
    error = np.abs(est.fields["ao"] - quadrature)
    assert (error <= share + ROUNDING).all(), (error, share)
    assert share.max() < 0.05 and error.max() < 0.02
    # the bent normal: |b_GL - b_K| <= |summed crossed weight vector|
    total = np.where(w[:, 2] > 0, w[:, 2] if weighting == "cosine" else 1.0, 0.0).sum()
    bent = est.fields["bent_normal"]
    unit_k = bent_k / np.linalg.norm(bent_k, axis=1, keepdims=True)
    angle = np.arccos(np.clip(np.einsum("nc,nc->n", bent, unit_k), -1, 1))
    limit = np.arcsin(np.clip(2 * (vector + ROUNDING * total)
                              / np.linalg.norm(bent_k, axis=1), 0, 1))
    assert (angle <= limit + 1e-6).all(), (angle, limit)
    if weighting == "cosine":
        exact = _exact(points, normals)
        assert (np.abs(est.fields["ao"] - exact) <= 3.0 * k ** -0.75 + share
                + ROUNDING).all()
    assert est.rays is None and set(est.fields) == {"ao", "bent_normal"}


@pytest.mark.slow
def test_the_closed_form_converges_as_k_grows(gl):
    """h^2 / (h^2 + R^2) on the axis, and the off-axis polygon form factor: the rms error
    over the points falls with K (measured at N = 512: 0.034, 0.013, 0.0045 at K = 64, 256,
    1024), as the quadrature's does, the map's share staying below it."""
    mesh = combine(quad([0, 0, 0], 3, 3), polygon([0, 0, HEIGHT], RADIUS, 256))
    points, normals = floor_points(12, 0.7, seed=5)
    points[0] = 0.0
    exact = 1.0 - polygon_form_factors(points, normals,
                                       polygon([0, 0, HEIGHT], RADIUS, 256).vertices[1:])
    assert abs(exact[0] - HEIGHT ** 2 / (HEIGHT ** 2 + RADIUS ** 2)) < 1e-4
    rms = []
    for k in (64, 256, 1024):
        est = _prepare(mesh, k, 512, seed=2).estimate(_points(points, normals), 1, 0)
        rms.append(float(np.sqrt(np.mean((est.fields["ao"] - exact) ** 2))))
    assert rms[0] > rms[1] > rms[2] and rms[2] < rms[0] / 4 and rms[2] < 0.01, rms


@pytest.mark.slow
@pytest.mark.parametrize("weighting", ["cosine", "uniform"])
def test_an_open_plane_is_exactly_one_at_any_tilt(gl, weighting):
    """A tilted plane seen by nothing: every direction above each point's horizon is open,
    so A = 1 exactly (the same sums above and below the fraction bar), and the bent normal
    is the weighted mean of those directions, as numpy sums them."""
    plane = quad([0, 0, 0], 2, 2)
    tilt = trimesh.transformations.rotation_matrix(0.7, [1, 2, 0.5])
    plane.apply_transform(tilt)
    normal = plane.face_normals[0]
    rng = np.random.default_rng(2)
    uv = rng.uniform(-1.8, 1.8, size=(40, 2))
    corner = plane.vertices
    points = (corner[0] + corner[2]) / 2 + uv[:, :1] * (corner[1] - corner[0]) / 4 \
        + uv[:, 1:] * (corner[3] - corner[0]) / 4
    method = _prepare(plane, 64, 128, weighting=weighting, quantities=("ao", "bent_normal"))
    est = method.estimate(_points(points, np.tile(normal, (40, 1))), 1, 0)
    assert (est.fields["ao"] == 1.0).all()
    c = method.w @ normal
    weight = np.where(c > 0, c if weighting == "cosine" else 1.0, 0.0)
    want = (weight[:, None] * method.w).sum(axis=0)
    want /= np.linalg.norm(want)
    assert np.abs(est.fields["bent_normal"] - want).max() < 1e-5


@pytest.mark.slow
def test_without_bias_a_plane_shadows_itself(gl):
    """b = 0: the map's height at a texel centre is the plane's there, above the point half
    the time, so the plane shadows itself ("acne"); b = 0.75 (> 1/sqrt 2) does not."""
    plane = quad([0, 0, 0], 2, 2)
    plane.apply_transform(trimesh.transformations.rotation_matrix(0.5, [1, 0, 0]))
    normal = plane.face_normals[0]
    rng = np.random.default_rng(4)
    uv = rng.uniform(-0.9, 0.9, size=(30, 2))
    points = uv[:, :1] * (plane.vertices[1] - plane.vertices[0]) / 2 \
        + uv[:, 1:] * (plane.vertices[3] - plane.vertices[0]) / 2
    sample = _points(points, np.tile(normal, (30, 1)))
    acne = _prepare(plane, 64, 128, b=0.0).estimate(sample, 1, 0).fields["ao"]
    clean = _prepare(plane, 64, 128, b=0.75).estimate(sample, 1, 0).fields["ao"]
    assert (clean == 1.0).all()
    assert (acne < 1.0).mean() > 0.5 and acne.mean() < 0.95


@pytest.mark.slow
def test_the_ground_plane_blocks_every_direction_going_down(gl):
    """A wall standing on the ground plane: from a point on its face every direction going
    down meets the plane, every other one is open (the wall is flat), so A is the
    quadrature's share of the upper directions (0.5 as K grows); a point on the wall's foot
    facing down is inside the ground (A = 0), as a ray tracer's origin below the plane."""
    wall = quad([0, 0, 0], 1, 1, axis_u=0, axis_v=1)  # normal +z, the ground at y = -1
    points = np.array([[0.0, 0.0, 0.0], [0.5, 0.5, 0.0], [0.0, -0.99, 0.0]])
    normals = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    method = _prepare(wall, 256, 256, ground_plane=True, up_axis="y")
    est = method.estimate(_points(points, normals), 1, 0)
    c = method.w[:, 2]
    weight = np.where(c > 0, c, 0.0)
    want = (weight * (method.w[:, 1] >= 0)).sum() / weight.sum()
    np.testing.assert_allclose(est.fields["ao"], want, atol=ROUNDING)
    assert abs(want - 0.5) < 0.02
    foot = _points([[0.0, -1.0, 0.0]], [[0.0, -1.0, 0.0]])
    assert method.estimate(foot, 1, 0).fields["ao"][0] == 0.0
    free = _prepare(wall, 256, 256).estimate(_points(points, normals), 1, 0)
    assert (free.fields["ao"] == 1.0).all()


# ------------------------------------------------------------------ the method's contract

@pytest.mark.slow
def test_any_split_gives_the_same_bits_and_zero_normals_say_nothing(gl):
    """A point's value depends on that point alone: all points in one call, reversed, and
    in parts merged by index are the same bits; the same seed the same bits, another seed
    other values; a zero normal gets the no-information 0.5 and is not baked."""
    mesh = trimesh.creation.torus(1.0, 0.4, major_sections=24, minor_sections=12)
    scene = load_scene(mesh)
    config = BakeConfig(quantities=("ao", "bent_normal"), seed=3)
    method = DepthmapsMethod.prepare(scene, config, None, 0,
                                     options=DepthmapsOptions(32, 128, 1.0))
    normals = scene.vertex_normals.copy()
    normals[5] = 0.0
    every = method.estimate(_points(scene.vertices, normals), 2, 0)
    ao = every.fields["ao"]
    assert ao[5] == NO_INFORMATION_AO and every.extras["depthmaps_renderer"][5] == ""
    assert (every.fields["bent_normal"][5] == 0.0).all()
    assert ((ao >= 0) & (ao <= 1)).all() and ao.min() < 0.9
    n = len(ao)
    order = np.arange(n)[::-1]
    backwards = method.estimate(_points(scene.vertices[order], normals[order]), 1, 0)
    np.testing.assert_array_equal(backwards.fields["ao"][::-1], ao)
    np.testing.assert_array_equal(backwards.fields["bent_normal"][::-1],
                                  every.fields["bent_normal"])
    cut = [np.arange(0, 37), np.arange(37, n)]
    parts = [(i, method.estimate(_points(scene.vertices[i], normals[i]), 1, 0)) for i in cut]
    merged = merge(parts, n)
    for name in every.fields:
        np.testing.assert_array_equal(merged.fields[name], every.fields[name])
    again = DepthmapsMethod.prepare(scene, config, None, 0,
                                    options=DepthmapsOptions(32, 128, 1.0))
    np.testing.assert_array_equal(again.estimate(_points(scene.vertices, normals), 1, 0)
                                  .fields["ao"], ao)
    other = DepthmapsMethod.prepare(scene, BakeConfig(seed=4), None, 0,
                                    options=DepthmapsOptions(32, 128, 1.0))
    assert not np.array_equal(other.estimate(_points(scene.vertices, normals), 1, 0)
                              .fields["ao"], ao)
    record = method.record(every)["parameters"]
    assert record["depthmaps_directions"] == 32 and record["points_baked"] == n - 1
    assert record["texel"] > 0 and record["bias_height"] == record["texel"]


@pytest.mark.slow
@pytest.mark.parametrize("space", ["object", "tangent"])
def test_a_lightmap_has_its_bent_normals(gl, space, tmp_path):
    """Texels: ao and the bent normal's three channels (unit, in object or tangent space),
    near the ray tracer's (a torus at K = 256: median angle 0.5 and 0.3 degrees against
    1024 rays), written to an EXR with them."""
    mesh = trimesh.creation.torus(1.0, 0.4, major_sections=32, minor_sections=16)
    options = dict(quantities=("ao", "bent_normal"), resolution=48, bent_space=space)
    maps = aobake.bake_texels(mesh, method="depthmaps", **options)
    rays = aobake.bake_texels(mesh, rays=512, **options)
    axes = [f"bent_normal.{a}" for a in "XYZ"]
    assert set(axes) <= set(maps.channels)
    covered = maps.covered
    bent = np.stack([maps.channels[a] for a in axes], axis=-1)[covered]
    want = np.stack([rays.channels[a] for a in axes], axis=-1)[covered]
    assert np.abs(np.linalg.norm(bent, axis=1) - 1.0).max() < 1e-6
    angle = np.degrees(np.arccos(np.clip(np.einsum("nc,nc->n", bent, want), -1, 1)))
    assert np.median(angle) < 2.0, np.median(angle)
    path = tmp_path / "map.exr"
    aobake.write(maps, path)
    from aobake.outputs import read

    for name in ["ao"] + axes:
        again = read(path, "ao", key=name)
        np.testing.assert_array_equal(again.value[covered], maps.channels[name][covered])


def test_settings_it_cannot_honour_are_refused_before_any_work():
    """A finite max distance (the declaration and the check, before any file is read, and
    the method's own prepare), quantities other than ao and bent_normal, back faces let
    through, ray counts: each refused with one line naming the method."""
    assert not capabilities.METHODS["depthmaps"].max_distance
    for distance in (2.0, "10%", 0.0):
        with pytest.raises(UsageError, match="--method depthmaps"):
            capabilities.check("depthmaps", "vertices", BakeConfig(max_distance=distance))
    capabilities.check("depthmaps", "vertices", BakeConfig(max_distance="inf"))
    capabilities.check("rays", "vertices", BakeConfig(max_distance=2.0))
    with pytest.raises(UsageError, match="--method depthmaps"):
        aobake.bake("no such mesh.obj", method="depthmaps", max_distance=1.0)
    scene = load_scene(quad([0, 0, 0], 1, 1))
    for config, words in ((BakeConfig(quantities=("obscurance",)), "ao and bent_normal"),
                          (BakeConfig(max_distance=1.0), "whole scene"),
                          (BakeConfig(backfaces="ignore"), "back faces occlude"),
                          (BakeConfig(tolerance=0.01), "casts no rays"),
                          (BakeConfig(keep_distances=True), "casts no rays")):
        with pytest.raises(InputError, match=words):
            DepthmapsMethod.prepare(scene, config, None, 0)


def test_bad_settings_are_refused_with_the_setting_named():
    assert "depthmaps" in METHODS
    for field, bad in (("depthmaps_directions", 0), ("depthmaps_directions", 70000),
                       ("depthmaps_resolution", 8), ("depthmaps_resolution", 8192),
                       ("depthmaps_bias", -1.0), ("depthmaps_bias", float("nan"))):
        with pytest.raises(InputError, match=field.replace("_", " ")):
            BakeConfig(**{field: bad})
    assert DepthmapsOptions.of(BakeConfig(depthmaps_directions=8)).depthmaps_directions == 8
    assert DepthmapsOptions.of(object()) == DepthmapsOptions()


def test_without_moderngl_the_message_says_what_to_install(monkeypatch):
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "moderngl" else find_spec(name, *a))
    with pytest.raises(DepthmapsError, match=r"pip install 'aobake\[gl\]'"):
        DepthmapsMethod.prepare(load_scene(quad([0, 0, 0], 1, 1)), BakeConfig(), None, 0)
    assert available()[0] is False


@pytest.mark.slow
def test_the_command_line_bakes_and_reports_it(gl, tmp_path):
    """``aobake MESH --method depthmaps``: ao and bent normals per vertex, the settings in
    the report's config and parameters; ``--max-distance`` refused with exit 2."""
    mesh = tmp_path / "scene.ply"
    floor = trimesh.creation.box((3.0, 0.1, 3.0))
    floor.apply_translation((0, -0.05, 0))
    box = trimesh.creation.box((0.8, 0.8, 0.8))
    box.apply_translation((0.2, 0.4, 0))
    trimesh.util.concatenate([floor, box]).export(mesh)
    out, report = tmp_path / "ao.npz", tmp_path / "report.json"
    result = run_cli(mesh, "--out", out, "--report", report, "--method", "depthmaps",
                     "-q", "ao", "-q", "bent_normal", "--depthmaps-directions", "48",
                     "--depthmaps-resolution", "256", "--depthmaps-bias", "0.8")
    assert result.exit_code == 0, result.output
    import json

    data = json.loads(report.read_text())
    assert data["config"]["depthmaps_directions"] == 48
    assert data["parameters"]["depthmaps_bias"] == 0.8
    assert data["parameters"]["method"] == "depthmaps"
    values = np.load(out)
    assert values["ao"].min() < 0.8 and values["ao"].max() <= 1.0
    assert "ao_stderr" not in values.files
    refused = run_cli(mesh, "--out", tmp_path / "x.npz", "--method", "depthmaps",
                      "--max-distance", "1")
    assert refused.exit_code == 2 and "--method depthmaps" in refused.output
