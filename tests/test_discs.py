"""``--method discs`` (Bunnell's disc AO): its closed forms, passes, hierarchy and plumbing.

An approximation has no error bar: its tests are the closed forms it must reproduce
exactly (to rounding), the algebra of its passes against an independent dense
computation, the hierarchy against brute force, and the bit-identity every method owes
the executors (any split of the points gives the same rows).  Rounding tolerances are
counted from the operations involved, in units of float64's epsilon.

These are the chapter's model's tests (``discs_model="chapter"``, named wherever the
model matters); the robust model's are in tests/test_discs_robust.py, and the plumbing
tests here run the default.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

import aobake
from aobake.settings import BakeConfig
from aobake.errors import InputError
from aobake.methods import METHODS
from aobake.methods.discs import (HIERARCHY_RMSE, NO_INFORMATION_AO, DiscsMethod, DiscsOptions,
                                  chapter_shadow, elements, lecture_shadow)
from aobake.scene import Scene, load_scene
from aobake.records import SamplePoints
from aobake.vectors import normalize

EPS = np.finfo(np.float64).eps

#: the chapter's model, which these tests describe
CHAPTER = dict(discs_model="chapter")


def _points(points, normals) -> SamplePoints:
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    return SamplePoints(points, normals, np.arange(len(points), dtype=np.int64))


def _one_disc(distance, radius, emitter_normal, options=None, max_distance=math.inf):
    """A disc of radius ``radius`` on the z axis at height ``distance`` and the pass-1 AO at
    the origin (normal +z)."""
    method = DiscsMethod.from_elements([[0.0, 0.0, distance]], [emitter_normal],
                                       [math.pi * radius * radius],
                                       options or DiscsOptions(discs_passes=1, **CHAPTER),
                                       max_distance=max_distance)
    return method.estimate(_points([0, 0, 0], [0, 0, 1]), 1, 1024).fields["ao"][0]


def _tori() -> trimesh.Trimesh:
    """Two interlocking tori: closed, curved, occluding each other (2304 elements)."""
    a = trimesh.creation.torus(1.0, 0.35, major_sections=48, minor_sections=24)
    b = trimesh.creation.torus(1.0, 0.35, major_sections=48, minor_sections=24)
    b.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    b.apply_translation([1.0, 0.0, 0.0])
    return trimesh.util.concatenate([a, b])


@pytest.fixture(scope="module")
def tori_elements():
    return elements(load_scene(_tori()))


# ---------------------------------------------------------------------------- closed forms

def test_shadow_on_axis_is_the_discs_solid_angle_fraction():
    """On axis the chapter's shadow is Omega / (2 pi) of a disc of radius r at distance d:
    1 - cos(alpha) = 2 sin^2(alpha / 2), alpha = atan(r / d) (evaluated through trig: an
    independent path), from near contact to far away, and through the method itself."""
    radius = 1.0
    distance = np.logspace(-3, 4, 29)
    oracle = 2.0 * np.sin(np.arctan2(radius, distance) / 2.0) ** 2
    got = chapter_shadow(math.pi * radius * radius, distance, 1.0, 1.0)
    # 7 rounded operations in the formula (x, 1 + x, sqrt, s + 1, product, quotient, area),
    # 5 in the oracle (atan2, halving, sin, square, doubling), each within 1 eps relative.
    np.testing.assert_allclose(got, oracle, rtol=12 * EPS, atol=0)
    for d, want in zip(distance[::7], oracle[::7]):
        # behind the disc (its normal points away from the receiver): it shadows
        ao = _one_disc(d, radius, [0, 0, 1])
        assert abs(ao - (1.0 - want)) <= 12 * EPS
        # facing the receiver (its front): it casts nothing, as the Cg code's sat(n_E . v)
        assert _one_disc(d, radius, [0, 0, -1]) == 1.0


def test_receiver_term_saturates_at_one_over_k():
    """sat(k n_R . v): linear in cos(theta_R) below 1/k, 1 above; the book's k = 4 is the
    default (the CD's shader: 3)."""
    assert DiscsOptions().discs_k == 4.0
    area, d = 0.5, 3.0
    full = chapter_shadow(area, d, 1.0, 1.0)
    for k in (3.0, 4.0):
        below, above = 0.5 / k, 1.5 / k
        assert chapter_shadow(area, d, 1.0, below, k) == pytest.approx(full * k * below,
                                                                       rel=4 * EPS)
        assert chapter_shadow(area, d, 1.0, above, k) == full
        assert chapter_shadow(area, d, 1.0, -above, k) == 0.0


def test_the_lectures_printed_form_does_not_vanish_with_distance():
    """1 - r cos(theta_E) max(1, 4 cos(theta_R)) / sqrt(A/pi + r^2) tends to
    1 - cos(theta_E) max(1, 4 cos(theta_R)), not 0, as r grows; the chapter's form falls
    as A cos(theta_E) sat(k cos(theta_R)) / (2 pi r^2)."""
    area, cos_e, cos_r = 1.0, 0.5, 0.1
    limit = 1.0 - cos_e * max(1.0, 4.0 * cos_r)
    assert limit == 0.5  # far from 0: the printed form is not a shadow
    for r in 10.0 ** np.arange(1, 7):
        x = area / (math.pi * r * r)
        lecture = lecture_shadow(area, r, cos_e, cos_r)
        # its distance from the limit: cos_e max(..) (1 - 1/sqrt(1 + x)) <= cos_e max(..) x / 2
        assert abs(lecture - limit) <= cos_e * max(1.0, 4.0 * cos_r) * x / 2 + 4 * EPS
        chapter = chapter_shadow(area, r, cos_e, cos_r)
        far = area * cos_e * min(1.0, 4.0 * cos_r) / (2.0 * math.pi * r * r)
        # 1 - 1/sqrt(1 + x) = x/2 (1 - 3x/4 + ...): within 3x/4 relative of the far form
        assert abs(chapter - far) <= far * (0.75 * x + 8 * EPS)


# ---------------------------------------------------------------------------- passes

def _dense_shadows(receivers, receiver_normals, position, normal, area, k=4.0):
    """(c, n) every emitter's shadow at every receiver, by chapter_shadow (an O(c n) matrix:
    an oracle for the passes' algebra, independent of the method's gathers)."""
    diff = position[None, :, :] - receivers[:, None, :]
    d = np.linalg.norm(diff, axis=2)
    safe = np.where(d > 0, d, 1.0)
    v = diff / safe[..., None]
    cos_e = np.einsum("jk,ijk->ij", normal, v)
    cos_r = np.einsum("ik,ijk->ij", receiver_normals, v)
    return np.where(d > 0, chapter_shadow(area[None, :], safe, cos_e, cos_r, k), 0.0)


def test_passes_weight_each_emitter_by_its_own_previous_pass():
    """Pass 1 = sat(1 - sum S); pass j = sat(1 - sum S a_(j-1)(emitter)), a the emitters'
    own previous pass; the result is weight * pass P + (1 - weight) * pass P-1."""
    rng = np.random.default_rng(7)
    n = 40
    position = rng.uniform(-1, 1, (n, 3))
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    area = rng.uniform(0.05, 0.4, n)
    receivers = rng.uniform(-1, 1, (25, 3))
    receiver_normals = rng.normal(size=(25, 3))
    receiver_normals /= np.linalg.norm(receiver_normals, axis=1, keepdims=True)

    s_ee = _dense_shadows(position, normal, position, normal, area)
    s_re = _dense_shadows(receivers, receiver_normals, position, normal, area)
    a1 = np.clip(1 - s_ee.sum(axis=1), 0, 1)
    a2 = np.clip(1 - s_ee @ a1, 0, 1)
    p1 = np.clip(1 - s_re.sum(axis=1), 0, 1)
    p2 = np.clip(1 - s_re @ a1, 0, 1)
    p3 = np.clip(1 - s_re @ a2, 0, 1)
    # n terms each below 1, summed in different orders, twice (a pass of a pass): the
    # sums differ by at most 2 n eps per level of passes.
    atol = 3 * 2 * n * EPS
    points = _points(receivers, receiver_normals)
    cases = {(1, 0.6): p1, (2, 0.6): 0.6 * p2 + 0.4 * p1, (3, 0.6): 0.6 * p3 + 0.4 * p2,
             (2, 0.25): 0.25 * p2 + 0.75 * p1}
    for (passes, weight), want in cases.items():
        options = DiscsOptions(discs_passes=passes, discs_weight=weight,
                               discs_traversal="brute", **CHAPTER)
        method = DiscsMethod.from_elements(position, normal, area, options)
        got = method.estimate(points, 1, 4096)
        np.testing.assert_allclose(got.fields["ao"], want, rtol=0, atol=atol)
        np.testing.assert_allclose(got.extras["discs_passes"], np.stack([p1, p2, p3][:passes],
                                                                        axis=1)[:, :passes],
                                   rtol=0, atol=atol)
    assert (p2 >= p1).all()  # a pass never darkens: its weights are <= 1
    assert p1.mean() < p2.mean()  # and here it lightens (the scene overlaps)
    # The CD's shader reads the next element's pass 1: a test that cannot tell would prove
    # nothing, so check that this scene does tell.
    shifted = np.clip(1 - s_re @ np.roll(a1, -1), 0, 1)
    assert np.abs(shifted - p2).max() > 100 * atol


# ---------------------------------------------------------------------------- hierarchy

def _rmse(a, b) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)))


@pytest.mark.slow
def test_hierarchy_that_opens_every_node_is_brute_force(tori_elements):
    """With kappa beyond the scene's span over the smallest disc's radius every node is
    opened: the same terms as brute force, summed in another order (and with a max
    distance, the same elements cut)."""
    position, normal, area = tori_elements
    n = len(position)
    span = float(np.linalg.norm(position.max(axis=0) - position.min(axis=0)))
    kappa = 2.0 * span / math.sqrt(area.min() / math.pi)
    points = _points(position[::7], normal[::7])
    # pass 1 sums n terms below 1 in two orders (n eps each); pass 2 weights them by
    # values that differ by as much: 4 n eps in all, per sum of at most n.
    atol = 4 * n * n * EPS
    for max_distance in (math.inf, 0.7):
        brute = DiscsMethod.from_elements(position, normal, area,
                                          DiscsOptions(discs_traversal="brute", **CHAPTER),
                                          max_distance)
        tree = DiscsMethod.from_elements(position, normal, area,
                                         DiscsOptions(discs_kappa=kappa, **CHAPTER),
                                         max_distance)
        a, b = brute.estimate(points, 1, 1 << 16), tree.estimate(points, 1, 1 << 16)
        np.testing.assert_allclose(b.fields["ao"], a.fields["ao"], rtol=0, atol=atol)
        assert (b.extras["discs_terms"] <= n).all()
    assert (a.fields["ao"] > 0.5).any() and (a.fields["ao"] < 0.99).any()  # a real test


@pytest.mark.slow
def test_hierarchy_agrees_with_brute_force_within_the_stated_tolerance(tori_elements):
    """At the default kappa the hierarchy is within HIERARCHY_RMSE of brute force (the
    claim docs/discs.md states), and each doubling of kappa at least halves its error
    (the stand-in disc's error is second order in the node's size over the distance: the
    measured rate is between 2.5 and 6 per doubling)."""
    position, normal, area = tori_elements
    points = _points(position, normal)
    brute = DiscsMethod.from_elements(position, normal, area,
                                      DiscsOptions(discs_traversal="brute", **CHAPTER))
    truth = brute.estimate(points, 1, 1 << 17).fields["ao"]
    errors = {}
    for kappa in (2.0, 4.0, 8.0):
        tree = DiscsMethod.from_elements(position, normal, area,
                                         DiscsOptions(discs_kappa=kappa, **CHAPTER))
        errors[kappa] = _rmse(tree.estimate(points, 1, 1 << 17).fields["ao"], truth)
    assert errors[DiscsOptions().discs_kappa] <= HIERARCHY_RMSE, errors
    assert errors[4.0] <= errors[2.0] / 2 and errors[8.0] <= errors[4.0] / 2, errors
    assert errors[8.0] > 0  # the hierarchy did approximate


# ---------------------------------------------------------------------------- conventions

def test_max_distance_drops_farther_elements():
    """An element whose centre is beyond the max distance contributes nothing; one within
    it contributes its whole shadow."""
    d, radius = 2.0, 0.5
    whole = 1.0 - chapter_shadow(math.pi * radius * radius, d, 1.0, 1.0)
    assert _one_disc(d, radius, [0, 0, 1], max_distance=d * (1 - 4 * EPS)) == 1.0
    assert abs(_one_disc(d, radius, [0, 0, 1], max_distance=d) - whole) <= 12 * EPS
    scene = load_scene(_tori())
    method = DiscsMethod.prepare(scene, BakeConfig(max_distance="10%"), None, 0)
    assert method.max_distance == pytest.approx(0.1 * scene.diagonal, rel=4 * EPS)


@pytest.mark.slow
def test_a_point_without_normal_gets_no_information(tori_elements):
    position, normal, area = tori_elements
    method = DiscsMethod.from_elements(position, normal, area)
    points = _points(position[:4], np.vstack([normal[:2], np.zeros((2, 3))]))
    got = method.estimate(points, 1, 4096)
    np.testing.assert_array_equal(got.fields["ao"][2:], NO_INFORMATION_AO)
    assert np.isnan(got.extras["discs_passes"][2:]).all()
    np.testing.assert_array_equal(got.extras["discs_terms"][2:], 0)
    assert np.isfinite(got.fields["ao"][:2]).all() and (got.extras["discs_terms"][:2] > 0).all()


def test_elements_are_the_chapters_discs():
    """One disc per vertex: area = sum of its faces' areas / 3 (they add up to the mesh's),
    normal = the normalised sum of its faces' unit normals."""
    mesh = trimesh.creation.box()
    scene = load_scene(mesh)
    position, normal, area = elements(scene)
    assert len(position) == 8
    assert area.sum() == pytest.approx(scene.areas().sum(), rel=8 * EPS)
    for v in range(8):  # the chapter's loop, vertex by vertex
        around = np.flatnonzero((scene.faces == v).any(axis=1))
        summed = scene.face_normals[around].sum(axis=0)
        row = np.flatnonzero((position == scene.vertices[v]).all(axis=1))[0]
        np.testing.assert_allclose(normal[row], summed / np.linalg.norm(summed), atol=4 * EPS)
        assert area[row] == pytest.approx(scene.areas()[around].sum() / 3, rel=4 * EPS)
    # a cube's corner disc leans outward along each of its three faces
    assert (normal * np.sign(position) > 0).all()


def test_scaling_by_a_power_of_two_changes_no_bit(tori_elements):
    position, normal, area = tori_elements
    points = _points(position[::5] * 1.01, normal[::5])
    options = DiscsOptions(**CHAPTER)
    base = DiscsMethod.from_elements(position, normal, area, options).estimate(points, 1, 4096)
    s = 2.0 ** 60
    scaled = DiscsMethod.from_elements(position * s, normal, area * s * s, options)
    big = scaled.estimate(_points(points.points * s, points.normals), 1, 4096)
    np.testing.assert_array_equal(base.fields["ao"], big.fields["ao"])


# ---------------------------------------------------------------------------- method protocol

@pytest.mark.slow
@pytest.mark.parametrize("traversal", ["hierarchy", "brute"])
def test_any_split_of_the_points_gives_the_same_rows(tori_elements, traversal):
    """Each point's value from that point alone: a permutation, a subset, other chunk
    sizes and thread counts give the same bits (tests/test_executors.py's contract)."""
    position, normal, area = tori_elements
    method = DiscsMethod.from_elements(position, normal, area,
                                       DiscsOptions(discs_traversal=traversal, **CHAPTER))
    rng = np.random.default_rng(3)
    query = np.vstack([position[::3], rng.uniform(-1.5, 2.5, (200, 3))])
    normals = np.vstack([normal[::3], rng.normal(size=(200, 3))])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    normals[::50] = 0.0  # some without information
    whole = method.estimate(_points(query, normals), 1, 1 << 17)
    order = rng.permutation(len(query))
    for index, threads, chunk in ((order, 2, 5000), (order[:97], 1, 300), (order[::2], 2, 1)):
        part = method.estimate(_points(query[index], normals[index]), threads, chunk)
        np.testing.assert_array_equal(part.fields["ao"], whole.fields["ao"][index])
        for name in ("discs_passes", "discs_terms"):
            np.testing.assert_array_equal(part.extras[name], whole.extras[name][index])
    assert part.rays is None and set(part.fields) == {"ao"}


def test_registered_and_it_records_every_parameter_and_each_pass():
    assert METHODS["discs"] is DiscsMethod and not DiscsMethod.casts_rays
    options = DiscsOptions(**CHAPTER)
    method = DiscsMethod.from_elements(*elements(load_scene(_tori())), options)
    assert method.error_quantities() == [] and method.kernel_stages() == {}
    got = method.estimate(_points(method.position[:50] / method.scale + method.center,
                                  method.normal[:50]), 1, 4096)
    parameters = method.record(got)["parameters"]
    for name in ("discs_model", "discs_k", "discs_passes", "discs_weight", "discs_kappa",
                 "discs_traversal"):
        assert parameters[name] == getattr(options, name)
    assert parameters["method"] == "discs" and parameters["max_distance"] == math.inf
    means = got.extras["discs_passes"].mean(axis=0)
    # the same mean in another summation order: within n eps
    assert parameters["pass_means"] == pytest.approx(means.tolist(), rel=len(means) * 50 * EPS)
    assert parameters["pass_means"][0] <= parameters["pass_means"][1]
    assert len(parameters["element_pass_means"]) == options.discs_passes - 1


def test_bad_options_and_inputs_are_input_errors():
    for bad in (dict(discs_kappa=0.0), dict(discs_kappa=-1.0), dict(discs_kappa=math.inf),
                dict(discs_k=math.nan), dict(discs_passes=0), dict(discs_passes=1.5),
                dict(discs_weight=1.5), dict(discs_traversal="bvh"),
                dict(discs_model="bunnell")):
        with pytest.raises(InputError):
            DiscsOptions(**bad)
    scene = load_scene(_tori())
    for config in (BakeConfig(quantities=("ao", "obscurance")), BakeConfig(ground_plane=True),
                   BakeConfig(tolerance=0.05)):
        with pytest.raises(InputError):
            DiscsMethod.prepare(scene, config, None, 0)
    flat = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])  # a triangle without area
    no_area = Scene(flat, np.array([[0, 1, 2]]), np.zeros((3, 3)), np.zeros((1, 3)))
    with pytest.raises(InputError, match="no faces with area"):
        DiscsMethod.prepare(no_area, BakeConfig(), None, 0)


# ---------------------------------------------------------------------------- through the bake

def _small_mesh() -> trimesh.Trimesh:
    return trimesh.creation.torus(1.0, 0.4, major_sections=24, minor_sections=12)


@pytest.mark.slow
def test_bake_view_and_bake_points_run_discs_without_rays_or_stderr():
    mesh = _small_mesh()
    view = aobake.bake_view(mesh, method="discs", size=(40, 30), threads=1)
    assert "ao" in view.channels and "ao_stderr" not in view.channels
    assert "rays" not in view.channels
    report = view.report
    assert report["parameters"]["method"] == "discs" and report["error"] == {}
    assert "rays_cast" not in report
    covered = view.covered
    ao = view.channels["ao"][covered]
    assert ((ao >= 0) & (ao <= 1)).all() and ao.min() < 1.0

    scene = load_scene(mesh)
    query, normals = scene.vertices[::5], scene.vertex_normals[::5]
    result = aobake.bake_points(mesh, query, normals, method="discs", threads=1)
    assert result.rays is None and result.ao_stderr is None
    # the points target normalises the normals (to the last bit): the same here
    direct = DiscsMethod.prepare(scene, BakeConfig(), None, 0).estimate(
        _points(query, normalize(normals)[0]), 1, 4096)
    np.testing.assert_array_equal(result.ao, direct.fields["ao"])
    other = aobake.bake_points(mesh, query, normals, method="discs", executor="processes",
                               workers=2, chunk_points=17)
    np.testing.assert_array_equal(result.ao, other.ao)
    assert other.report["parameters"] == result.report["parameters"]


@pytest.mark.slow
def test_bake_per_vertex_runs_discs():
    """``aobake.bake(mesh, method="discs")``: the method's values at the vertex target's
    points, no rays, no stderr, no error summary, and the same bits in chunks."""
    from aobake.targets.vertices import VertexTarget

    mesh = _small_mesh()
    result = aobake.bake(mesh, method="discs", threads=1)
    assert result.rays is None and result.ao_stderr is None
    assert result.report["error"] == {} and "rays_cast" not in result.report
    scene = load_scene(mesh)
    plan = VertexTarget().sample(scene, BakeConfig(), None, 1, {}, [])
    direct = DiscsMethod.prepare(scene, BakeConfig(), None, 0).estimate(plan, 1, 4096)
    np.testing.assert_array_equal(result.ao, direct.fields["ao"][plan.state])
    chunked = aobake.bake(mesh, method="discs", threads=2, chunk_points=29)
    np.testing.assert_array_equal(result.ao, chunked.ao)
    assert chunked.report["parameters"] == result.report["parameters"]


@pytest.mark.slow
def test_bake_texels_runs_discs():
    """A lightmap of a method that casts no rays: values and coverage, no stderr, no rays;
    the covered texels are the ray-traced bake's (the same atlas)."""
    result = aobake.bake_texels(_small_mesh(), method="discs", resolution=32, threads=1)
    assert set(result.channels) == {"ao", "coverage"}
    traced = aobake.bake_texels(_small_mesh(), rays=8, resolution=32, threads=1)
    assert (result.covered == traced.covered).all()
    assert 0 <= result.channels["ao"].min() and result.channels["ao"].max() <= 1


def test_pass_two_is_never_darker_than_pass_one():
    """Pass 2 weights every emitter's shadow by its own pass-1 accessibility, a factor in
    [0, 1], so its summed shadow is at most pass 1's: pass 2 >= pass 1 at every point (the
    correction of pass 1's over-darkening), and pass 1 alone is darker on average."""
    result = aobake.bake(_small_mesh(), method="discs", discs_passes=3, threads=1)
    from aobake import occluders
    from aobake.settings import BakeConfig
    from aobake.methods.discs import DiscsMethod
    from aobake.scene import load_scene
    from aobake.records import SamplePoints

    scene = load_scene(_small_mesh())
    config = BakeConfig(discs_passes=3)
    method = DiscsMethod.prepare(scene, config, occluders.build(scene, config), 1)
    ids = np.arange(len(scene.vertices))
    estimates = method.estimate(SamplePoints(scene.vertices, scene.vertex_normals, ids),
                                1, 1 << 16)
    passes = estimates.extras["discs_passes"]
    assert passes.shape == (len(scene.vertices), 3)
    assert (passes[:, 1] >= passes[:, 0]).all()
    assert passes[:, 0].mean() < passes[:, 1].mean()
    assert result.report["parameters"]["method"] == "discs"
