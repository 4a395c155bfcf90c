"""Embree agrees with the slow numpy reference intersector on seeded scenes, query by query
and over a whole bake."""

import numpy as np
import pytest
import trimesh

import aobake
from aobake.trace import point_offsets
from aobake.backends import BACKENDS, reference
from aobake.backends.embree import EmbreeBackend
from aobake.backends.plane import PlaneOccluder
from aobake.backends.reference import ReferenceBackend
from aobake.scene import face_normals
from analytic import combine, floor_points, quad


def _scene(seed):
    rng = np.random.default_rng(seed)
    parts = []
    for _ in range(6):
        m = trimesh.creation.icosphere(subdivisions=1, radius=rng.uniform(0.1, 0.4))
        m.apply_translation(rng.uniform(-1, 1, 3))
        parts.append(m)
    return trimesh.util.concatenate(parts)


def _rays(seed, n=4000):
    rng = np.random.default_rng(seed + 100)
    o = rng.uniform(-1.5, 1.5, (n, 3))
    d = rng.normal(size=(n, 3))
    return o, d / np.linalg.norm(d, axis=1)[:, None]


@pytest.mark.slow
@pytest.mark.parametrize("tmax", [np.inf, 0.7])
@pytest.mark.parametrize("seed", range(3))
def test_embree_matches_reference_distances_and_occlusion(seed, tmax):
    mesh = _scene(seed)
    v, f = mesh.vertices, mesh.faces.astype(np.int64)
    occ = EmbreeBackend(v, f, face_normals(v, f), step=1e-5)
    o, d = _rays(seed)
    o32, d32 = o.astype(np.float32), d.astype(np.float32)
    ref_t = reference.hit_distance(v, f, o32.astype(float), d32.astype(float), tmax)
    emb_t = occ.distance(o32, d32, np.float32(tmax))
    assert np.array_equal(np.isfinite(ref_t), np.isfinite(emb_t))
    hit = np.isfinite(ref_t)
    np.testing.assert_allclose(emb_t[hit], ref_t[hit], rtol=1e-5, atol=1e-6)
    assert np.array_equal(occ.occluded(o32, d32, np.float32(tmax)), hit)


@pytest.mark.slow
def test_backface_ignoring_matches_reference_front_hits():
    mesh = _scene(7)
    v, f = mesh.vertices, mesh.faces.astype(np.int64)
    fn = face_normals(v, f)
    occ = EmbreeBackend(v, f, fn, step=1e-5)
    o, d = _rays(7)
    o32, d32 = o.astype(np.float32), d.astype(np.float32)
    got = occ.front_distance(o32, d32, np.float32(np.inf))
    # Reference: drop back-facing triangles per ray by tracing against front faces only.
    # For one ray direction, a face is front-facing if n . d < 0.
    expect = np.full(len(o), np.inf)
    for i in range(len(o)):
        keep = fn @ d32[i].astype(float) < 0
        t = reference.hit_distance(v, f[keep], o32[i:i + 1].astype(float), d32[i:i + 1].astype(float), np.inf)
        expect[i] = t[0]
    assert np.array_equal(np.isfinite(got), np.isfinite(expect))
    hit = np.isfinite(expect)
    np.testing.assert_allclose(got[hit], expect[hit], rtol=1e-4, atol=1e-4)


def test_ground_plane_is_a_solid_half_space():
    plane = PlaneOccluder(axis=1, height=0.0)
    o = np.array([[0, 1, 0], [0, 1, 0], [0, -1, 0], [0, 0, 0]], dtype=np.float32)
    d = np.array([[0, -1, 0], [0, 1, 0], [0, 1, 0], [1, 0, 0]], dtype=np.float32)
    np.testing.assert_array_equal(plane.distance(o, d, np.float32(np.inf)), [1, np.inf, 0, 0])
    np.testing.assert_array_equal(plane.distance(o, d, np.float32(0.5)), [np.inf, np.inf, 0, 0])


def test_ground_plane_darkens_contact():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    plain = aobake.bake(sphere, rays=64)
    grounded = aobake.bake(sphere, rays=64, ground_plane=True, up_axis="y")
    bottom = np.argmin(sphere.vertices[:, 1])
    top = np.argmax(sphere.vertices[:, 1])
    assert plain.ao[bottom] == 1.0 and grounded.ao[bottom] < 0.6
    assert grounded.ao[top] == 1.0
    assert grounded.report["parameters"]["ground_plane"]["height"] == sphere.vertices[:, 1].min()


def test_backfaces_ignore_sees_through_inside_out_shell():
    box = trimesh.creation.box(extents=[1, 1, 1])  # outward normals: from inside, all faces are back faces
    inside = aobake.bake_points(box, [[0, 0, 0]], [[0, 0, 1.0]], rays=64, backfaces="ignore",
                                quantities=("ao", "obscurance"))
    assert inside.ao[0] == 1.0 and inside.obscurance[0] == 1.0
    occl = aobake.bake_points(box, [[0, 0, 0]], [[0, 0, 1.0]], rays=64, backfaces="occlude")
    assert occl.ao[0] == 0.0


def test_back_face_just_short_of_the_max_distance(backend):
    """A ray crossing a back face at t <= tmax < t + step (the step past it) sees nothing
    (the remaining length is clamped at 0, not handed on negative)."""
    sheet = quad([0, 0, 1.0], 1, 1)  # normal +z: from below, a back face
    v, f = sheet.vertices, sheet.faces.astype(np.int64)
    tracer = BACKENDS[backend](v, f, face_normals(v, f), 1e-5)
    o = np.array([[0.1, 0.2, 0.0]], dtype=np.float32)
    d = np.array([[0.0, 0.0, 1.0]], dtype=np.float32)
    tmax = np.float32(1.0 + 5e-6)
    assert tracer.front_distance(o, d, tmax).tolist() == [np.inf]
    assert tracer.front_occluded(o, d, tmax).tolist() == [False]


# --- a whole bake on both backends -------------------------------------------------------

#: how far (scene units) a triangle edge or the max distance must be from a ray for its
#: float32 (Embree) and float64 (reference) decisions to be sure to agree: the float32 rounding of
#: the rebased vertices and of the hit arithmetic is ~1e-7 at this scene's size (|x| <= 2), so
#: 1e-5 is a wide margin (~40 ulps).  Measured on the bake below: it flags 1 of the 12800 rays
#: (1e-4: 3, 1e-3: 54; with back faces ignored 0, 2, 22), and no AO value differs at all, so the
#: comparison is bit-for-bit at all but a point or two.
EDGE_MARGIN = 1e-5


def _small_scene():
    """44 triangles: a floor, two coarse spheres, and an up-facing sheet overhead whose underside
    (what the floor points see) is a back face, so ``backfaces='ignore'`` sees through it."""
    parts = [quad([0, 0, 0], 2, 2)]
    for centre, radius in (([-0.5, 0.2, 0.6], 0.5), ([0.7, -0.3, 0.4], 0.35)):
        sphere = trimesh.creation.icosphere(subdivisions=0, radius=radius)
        sphere.apply_translation(centre)
        parts.append(sphere)
    parts.append(quad([0.3, 0.3, 1.3], 0.6, 0.4))
    return combine(*parts)


def _grown(triangles, by):
    """(f, 3, 3) triangles with every edge moved outward by ``by`` (inward if negative) in
    their plane: scaled about the incentre by (r + by) / r, r the inradius."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    la, lb, lc = (np.linalg.norm(x, axis=1)[:, None] for x in (b - c, c - a, a - b))
    incentre = (la * a + lb * b + lc * c) / (la + lb + lc)
    inradius = np.linalg.norm(np.cross(b - a, c - a), axis=1)[:, None] / (la + lb + lc)
    return incentre[:, None] + (triangles - incentre[:, None]) * ((inradius + by) / inradius)[:, None]


def _ambiguous_rays(mesh, origins, directions, tmax, front_only):
    """(n,) bool: rays whose hit on some face within tmax may be decided differently in float32
    and float64 -- the face grown by EDGE_MARGIN is hit within tmax + margin, the face shrunk by it
    not within (margin, tmax - margin].  (Back-facing faces are left out for ``front_only``.)"""
    triangles = mesh.vertices[mesh.faces]
    one = np.array([[0, 1, 2]])
    unsure = np.zeros(len(origins), dtype=bool)
    for face, tri_in, tri_out in zip(range(len(triangles)), _grown(triangles, -EDGE_MARGIN),
                                     _grown(triangles, EDGE_MARGIN)):
        t_out = reference.hit_distance(tri_out, one, origins, directions, np.inf)
        t_in = reference.hit_distance(tri_in, one, origins, directions, np.inf)
        surely = (t_in > EDGE_MARGIN) & (t_in <= tmax - EDGE_MARGIN)
        maybe = t_out <= tmax + EDGE_MARGIN
        if front_only:
            back = directions @ mesh.face_normals[face] > 0
            surely &= ~back
            maybe &= ~back
        unsure |= maybe & ~surely
    return unsure


def test_ambiguous_rays_are_those_near_an_edge_or_the_max_distance():
    """The yardstick of the test below: flags a ray grazing an edge or ending at the max
    distance, not one through a face's middle or clear of every face."""
    mesh = quad([0, 0, 1.0], 1, 1)  # edges at x, y = +-1
    up = np.array([0, 0, 1.0])
    origins = np.array([[0.2, 0.3, 0], [1 + 0.5 * EDGE_MARGIN, 0.3, 0], [1 - 0.5 * EDGE_MARGIN, 0.3, 0],
                        [1 + 2 * EDGE_MARGIN, 0.3, 0], [0.2, 0.3, 0]])
    tmax = np.array([2.0, 2.0, 2.0, 2.0, 1.0 + 0.5 * EDGE_MARGIN])
    flags = _ambiguous_rays(mesh, origins, np.tile(up, (5, 1)), tmax, front_only=False)
    assert flags.tolist() == [False, True, True, False, True]
    # Seen from below the face is a back face: ignored altogether with front_only.
    assert not _ambiguous_rays(mesh, origins, np.tile(up, (5, 1)), tmax, front_only=True).any()


class _RecordingReference:
    """The reference backend, keeping every query's rays (the test's ray-to-point bookkeeping)."""

    calls: list = []

    def __init__(self, *args, **options):
        self._backend = ReferenceBackend(*args, **options)

    def _recorded(query):
        def method(self, origins, directions, tmax):
            tmax = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (len(origins),))
            self.calls.append((query, origins.copy(), directions.copy(), tmax.copy()))
            return getattr(self._backend, query)(origins, directions, tmax)
        return method

    occluded = _recorded("occluded")
    distance = _recorded("distance")
    front_occluded = _recorded("front_occluded")
    front_distance = _recorded("front_distance")
    del _recorded


@pytest.mark.slow
@pytest.mark.parametrize("quantities", [("ao", "obscurance", "bent-normal"), ("ao", "bent-normal")],
                         ids=["distance-query", "occlusion-query"])
@pytest.mark.parametrize("backfaces", ["occlude", "ignore"])
def test_whole_bake_agrees_on_both_backends(backfaces, quantities, monkeypatch):
    """``bake_points`` gives the same numbers on Embree (float32) and the float64 reference: every
    escape decision is the same except on rays passing within EDGE_MARGIN of an edge (or of the
    max distance), whose number bounds each point's AO difference; hit distances agree to float32
    rounding, which bounds the obscurance difference where no decision differs."""
    mesh = _small_scene()
    floor, up = floor_points(40, 1.5)
    on_spheres = slice(2, 42, 4)  # ten faces of the two spheres, each point facing out
    points = np.vstack([floor, mesh.triangles_center[on_spheres]])
    normals = np.vstack([up, mesh.face_normals[on_spheres]])
    opts = dict(rays=256, quantities=quantities, max_distance=2.0, backfaces=backfaces, threads=1)
    embree = aobake.bake_points(mesh, points, normals, backend="embree", **opts)
    monkeypatch.setattr(_RecordingReference, "calls", [])
    monkeypatch.setitem(BACKENDS, "reference", _RecordingReference)
    ref = aobake.bake_points(mesh, points, normals, backend="reference", **opts)
    params = ref.report["parameters"]
    assert params["backend"] == "reference" and embree.report["parameters"]["backend"] == "embree"

    queries, o, d, tmax = zip(*_RecordingReference.calls)
    assert set(queries) == {params["query"]}
    o, d, tmax = (np.concatenate(x).astype(np.float64) for x in (o, d, tmax))
    # Each ray's point: its origin is the point's in the tracer's local frame (rebased, scaled
    # by a power of two), then offset along the normal (query points stand in the scene's
    # median triangle size for their own).  Recorded rays and tmax are in local units too.
    scale = params["trace_scale"]
    local = (points - params["rebase_center"]) * scale
    size = np.sqrt(2.0 * np.median(mesh.area_faces)) * scale
    offsets = point_offsets(local, np.full(len(points), size), ref.report["config"]["ray_offset"])
    start = local + offsets[:, None] * normals
    owner = np.argmin(np.linalg.norm(o[:, None] - start[None], axis=2), axis=1)
    assert np.all(np.linalg.norm(o - start[owner], axis=1) < 1e-6)
    n_rays = np.bincount(owner, minlength=len(points))
    np.testing.assert_array_equal(n_rays, ref.rays)
    rebased = trimesh.Trimesh((mesh.vertices - params["rebase_center"]) * scale, mesh.faces,
                              process=False)
    unsure = np.bincount(owner, weights=_ambiguous_rays(rebased, o, d, tmax, backfaces == "ignore"),
                         minlength=len(points))

    # The scene is a real test: open and occluded points, and few rays near an edge.
    assert embree.ao.min() < 0.2 and embree.ao.max() > 0.9
    assert unsure.sum() <= 1e-3 * n_rays.sum() and np.count_nonzero(unsure) <= 5
    if backfaces == "ignore":  # ... where the sheet overhead is seen through
        occluding = aobake.bake_points(mesh, points, normals, **dict(opts, backfaces="occlude"))
        assert np.any(embree.ao > occluding.ao)

    sure = unsure == 0
    for name in ("ao", "ao_stderr", "bent_normal", "bent_normal_stderr"):
        np.testing.assert_array_equal(getattr(embree, name)[sure], getattr(ref, name)[sure],
                                      err_msg=name)
    # One decision moves AO by one ray's weight: 1 / rays.
    assert np.all(np.abs(embree.ao - ref.ao) <= unsure / ref.rays)
    if "obscurance" in quantities:
        # Where no decision differs, rho(L) = 1 - exp(-tau L) moves by at most tau |dL|.  The hit
        # distances differ by float32 rounding of the rebased scene: <= 16 ulps of its largest
        # coordinate (the direct comparisons above measure up to 9), plus the float32 rounding
        # of rho itself (4 ulps of 1).  The stderr moves by no more than about as much (values
        # each moved by <= eps move their spread by <= eps sqrt(n / (n - 1))).  This catches a
        # systematic 1e-4 relative error in the distances (measured gap 2.8e-5); the measured
        # gap between the backends is 4e-8.
        ulp = np.spacing(np.float32(np.abs(rebased.vertices).max())) / scale  # scene units
        eps = params["tau"] * 16 * ulp + 4 * np.spacing(np.float32(1))
        gap = np.abs(embree.obscurance - ref.obscurance)
        assert np.all(gap <= unsure / ref.rays + eps), gap.max()
        gap = np.abs(embree.obscurance_stderr - ref.obscurance_stderr)[sure]
        assert np.all(gap <= 2 * eps), gap.max()


@pytest.mark.slow
def test_embree_mode_is_recorded_and_checked():
    """--embree-mode: the report says which traversal ran; fast traces the same rays (on a
    closed sphere both give the same bits: no crack for a ray to slip through)."""
    import aobake
    from aobake.errors import InputError

    mesh = trimesh.creation.icosphere(2, 1.0)
    robust = aobake.bake(mesh, rays=16, seed=1)
    fast = aobake.bake(mesh, rays=16, seed=1, embree_mode="fast")
    assert robust.report["parameters"]["embree_mode"] == "robust"
    assert fast.report["parameters"]["embree_mode"] == "fast"
    assert fast.report["config"]["embree_mode"] == "fast"
    assert np.array_equal(robust.ao, fast.ao)
    reference = aobake.bake(mesh, rays=16, seed=1, backend="reference")
    assert "embree_mode" not in reference.report["parameters"]
    with pytest.raises(InputError, match="embree"):
        aobake.bake(mesh, rays=16, embree_mode="quick")
