"""``--method hemicube``: rasterised hemicube AO (OpenGL in a child process).

The pixel weights are checked against independent closed forms (Lambert's polygon form
factor, Van Oosterom and Strackee's solid angle) without GL.  The rendered values are
deterministic, so their tests are bounds, not error bars: on the closed-form scenes (the
floor under a coaxial tessellated disc, the floor under a ceiling with a max distance) a
pixel whose spherical cap (``hemicube_cells.angular_radius``) does not meet the occluder's
silhouette is exactly right (GL samples its centre), so

    |A - exact| <= sum of the weights of the pixels whose cap meets the silhouette

which each test computes for its own points and resolution.  The caps are widened by 1/32
of themselves for the rasteriser's snapping of vertices to 1/256 pixel and float32 rounding
(both well under 1% of a pixel's radius).

The GL tests skip where moderngl or an EGL context is missing (a probe in a child);
``.ci/run`` insists that CI has both, so they run there.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

import aobake
from aobake import child
from aobake.settings import BakeConfig
from aobake.errors import InputError
from aobake.methods import METHODS, hemicube_cells
from aobake.methods.hemicube import (NO_INFORMATION_AO, HemicubeError, HemicubeMethod,
                                     HemicubeOptions, available)
from aobake.scene import load_scene
from aobake.records import SamplePoints
from aobake.trace import point_offsets
from aobake.warp import frames

from analytic import (floor_and_ceiling, floor_points, polygon, polygon_form_factor,
                      polygon_form_factors, quad, combine, solid_angle)

#: the caps' widening for the rasteriser (see the module docstring)
WIDEN = 1.0 + 1.0 / 32.0
#: the weights' own rounding (3R^2 float64 terms, each a few ulps)
ROUNDING = 1e-12


@pytest.fixture(scope="module")
def gl():
    """Skip unless moderngl imports and a child can make an EGL context."""
    pytest.importorskip("moderngl")
    ok, why = available()
    if not ok:
        pytest.skip(why)
    return why


@pytest.fixture
def resolution(monkeypatch):
    """``resolution(r)``: the test's bakes run with ``hemicube_resolution=r`` (the config's
    field, as ``--hemicube-resolution`` sets it) unless they give it."""
    import importlib

    bake_module = importlib.import_module("aobake.api")
    original = bake_module._config

    def set_resolution(r):
        def with_resolution(config, options):
            return original(config, {"hemicube_resolution": r, **options})
        monkeypatch.setattr(bake_module, "_config", with_resolution)
    return set_resolution


# ------------------------------------------------------------------ the cells (no GL)

@pytest.mark.parametrize("weighting", ["cosine", "uniform"])
def test_pixel_weights_are_the_exact_integrals(weighting):
    """Each pixel's weight against an independent closed form of its corners on the face
    plane: Lambert's polygon form factor (cosine), Van Oosterom and Strackee's solid angle
    / 2 pi (uniform); the five faces sum to 1 before normalising."""
    r = 6
    cells = hemicube_cells.layout(r)
    raw = hemicube_cells.raw_weights(r, weighting)
    face_frames = hemicube_cells.face_frames()
    for i in range(r):
        for j in range(3 * r):
            right, up, forward = face_frames[cells["face"][i, j]]
            corners = [x * right + y * up + forward
                       for x, y in ((cells["x0"][i, j], cells["y0"][i, j]),
                                    (cells["x1"][i, j], cells["y0"][i, j]),
                                    (cells["x1"][i, j], cells["y1"][i, j]),
                                    (cells["x0"][i, j], cells["y1"][i, j]))]
            if weighting == "cosine":
                want = polygon_form_factor(np.zeros(3), np.array([0.0, 0.0, 1.0]), corners)
            else:
                want = solid_angle(np.zeros(3), corners) / (2 * math.pi)
            assert abs(raw[i, j] - want) <= 1e-14
    assert abs(raw.sum() - 1.0) <= 1e-13
    assert abs(hemicube_cells.weights(r, weighting).sum() - 1.0) <= 1e-15


def test_a_pixels_cap_holds_the_pixel():
    """Points drawn inside each pixel are within its angular radius of its centre."""
    r = 4
    cells = hemicube_cells.layout(r)
    radius = hemicube_cells.angular_radius(r)
    face_frames = hemicube_cells.face_frames()
    rng = np.random.default_rng(5)
    for i in range(r):
        for j in range(3 * r):
            right, up, forward = face_frames[cells["face"][i, j]]
            u = rng.random((500, 2))
            x = cells["x0"][i, j] + u[:, 0] * (cells["x1"][i, j] - cells["x0"][i, j])
            y = cells["y0"][i, j] + u[:, 1] * (cells["y1"][i, j] - cells["y0"][i, j])
            inside = x[:, None] * right + y[:, None] * up + forward
            inside /= np.linalg.norm(inside, axis=1, keepdims=True)
            centre = cells["direction"][i, j] / np.linalg.norm(cells["direction"][i, j])
            angle = np.arccos(np.clip(inside @ centre, -1, 1))
            assert angle.max() <= radius[i, j] + 1e-12
            assert angle.max() > 0.8 * radius[i, j]  # and the cap is not loose


def test_bad_resolution_is_refused_with_a_clear_message():
    for bad, words in ((0, "got 0"), (7, "got 7"), (-2, "got -2"),
                       (1024, "above the limit of 512")):
        with pytest.raises(InputError, match="hemicube resolution") as info:
            HemicubeOptions(hemicube_resolution=bad)
        assert words in str(info.value)
    with pytest.raises(ValueError, match="even integer >= 2, got 3"):
        hemicube_cells.layout(3)
    assert HemicubeOptions().hemicube_resolution == 64
    assert "hemicube" in METHODS


def test_options_are_read_from_a_config_that_has_them():
    class Wired:
        hemicube_resolution = 16
    assert HemicubeOptions.of(Wired()).hemicube_resolution == 16
    assert HemicubeOptions.of(BakeConfig()).hemicube_resolution == 64
    # BakeConfig composes the record: its value wins over a default for configs without it
    assert HemicubeOptions.of(BakeConfig(hemicube_resolution=8)).hemicube_resolution == 8
    assert HemicubeOptions.of(object(), HemicubeOptions(8)).hemicube_resolution == 8


def test_settings_it_cannot_honour_are_refused():
    scene = load_scene(quad([0, 0, 0], 1, 1))
    for config, words in ((BakeConfig(quantities=("obscurance",)), "ao only"),
                          (BakeConfig(ground_plane=True), "ground plane"),
                          (BakeConfig(tolerance=0.01), "casts no rays"),
                          (BakeConfig(keep_distances=True), "casts no rays")):
        with pytest.raises(InputError, match=words):
            HemicubeMethod.prepare(scene, config, None, 0)


def test_without_moderngl_the_message_says_what_to_install(monkeypatch):
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "moderngl" else find_spec(name, *a))
    with pytest.raises(HemicubeError, match=r"pip install 'aobake\[gl\]'"):
        HemicubeMethod.prepare(load_scene(quad([0, 0, 0], 1, 1)), BakeConfig(), None, 0)
    assert available()[0] is False


# ------------------------------------------------------------------ bounds of the closed forms

def _pixel_directions(normal: np.ndarray, r: int) -> np.ndarray:
    """(R, 3R, 3) unit world directions of the pixel centres of a point with ``normal``, in
    the method's frame (aobake.warp.frames)."""
    t, b = frames(normal[None, :])
    basis = np.stack([t[0], b[0], normal])
    d = hemicube_cells.layout(r)["direction"] @ basis
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _arc_distance(c: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles from unit directions c (..., 3) to the great-circle arc from unit a to unit b
    (shorter than pi)."""
    g = np.cross(a, b)
    g /= np.linalg.norm(g)
    off = c @ g
    p = c - off[..., None] * g
    within = (np.cross(a, p) @ g >= 0) & (np.cross(p, b) @ g >= 0)
    to_end = np.minimum(np.arccos(np.clip(c @ a, -1, 1)), np.arccos(np.clip(c @ b, -1, 1)))
    return np.where(within, np.arcsin(np.clip(np.abs(off), 0, 1)), to_end)


def _polygon_bound(eye, normal, corners, r, weighting) -> float:
    """The summed weight of the pixels whose (widened) cap meets the silhouette of the
    polygon ``corners`` (k, 3) seen from ``eye``: its edges, great-circle arcs."""
    d = _pixel_directions(normal, r)
    rim = np.asarray(corners, float) - eye
    rim /= np.linalg.norm(rim, axis=1, keepdims=True)
    near = np.full(d.shape[:2], np.inf)
    for k in range(len(rim)):
        near = np.minimum(near, _arc_distance(d, rim[k], rim[(k + 1) % len(rim)]))
    crossed = near <= WIDEN * hemicube_cells.angular_radius(r)
    return float(hemicube_cells.weights(r, weighting)[crossed].sum()) + ROUNDING


def _cone_bound(normal, half_angle, r, weighting) -> float:
    """The same for a silhouette that is the cone of ``half_angle`` about the normal."""
    d = _pixel_directions(normal, r)
    angle = np.arccos(np.clip(d @ normal, -1, 1))
    crossed = np.abs(angle - half_angle) <= WIDEN * hemicube_cells.angular_radius(r)
    return float(hemicube_cells.weights(r, weighting)[crossed].sum()) + ROUNDING


def _disc_scene(sides=48, height=1.0, radius=1.0):
    disc = polygon([0, 0, height], radius, sides)
    return combine(quad([0, 0, 0], 3, 3), disc), disc.vertices[1:]


def _disc_case(r, weighting, resolution, n=12, seed=3):
    """(ao, exact, bound) per floor point under the disc, the exact value and the bound at
    the eye the method used (the point lifted by its ray offset)."""
    resolution(r)
    mesh, rim = _disc_scene()
    points, normals = floor_points(n, 0.7, seed=seed)
    result = aobake.bake_points(mesh, points, normals, method="hemicube", weighting=weighting,
                                threads=1)
    offset = result.report["parameters"]["ray_offset"]
    eyes = points + offset * normals
    if weighting == "cosine":
        exact = 1.0 - polygon_form_factors(eyes, normals, rim)
    else:
        exact = np.array([1.0 - solid_angle(e, rim) / (2 * math.pi) for e in eyes])
    bound = np.array([_polygon_bound(e, nrm, rim, r, weighting)
                      for e, nrm in zip(eyes, normals)])
    return result, exact, bound


@pytest.mark.parametrize("weighting", ["cosine", "uniform"])
@pytest.mark.parametrize("r", [8, 32])
@pytest.mark.slow
def test_floor_under_a_coaxial_disc_within_the_discretisation_bound(gl, resolution, r,
                                                                    weighting):
    """The floor under a tessellated disc: exact by Lambert's polygon form factor (cosine)
    or its solid angle (uniform), off axis too; on axis it is h^2 / (h^2 + R^2) for the
    round disc (cosine).  Every point within its own bound, the bound itself small."""
    result, exact, bound = _disc_case(r, weighting, resolution)
    error = np.abs(result.ao - exact)
    assert (error <= bound).all(), (error, bound)
    # the bound says something: about 2 / R (every crossed pixel counted whole)
    assert bound.max() < {8: 0.35, 32: 0.08}[r]
    assert result.rays is None and result.ao_stderr is None
    parameters = result.report["parameters"]
    assert parameters["method"] == "hemicube" and parameters["hemicube_resolution"] == r
    assert parameters["weighting"] == weighting and parameters["points_drawn"] == len(exact)
    assert result.report["error"] == {} and "rays_cast" not in result.report


@pytest.mark.slow
def test_round_disc_on_axis(gl, resolution):
    """On the axis, a 256-gon's AO is the round disc's h^2 / (h^2 + R^2) to 1e-4 (the
    polygon's area deficit), and the hemicube is within its bound of the polygon's."""
    resolution(32)
    disc = polygon([0, 0, 1.0], 1.0, 256)
    mesh = combine(quad([0, 0, 0], 3, 3), disc)
    result = aobake.bake_points(mesh, [[0.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]],
                                method="hemicube", threads=1)
    offset = result.report["parameters"]["ray_offset"]
    h = 1.0 - offset
    round_disc = h * h / (h * h + 1.0)
    polygon_exact = 1.0 - polygon_form_factors([[0, 0, offset]], [[0, 0, 1.0]],
                                               disc.vertices[1:])[0]
    assert abs(polygon_exact - round_disc) < 1e-4
    bound = _polygon_bound(np.array([0, 0, offset]), np.array([0, 0, 1.0]),
                           disc.vertices[1:], 32, "cosine")
    assert abs(result.ao[0] - polygon_exact) <= bound


@pytest.mark.parametrize("weighting", ["cosine", "uniform"])
@pytest.mark.slow
def test_floor_under_a_ceiling_with_max_distance(gl, resolution, weighting):
    """A ceiling at h, max distance D > h: only the ceiling's disc within D blocks, so AO =
    (h/D)^2 (cosine) or h/D (uniform): the far limit is a sphere, not a plane (a far plane
    at D would block nothing); within the bound of the cone of half-angle acos(h/D)."""
    r, h, d = 16, 1.0, 2.5
    resolution(r)
    mesh = floor_and_ceiling(h, 4.0)  # the ceiling reaches past D's disc (radius 2.3)
    points, normals = floor_points(6, 0.5, seed=7)
    result = aobake.bake_points(mesh, points, normals, method="hemicube", max_distance=d,
                                weighting=weighting, threads=1)
    offset = result.report["parameters"]["ray_offset"]
    height = h - offset
    exact = (height / d) ** 2 if weighting == "cosine" else height / d
    bound = _cone_bound(np.array([0.0, 0.0, 1.0]), math.acos(height / d), r, weighting)
    assert (np.abs(result.ao - exact) <= bound).all(), (result.ao, exact, bound)
    assert bound < 0.15
    assert result.report["parameters"]["max_distance"] == d


@pytest.mark.slow
def test_error_falls_with_resolution(gl, resolution):
    """Convergence: the largest error over the disc's points and its bound both fall about
    as 1/R (measured: 0.017, 0.0053, 0.0032, 0.0008 at R = 8, 16, 32, 64)."""
    worst, bounds = [], []
    for r in (8, 16, 32, 64):
        result, exact, bound = _disc_case(r, "cosine", resolution, n=6, seed=11)
        worst.append(np.abs(result.ao - exact).max())
        bounds.append(bound.max())
    assert worst[-1] < worst[0] / 4 and worst[-1] < 0.003
    assert all(b1 < b0 * 0.7 for b0, b1 in zip(bounds, bounds[1:]))
    assert bounds[-1] * 64 < 2 * bounds[0] * 8  # ~1/R


# ------------------------------------------------------------------ the method's contract

def _points(points, normals, sizes=None) -> SamplePoints:
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    return SamplePoints(points, normals, np.arange(len(points), dtype=np.int64), sizes=sizes)


@pytest.mark.slow
def test_any_split_gives_the_same_bits_and_zero_normals_say_nothing(gl):
    """A point's value depends on that point alone: all points in one call (one batch of
    tiles), reversed (every point in another tile), in two children (threads=2) and split
    in parts, merged by index, are the same bits; a zero normal gets the no-information
    0.5 and is not drawn.  A max distance exercises the per-pixel distance test too."""
    from aobake.records import merge

    mesh = trimesh.creation.torus(1.0, 0.4, major_sections=24, minor_sections=12)
    scene = load_scene(mesh)
    config = BakeConfig(max_distance=1.5)
    method = HemicubeMethod.prepare(scene, config, None, 0, options=HemicubeOptions(16))
    normals = scene.vertex_normals.copy()
    normals[5] = 0.0
    sizes = np.full(len(normals), 0.1)
    every = method.estimate(_points(scene.vertices, normals, sizes), 1, 4096)
    ao = every.fields["ao"]
    assert ao[5] == NO_INFORMATION_AO and every.extras["hemicube_renderer"][5] == ""
    assert ((ao >= 0) & (ao <= 1)).all() and ao.min() < 0.9
    flip = np.arange(len(normals))[::-1]
    reversed_ = method.estimate(_points(scene.vertices[flip], normals[flip], sizes[flip]),
                                2, 4096)
    np.testing.assert_array_equal(reversed_.fields["ao"][::-1], ao)
    parts = [np.arange(0, 100), np.arange(100, len(normals))]
    merged = merge([(i, method.estimate(_points(scene.vertices[i], normals[i], sizes[i]), 1,
                                        4096)) for i in parts[::-1]], len(normals))
    np.testing.assert_array_equal(merged.fields["ao"], ao)
    assert method.record(merged) == method.record(every)
    assert method.record(every)["parameters"]["points_drawn"] == len(normals) - 1


@pytest.mark.slow
def test_back_faces_occlude_as_rays_do(gl, resolution):
    """A ceiling whose back faces the floor blocks by default and is passed through with
    backfaces='ignore', as the ray-traced method does; its front-facing twin blocks
    either way, to the bit wherever no pixel centre sits on a triangle's edge."""
    resolution(16)
    points, normals = floor_points(4, 0.3, seed=2)
    back = combine(quad([0, 0, 0], 3, 3), quad([0, 0, 1], 3, 3))
    front = combine(quad([0, 0, 0], 3, 3), quad([0, 0, 1], 3, 3, flip=True))
    blocked = aobake.bake_points(back, points, normals, method="hemicube", threads=1).ao
    assert (blocked < 0.2).all()
    passed = aobake.bake_points(back, points, normals, method="hemicube",
                                backfaces="ignore", threads=1).ao
    assert (passed == 1.0).all()
    facing = aobake.bake_points(front, points, normals, method="hemicube",
                                backfaces="ignore", threads=1).ao
    assert np.abs(facing - blocked).max() < 1e-3


@pytest.mark.slow
def test_a_tiny_near_plane_still_sees_the_scene(gl, resolution):
    """A point at the local frame's origin with a tiny triangle gets a ray offset, so a near
    plane, of ~1e-11: every depth 1 - near / w then rounds to the cleared 1.0 of the depth
    buffer, and must still be drawn.  The same floor point away from the origin (a larger
    offset) gives the same bits: the ceiling's silhouette is the same."""
    resolution(16)
    # the floor at the vertices' median height, between a ceiling and a mirrored floor
    mesh = combine(quad([0, 0, 0], 4, 4), quad([0, 0, 1], 4, 4),
                   quad([0, 0, -1], 4, 4, flip=True))
    result = aobake.bake_points(mesh, [[0, 0, 0], [0.5, 0.5, 0]], [[0, 0, 1.0], [0, 0, 1.0]],
                                point_sizes=[1e-6, 1e-6], method="hemicube", threads=1)
    low, high = result.report["parameters"]["ray_offset_range"]
    assert low < 1e-10 < 1e-6 < high
    assert result.ao[0] == result.ao[1] and result.ao[0] < 0.1


@pytest.mark.slow
def test_bake_per_vertex_runs_hemicube(gl, resolution):
    """``aobake.bake(mesh, method="hemicube")`` on a small mesh: the floor's vertices under
    the disc within their bounds, the disc's top vertices fully open, no rays or stderr;
    the processes executor gives the same bits."""
    r = 16
    resolution(r)
    disc = polygon([0, 0, 1.0], 1.0, 24)
    rim = disc.vertices[1:]
    floor = quad([0, 0, 0], 3, 3).subdivide().subdivide().subdivide()  # a 0.75 grid
    mesh = combine(floor, disc)
    result = aobake.bake(mesh, method="hemicube", threads=1)
    assert result.rays is None and result.ao_stderr is None
    assert result.report["parameters"]["method"] == "hemicube"
    positions, normals = result.positions, result.normals
    under = (positions[:, 2] == 0) & (np.hypot(positions[:, 0], positions[:, 1]) < 0.8)
    top = positions[:, 2] == 1.0
    assert under.sum() >= 3 and top.sum() == 25
    assert (result.ao[top] == 1.0).all()
    offsets = result.report["parameters"]["ray_offset_range"]
    for i in np.flatnonzero(under):
        for offset in offsets:  # the exact value moves by ~1e-6 between the two offsets
            eye = positions[i] + offset * normals[i]
            exact = 1.0 - polygon_form_factors(eye[None], normals[i][None], rim)[0]
            bound = _polygon_bound(eye, normals[i], rim, r, "cosine")
            assert abs(result.ao[i] - exact) <= bound + 1e-5
    # spawned workers see the default resolution only (the class-level setting stays in this
    # process until BakeConfig carries it): compare at the default
    resolution(HemicubeOptions().hemicube_resolution)
    one = aobake.bake(mesh, method="hemicube", threads=1)
    other = aobake.bake(mesh, method="hemicube", executor="processes", workers=2,
                        chunk_points=60)
    np.testing.assert_array_equal(other.ao, one.ao)
    assert other.report["parameters"] == one.report["parameters"]


def test_a_crashing_child_is_an_error_here(gl, monkeypatch):
    """The GL context lives in a child: a driver crash there is a HemicubeError in the
    baker, which goes on."""
    from aobake.methods import hemicube

    crash = child.Worker("hemicube-crash", "import os\nos.abort()\n", "")
    monkeypatch.setattr(hemicube, "WORKER", crash)
    method = HemicubeMethod.prepare(load_scene(quad([0, 0, 0], 1, 1)), BakeConfig(), None,
                                    0, options=HemicubeOptions(4))
    with pytest.raises(HemicubeError, match="SIGABRT"):
        method.estimate(_points([0, 0, 0], [0, 0, 1]), 1, 4096)
    assert gl  # the probe still answers: nothing of the crash reached this process


def test_the_child_started_ahead_ends_with_its_method():
    """``prepare`` starts the GL child ahead for the first estimate; if none takes it,
    ``close`` (which every executor calls) ends it, and so does the method's collection:
    no process a bake started outlives it (issue 35: ``--executor processes`` draws in
    its workers, and the caller's child was left running)."""
    import gc

    pytest.importorskip("moderngl")
    from aobake.methods import hemicube

    scene = load_scene(quad([0, 0, 0], 1, 1))
    method = HemicubeMethod.prepare(scene, BakeConfig(), None, 0, options=HemicubeOptions(4))
    ahead = child.waiting(hemicube.WORKER)
    assert ahead is not None and ahead.poll() is None
    method.close()
    assert child.waiting(hemicube.WORKER) is None and ahead.poll() is not None
    method.close()  # nothing left to end: no error
    method = HemicubeMethod.prepare(scene, BakeConfig(), None, 0, options=HemicubeOptions(4))
    ahead = child.waiting(hemicube.WORKER)
    assert ahead is not None
    del method
    gc.collect()
    assert child.waiting(hemicube.WORKER) is None and ahead.poll() is not None


# ------------------------------------------------------------------ the culled draw

def _surface_case(n=60, seed=4, torus=(48, 24)):
    """A torus over a floor (clipped triangles at every face's edges, the horizon and the
    near plane) and n points drawn by area on it with their triangles' normals: (vertices
    (v, 3) float32 local units, faces (f, 3) int64, eyes (n, 3) float32, frames (n, 3, 3)
    float32 rows t, b, n, near (n,) float32), as the method hands them to its GL child."""
    mesh = combine(trimesh.creation.torus(1.0, 0.4, major_sections=torus[0],
                                          minor_sections=torus[1]),
                   quad([0, 0, -0.45], 2.5, 2.5))
    scene = load_scene(mesh)
    rng = np.random.default_rng(seed)
    areas = scene.areas()
    face = rng.choice(len(areas), size=n, p=areas / areas.sum())
    u = rng.random((n, 2))
    u[u.sum(axis=1) > 1] = 1 - u[u.sum(axis=1) > 1]
    corners = scene.vertices[scene.faces[face]]
    points = corners[:, 0] + u[:, :1] * (corners[:, 1] - corners[:, 0]) \
        + u[:, 1:] * (corners[:, 2] - corners[:, 0])
    normals = scene.face_normals[face]
    # the method's eyes (HemicubeMethod.eyes) in a local frame of scale 1/2
    local = (scene.vertices * 0.5).astype(np.float32)
    near = point_offsets(points * 0.5, np.full(n, 0.025), 1e-4)
    eyes = points * 0.5 + near[:, None] * normals
    t, b = frames(normals)
    basis = np.stack([t, b, normals], axis=1).astype(np.float32)
    return local, np.asarray(scene.faces, np.int64), eyes.astype(np.float32), basis, \
        near.astype(np.float32)


def test_cull_skips_only_triangles_the_clipper_removes():
    """``cull_commands`` (numpy, no GL): every triangle of a cluster skipped for a face has
    all three vertices outside one of that face's clip planes in the vertex shader's own
    float32 arithmetic (so it makes no fragment), the commands cover exactly the kept
    clusters, sorted by point, and the cull keeps little of the 5 x triangles."""
    from aobake.methods import hemicube_gl

    vertices, faces, eyes, basis, near = _surface_case(n=12)
    order = hemicube_gl.morton_order(vertices.astype(np.float64)[faces].mean(axis=1))
    faces = faces[order]
    clusters = hemicube_gl.cluster_boxes(vertices, faces, 8)
    starts, ends = clusters[0], clusters[1]
    commands, records, point = hemicube_gl.cull_commands(
        clusters, eyes.astype(np.float64), basis.astype(np.float64), near.astype(np.float64))
    assert (np.diff(point) >= 0).all() and (commands[:, 4] == np.arange(len(commands))).all()
    planes, axes = hemicube_gl._PLANES.astype(np.float32), hemicube_gl._AXES.astype(np.float32)
    drawn = 0
    for k in range(len(eyes)):
        # the shader's q = (p - eye) * frame in float32, then each face's clip values
        q = (vertices - eyes[k]) @ basis[k].T
        distance = np.einsum("vi,fqi->fqv", q, planes)          # (5, 4, v)
        w = np.einsum("vi,fi->fv", q, axes)
        outside = np.concatenate([distance < 0, (w - 2 * near[k] + w < 0)[:, None]], axis=1)
        for f in range(5):
            mine = (point == k) & (records[:, 0] == f)
            kept = np.zeros(len(faces), bool)
            for first, count in zip(records[mine, 1], commands[mine, 0] // 3):
                kept[first:first + count] = True
            drawn += kept.sum()
            # runs are whole clusters
            assert np.isin(np.flatnonzero(np.diff(kept.astype(int)) != 0) + 1,
                           np.r_[starts, ends]).all()
            skipped = faces[~kept]
            # every skipped triangle: some plane with all three vertices outside
            assert outside[f][:, skipped].all(axis=2).any(axis=0).all()
    assert drawn < 0.5 * 5 * len(faces) * len(eyes)


@pytest.mark.slow
@pytest.mark.parametrize("max_distance,backfaces", [(math.inf, "occlude"), (1.2, "occlude"),
                                                    (1.2, "ignore")])
def test_culled_draw_is_the_whole_draw_bit_for_bit(gl, max_distance, backfaces):
    """The culled draw (runs of clusters per point and face, triangles in Morton order)
    against the whole draw (every triangle, five instances per point): the same tiles, bit
    for bit, with clipped triangles everywhere, a max distance (the per-pixel distance test
    reads the triangle through the command's base + gl_PrimitiveID) and back faces culled;
    so the same values.  40 points: three cull groups in one framebuffer."""
    from aobake.methods import hemicube

    vertices, faces, eyes, basis, near = _surface_case(n=40)
    inputs = dict(vertices=vertices, faces=faces, eyes=eyes, frames=basis, near=near,
                  resolution=np.array(16), max_distance=np.array(max_distance * 0.5),
                  weighting=np.array("cosine"), backfaces=np.array(backfaces),
                  threads=np.array(1), keep_tiles=np.array(True))
    whole = child.run(hemicube.WORKER, {**inputs, "cull": np.array(0)}, 120.0)
    culled = child.run(hemicube.WORKER, {**inputs, "cull": np.array(1)}, 120.0)
    np.testing.assert_array_equal(culled["tiles"], whole["tiles"])
    np.testing.assert_array_equal(culled["ao"], whole["ao"])
    assert (whole["blocked_pixels"] > 0).mean() > 0.8  # the scene is in view
