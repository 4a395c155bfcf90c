"""``--method discs --discs-model robust``: Hoberock and Jia's fixes to the chapter.

The exact near field against Lambert's polygon form factor (an independent clip and the
closed form in tests/analytic.py), open sheets that cast from both sides where the
chapter's cast from their backs only (a floor under a coaxial disc: h^2 / (h^2 + R^2)),
closed surfaces counted once, the contact rules, the blend between hierarchy levels
(continuous: its largest step halves with the sampling step, where the chapter's jumps
stay), the bit-identity every method owes the executors, and the still life's error
against the ray-traced truth, the issue's target.  Rounding tolerances count the
operations involved in units of float64's epsilon; the agreement with the truth is the
measured error of an approximation, its tolerance the target with the truth's noise
taken out.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

import aobake
from aobake.errors import InputError
from aobake.methods import discs_tree
from aobake.methods.discs import (DEFAULT_MODEL, DiscsMethod, DiscsOptions, closed_elements,
                                  element_faces, elements)
from aobake.records import SamplePoints
from aobake.scene import load_scene
from aobake.settings import BakeConfig

from analytic import floor_points, polygon, polygon_form_factor, polygon_form_factors, quad

EPS = np.finfo(np.float64).eps
STILL_LIFE = Path(__file__).resolve().parents[1] / "assets" / "still_life.obj"

#: the issue's target: per-vertex RMSE against the ray-traced truth on the still life
STILL_LIFE_RMSE = 0.10

#: every node opened, every element exact: kappa far beyond these scenes' spans over their
#: smallest disc's radius (the setting's upper limit)
EVERY_NODE = 1e6


def _points(points, normals) -> SamplePoints:
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    return SamplePoints(points, normals, np.arange(len(points), dtype=np.int64))


def _ao(mesh, points, normals, **options) -> np.ndarray:
    scene = load_scene(mesh)
    method = DiscsMethod.prepare(scene, BakeConfig(), None, 0, options=DiscsOptions(**options))
    return method.estimate(_points(points, normals), 1, 1 << 16).fields["ao"]


def _flip(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    return trimesh.Trimesh(mesh.vertices, mesh.faces[:, ::-1], process=False)


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ---------------------------------------------------------------------------- the near field

def _clip(corners, point, normal) -> np.ndarray:
    """The part of a polygon on the positive side of the plane through ``point`` with
    ``normal`` (Sutherland-Hodgman, one plane): an oracle independent of the method's clip."""
    out = []
    k = len(corners)
    for i in range(k):
        a, b = corners[i], corners[(i + 1) % k]
        sa, sb = np.dot(a - point, normal), np.dot(b - point, normal)
        if sa >= 0:
            out.append(a)
        if (sa >= 0) != (sb >= 0):
            out.append(a + sa / (sa - sb) * (b - a))
    return np.array(out)


def test_triangle_form_factor_is_lamberts_of_the_part_above_the_horizon():
    """Random triangles and receivers: the kernel's form factor is Lambert's of the triangle
    clipped to the receiver's hemisphere, reported as ``back`` where the receiver is
    behind the triangle and ``front`` otherwise."""
    rng = np.random.default_rng(11)
    m = 600
    points = rng.uniform(-1, 1, (m, 3))
    normals = _unit(rng.normal(size=(m, 3)))
    corners = rng.uniform(-2, 2, (m, 3, 3))
    face_normal = _unit(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]))
    size = np.max([np.linalg.norm(corners[:, (i + 1) % 3] - corners[:, i], axis=1)
                   for i in range(3)], axis=0)
    back, front, enclosed, edge_on = discs_tree.triangle_form_factors(
        points, normals, corners, face_normal, size)
    assert not enclosed.any() and not edge_on.any()
    straddling = 0
    for i in range(m):
        part = _clip(corners[i], points[i], normals[i])
        want = polygon_form_factor(points[i], normals[i], part) if len(part) >= 3 else 0.0
        straddling += len(part) == 4
        behind = np.dot(face_normal[i], points[i] - corners[i, 0]) < 0
        got = back[i] if behind else front[i]
        assert (front[i] if behind else back[i]) == 0.0
        # a sum of four atan2s of values of order 1 against one of up to four: both within
        # a few tens of eps of the exact number
        assert got == pytest.approx(want, abs=64 * EPS), i
    assert straddling > 50  # the clip was exercised
    assert (back > 0).sum() > 50 and (front > 0).sum() > 50


def test_a_receiver_on_a_triangle_takes_the_limit_from_its_side():
    """On the triangle's plane: the one-sided limit on the side the normal points to, (1 -
    |n_R . n_f|) / 2 at an inner point (half the hemisphere lies beyond the plane, cosine-
    weighted); 0 at a corner of its own triangle; a normal along the plane touches it
    (``edge_on``) unless it steps off over an edge; a normal into its back is ``enclosed``."""
    tri = np.array([[[-1.0, -1.0, 0.0], [2.0, -1.0, 0.0], [-1.0, 2.0, 0.0]]])
    up = np.array([[0.0, 0.0, 1.0]])

    def call(point, normal):
        return discs_tree.triangle_form_factors(np.array([point], dtype=np.float64),
                                                _unit([normal]), tri, up, np.array([3 * 2 ** 0.5]))

    for angle in (0.0, 0.4, 1.0, 1.4):  # tilted from the front's normal
        c = math.cos(angle)
        back, front, enclosed, edge_on = call([0.0, 0.0, 0.0], [math.sin(angle), 0.0, c])
        # the limit is taken LIMIT_HEIGHT x the size off the plane, about 1e-6 of the way
        # to the nearest edge: the error is of that order
        assert front[0] == pytest.approx((1 - c) / 2, abs=1e-5) and back[0] == 0.0
        assert not enclosed[0] and not edge_on[0]
    assert call([-1.0, -1.0, 0.0], [0.0, 0.0, 1.0])[1][0] == 0.0   # its own corner
    back, front, enclosed, edge_on = call([0.0, 0.0, 0.0], [1.0, 0.0, 0.0])
    assert edge_on[0] and not enclosed[0] and back[0] == front[0] == 0.0
    assert call([0.0, 0.0, 0.0], [0.0, 0.0, -1.0])[2][0]          # facing into its back
    # on the edge y = -1: stepping out (-y) leaves the triangle, stepping in (+y) stays
    assert not call([0.0, -1.0, 0.0], [0.0, -1.0, 0.0])[3][0]
    assert call([0.0, -1.0, 0.0], [0.0, 1.0, 0.0])[3][0]
    # beside the triangle in its plane: nothing
    assert call([5.0, 5.0, 0.0], [0.3, 0.0, 1.0])[:2] == (0.0, 0.0)


# ---------------------------------------------------------------------------- open and closed

@pytest.mark.parametrize("facing", ["down", "up"])
def test_a_floor_under_an_open_disc_is_shadowed_from_either_side(facing):
    """A tessellated disc of radius R at height h (an open sheet) over floor points: the
    robust model gives 1 - F, F Lambert's form factor of the polygon (exact once every
    element is in the near field), whichever way the sheet faces; the chapter's casts
    from a sheet's back only, so with its front facing the floor it casts nothing."""
    h, radius = 0.6, 1.0
    disc = polygon([0.0, 0.0, h], radius, 48)  # faces up (+z)
    mesh = _flip(disc) if facing == "down" else disc
    points, normals = floor_points(40, 1.5)
    points = np.vstack([[[0.0, 0.0, 0.0]], points])
    normals = np.vstack([[[0.0, 0.0, 1.0]], normals])
    exact = 1.0 - polygon_form_factors(points, normals, disc.vertices[1:])
    robust = _ao(mesh, points, normals, discs_model="robust", discs_kappa=EVERY_NODE)
    # 48 triangles' form factors summed in thirds: a few hundred eps
    np.testing.assert_allclose(robust, exact, rtol=0, atol=1e-12)
    # on the axis, the polygon's is the disc's h^2 / (h^2 + R^2) less the tessellation's
    # share (the inscribed 48-gon misses 0.29% of the disc's area)
    assert robust[0] == pytest.approx(h * h / (h * h + radius * radius), abs=3e-3)
    chapter = _ao(mesh, points, normals, discs_model="chapter")
    if facing == "down":
        assert (chapter == 1.0).all()  # the open sheet's front: the chapter casts nothing
    else:
        assert (chapter < 1.0).mean() > 0.5


@pytest.mark.parametrize("facing", [1.0, -1.0])
def test_one_open_disc_gives_the_closed_form_on_its_axis(facing):
    """One explicit disc (no triangles: discs at every distance) of radius R at height h:
    the robust model's disc form factor on its axis is R^2 / (h^2 + R^2), so the floor
    point's AO is h^2 / (h^2 + R^2) with either face towards it (its back is open, so it
    casts from its front too); the chapter's casts nothing from its front."""
    radius = 0.5
    for h in (0.01, 0.3, 1.0, 30.0):
        want = h * h / (h * h + radius * radius)
        for model in ("robust", "chapter"):
            method = DiscsMethod.from_elements([[0.0, 0.0, h]], [[0.0, 0.0, facing]],
                                               [math.pi * radius * radius],
                                               DiscsOptions(discs_model=model))
            got = method.estimate(_points([0, 0, 0], [0, 0, 1]), 1, 1024).fields["ao"][0]
            if model == "robust":
                assert got == pytest.approx(want, rel=16 * EPS)
            elif facing < 0:
                assert got == 1.0


def test_a_closed_box_is_counted_once():
    """A closed box over floor points beneath it: its back faces (top and sides) cover the
    directions its front (the bottom) covers, so the robust model's exact sum over them is
    Lambert's form factor of the bottom alone; the flipped layer is absent (a closed
    surface has no open back)."""
    box = trimesh.creation.box(extents=(0.8, 0.6, 0.5))
    box.apply_translation([0.1, 0.0, 0.75])
    points, normals = floor_points(30, 0.25, seed=4)
    bottom = np.array([[-0.3, -0.3, 0.5], [0.5, -0.3, 0.5], [0.5, 0.3, 0.5], [-0.3, 0.3, 0.5]])
    exact = 1.0 - polygon_form_factors(points, normals, bottom)
    scene = load_scene(box)
    method = DiscsMethod.prepare(scene, BakeConfig(), None, 0,
                                 options=DiscsOptions(discs_kappa=EVERY_NODE))
    assert (method.presence == 0).all()
    got = method.estimate(_points(points, normals), 1, 1 << 16).fields["ao"]
    np.testing.assert_allclose(got, exact, rtol=0, atol=1e-12)


def test_closed_elements_weld_patches_and_find_open_sheets():
    """Components are found with the vertices welded by position: a box written as six
    patches that share no vertex is closed; a box without its lid, and a sheet, are open."""
    patches = [quad([0, 0, 0.5], 0.5, 0.5), quad([0, 0, -0.5], 0.5, 0.5, flip=True),
               quad([0, 0.5, 0], 0.5, 0.5, 0, 2, flip=True), quad([0, -0.5, 0], 0.5, 0.5, 0, 2),
               quad([0.5, 0, 0], 0.5, 0.5, 1, 2), quad([-0.5, 0, 0], 0.5, 0.5, 1, 2, flip=True)]

    def closed(meshes):
        mesh = trimesh.util.concatenate(meshes)
        scene = load_scene(mesh)
        faces = np.asarray(scene.faces, dtype=np.int64)
        _, _, _, keep = _keep(scene)
        start, owned = element_faces(faces, scene.areas(), keep)
        return closed_elements(scene.vertices, faces, start, owned)

    six = trimesh.util.concatenate(patches)
    assert np.allclose(six.volume, 1.0)  # the patches face out
    assert closed(patches).all()
    assert not closed(patches[1:]).any()
    assert not closed([quad([0, 0, 0], 1, 1)]).any()


def _keep(scene):
    from aobake.methods import discs

    return discs._elements(scene)


# ---------------------------------------------------------------------------- the hierarchy

@pytest.mark.slow
def test_the_blend_between_levels_is_continuous():
    """A receiver moving along a line over a torus: the robust model's largest step
    between neighbouring samples halves when the samples do (continuous); the chapter's
    stays (its hard switch between a node and its children is a jump)."""
    mesh = trimesh.creation.torus(1.0, 0.35, major_sections=48, minor_sections=24)
    scene = load_scene(mesh)
    steps = {}
    for model in ("chapter", "robust"):
        method = DiscsMethod.prepare(scene, BakeConfig(), None, 0,
                                     options=DiscsOptions(discs_model=model, discs_passes=1))
        for n in (1500, 3000):
            t = np.linspace(0.0, 1.0, n)
            points = np.stack([0.2 + 0.6 * t, 0.1 + 0 * t, 0.45 + 0.3 * t], axis=1)
            normals = np.tile(_unit([0.3, 0.0, -1.0]), (n, 1))
            ao = method.estimate(_points(points, normals), 1, 1 << 17).fields["ao"]
            steps[model, n] = float(np.abs(np.diff(ao)).max())
    # measured: the chapter 0.0100 at both, the robust model 2.0e-4 and 1.0e-4
    assert steps["robust", 1500] / steps["robust", 3000] > 1.8, steps
    assert steps["chapter", 1500] / steps["chapter", 3000] < 1.2, steps
    assert steps["chapter", 3000] > 20 * steps["robust", 3000], steps


def _scene_with_a_sheet():
    """A torus standing on an open floor sheet (its flipped layer present), and a box."""
    torus = trimesh.creation.torus(0.6, 0.2, major_sections=32, minor_sections=12)
    torus.apply_translation([0.0, 0.0, 0.2])
    floor = quad([0.0, 0.0, 0.0], 1.5, 1.5).subdivide().subdivide().subdivide()
    box = trimesh.creation.box(extents=(0.3, 0.3, 0.3))
    box.apply_translation([1.0, 0.8, 0.15])
    return trimesh.util.concatenate([torus, floor, box])


@pytest.mark.slow
@pytest.mark.parametrize("traversal", ["hierarchy", "brute"])
def test_any_split_of_the_points_gives_the_same_rows(traversal):
    """Each point's value from that point alone (tests/test_executors.py's contract), with
    the exact near field, the flipped layer and the blend all in play."""
    scene = load_scene(_scene_with_a_sheet())
    method = DiscsMethod.prepare(scene, BakeConfig(quantities=("ao", "indirect")), None, 0,
                                 options=DiscsOptions(discs_traversal=traversal))
    assert method.presence.max() == 1.0 and (method.presence == 0).any()
    rng = np.random.default_rng(5)
    query = np.vstack([scene.vertices[::4], rng.uniform(-1.2, 1.2, (150, 3))])
    normals = _unit(np.vstack([scene.vertex_normals[::4], rng.normal(size=(150, 3))]))
    normals[::40] = 0.0
    whole = method.estimate(_points(query, normals), 1, 1 << 17)
    order = rng.permutation(len(query))
    for index, threads, chunk in ((order, 2, 3000), (order[:61], 1, 200), (order[::2], 2, 1)):
        part = method.estimate(_points(query[index], normals[index]), threads, chunk)
        for name in ("ao", "indirect"):
            np.testing.assert_array_equal(part.fields[name], whole.fields[name][index])
        for name in ("discs_passes", "discs_indirect_passes", "discs_terms"):
            np.testing.assert_array_equal(part.extras[name], whole.extras[name][index])


@pytest.mark.slow
def test_hierarchy_opening_every_node_is_brute_force():
    """Brute force walks the same leaves with every node above them opened: with kappa
    beyond the scene, the hierarchy opens them too and the two agree to rounding."""
    scene = load_scene(_scene_with_a_sheet())
    points = _points(scene.vertices[::3], scene.vertex_normals[::3])
    got = {}
    for traversal in ("hierarchy", "brute"):
        method = DiscsMethod.prepare(scene, BakeConfig(), None, 0, options=DiscsOptions(
            discs_traversal=traversal, discs_kappa=EVERY_NODE))
        got[traversal] = method.estimate(points, 2, 1 << 17).fields["ao"]
    # the same terms in another order, a pass of a pass: n eps per sum, twice
    n = len(scene.vertices)
    np.testing.assert_allclose(got["hierarchy"], got["brute"], rtol=0, atol=4 * n * EPS)
    assert (got["brute"] < 0.9).any()


def test_max_distance_drops_farther_elements():
    h, radius = 2.0, 0.5
    want = h * h / (h * h + radius * radius)
    for limit, expected in ((h * (1 - 4 * EPS), 1.0), (h, want)):
        method = DiscsMethod.from_elements([[0.0, 0.0, h]], [[0.0, 0.0, -1.0]],
                                           [math.pi * radius * radius],
                                           DiscsOptions(discs_model="robust"), limit)
        got = method.estimate(_points([0, 0, 0], [0, 0, 1]), 1, 1024).fields["ao"][0]
        assert got == pytest.approx(expected, rel=16 * EPS)


# ---------------------------------------------------------------------------- the setting

def test_the_model_setting_and_the_record():
    assert DEFAULT_MODEL == DiscsOptions().discs_model == "robust"
    with pytest.raises(InputError):
        DiscsOptions(discs_model="bunnell")
    scene = load_scene(_scene_with_a_sheet())
    with pytest.raises(InputError, match="cosine"):
        DiscsMethod.prepare(scene, BakeConfig(weighting="uniform"), None, 0)
    # the chapter's model keeps honouring it as before
    DiscsMethod.prepare(scene, BakeConfig(weighting="uniform"), None, 0,
                        options=DiscsOptions(discs_model="chapter"))
    method = DiscsMethod.prepare(scene, BakeConfig(), None, 0)
    estimates = method.estimate(_points(scene.vertices[:40], scene.vertex_normals[:40]), 1,
                                4096)
    parameters = method.record(estimates)["parameters"]
    assert parameters["discs_model"] == "robust" and parameters["discs_k"] is None
    assert parameters["two_sided_elements"] == int((method.presence > 0).sum()) > 0
    chapter = DiscsMethod.prepare(scene, BakeConfig(), None, 0,
                                  options=DiscsOptions(discs_model="chapter"))
    record = chapter.record(chapter.estimate(_points(scene.vertices[:40],
                                                     scene.vertex_normals[:40]), 1, 4096))
    assert record["parameters"]["discs_k"] == 4.0
    assert "two_sided_elements" not in record["parameters"]


@pytest.mark.slow
def test_from_the_command_line(tmp_path):
    from conftest import run_cli

    path = tmp_path / "scene.obj"
    _scene_with_a_sheet().export(path)
    for model in ("chapter", "robust"):
        out = tmp_path / f"{model}.npz"
        result = run_cli(path, "--method", "discs", "--discs-model", model, "-o", out)
        assert result.exit_code == 0, result.output
    result = run_cli(path, "--method", "discs", "--discs-model", "bunnell", "-o",
                     tmp_path / "x.npz")
    assert result.exit_code == 2 and "bunnell" in result.output


# ---------------------------------------------------------------------------- against the truth

@pytest.mark.slow
def test_the_still_life_within_the_target():
    """Issue 33's target: on the bundled still life (an open floor with objects on it) the
    per-vertex RMSE against the ray-traced truth is at most 0.10, the truth's own noise
    taken out (its mean squared stderr subtracted from the mean squared error: 256 rays,
    rms stderr about 0.007, a correction below 0.001).  Measured: 0.047 (1024 rays); the
    chapter's model: 0.42, bias +0.31 (the floor casts nothing)."""
    truth = aobake.bake(STILL_LIFE, rays=256, seed=7, threads=2)
    ok = truth.rays > 0
    noise = float(np.mean(truth.ao_stderr[ok] ** 2))

    def excess(values):
        e = values[ok] - truth.ao[ok]
        return math.sqrt(max(0.0, float(np.mean(e * e)) - noise)), float(e.mean())

    robust, robust_bias = excess(aobake.bake(STILL_LIFE, method="discs", threads=2).ao)
    assert robust <= STILL_LIFE_RMSE and abs(robust_bias) <= 0.02, (robust, robust_bias)
    chapter, chapter_bias = excess(aobake.bake(STILL_LIFE, method="discs", threads=2,
                                               discs_model="chapter").ao)
    assert chapter > 0.3 and chapter_bias > 0.2, (chapter, chapter_bias)


@pytest.mark.slow
def test_hierarchy_agrees_with_brute_force_within_the_stated_tolerance():
    """The robust model's hierarchy against its brute force on two interlocking tori: within
    HIERARCHY_RMSE at the default kappa (measured 0.011; the chapter's 0.015-0.019), and
    each doubling of kappa at least halves the error (measured 0.025, 0.011, 0.0034)."""
    from aobake.methods.discs import HIERARCHY_RMSE

    a = trimesh.creation.torus(1.0, 0.35, major_sections=48, minor_sections=24)
    b = trimesh.creation.torus(1.0, 0.35, major_sections=48, minor_sections=24)
    b.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    b.apply_translation([1.0, 0.0, 0.0])
    scene = load_scene(trimesh.util.concatenate([a, b]))
    points = _points(scene.vertices, scene.vertex_normals)

    def ao(**options):
        method = DiscsMethod.prepare(scene, BakeConfig(), None, 0,
                                     options=DiscsOptions(**options))
        return method.estimate(points, 2, 1 << 17).fields["ao"]

    brute = ao(discs_traversal="brute")
    errors = {k: float(np.sqrt(np.mean((ao(discs_kappa=k) - brute) ** 2))) for k in (2.0, 4.0, 8.0)}
    assert errors[DiscsOptions().discs_kappa] <= HIERARCHY_RMSE, errors
    assert errors[4.0] <= errors[2.0] / 2 and errors[8.0] <= errors[4.0] / 2, errors
    assert errors[8.0] > 0
