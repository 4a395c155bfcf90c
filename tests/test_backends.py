"""Embree agrees with the slow numpy reference intersector on seeded scenes."""

import numpy as np
import trimesh

import aobake
from aobake.backends import reference
from aobake.backends.embree import EmbreeBackend
from aobake.backends.plane import PlaneOccluder
from aobake.scene import face_normals


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


def test_embree_matches_reference_distances_and_occlusion():
    for seed in range(3):
        mesh = _scene(seed)
        v, f = mesh.vertices, mesh.faces.astype(np.int64)
        occ = EmbreeBackend(v, f, face_normals(v, f), np.zeros(3), step=1e-5)
        o, d = _rays(seed)
        o32, d32 = o.astype(np.float32), d.astype(np.float32)
        for tmax in (np.inf, 0.7):
            ref_t = reference.hit_distance(v, f, o32.astype(float), d32.astype(float), tmax)
            emb_t = occ.distance(o32, d32, np.float32(tmax))
            assert np.array_equal(np.isfinite(ref_t), np.isfinite(emb_t))
            hit = np.isfinite(ref_t)
            np.testing.assert_allclose(emb_t[hit], ref_t[hit], rtol=1e-5, atol=1e-6)
            assert np.array_equal(occ.occluded(o32, d32, np.float32(tmax)), hit)


def test_backface_ignoring_matches_reference_front_hits():
    mesh = _scene(7)
    v, f = mesh.vertices, mesh.faces.astype(np.int64)
    fn = face_normals(v, f)
    occ = EmbreeBackend(v, f, fn, np.zeros(3), step=1e-5)
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
