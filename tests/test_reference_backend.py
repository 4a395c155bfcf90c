"""The numpy reference intersector: exact small cases, then agreement with trimesh's numpy code.

The reference backend is the oracle the Embree backend is tested against, so it is itself
checked against hand-computed answers and an independent implementation
(trimesh.ray.ray_triangle, plane intersection + barycentric test, a different algorithm).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh
from trimesh.ray import ray_triangle

from aobake.backends import reference

# One triangle in the plane z = 0, covering the unit right triangle (0,0)-(1,0)-(0,1).
TRI_V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
TRI_F = np.array([[0, 1, 2]])
DOWN = np.array([[0.0, 0.0, -1.0]])


def _ray(origin, direction=DOWN[0]):
    """One ray as ((1, 3) origin, (1, 3) unit direction)."""
    direction = np.asarray(direction, dtype=np.float64)
    return np.array([origin], dtype=np.float64), np.array([direction / np.linalg.norm(direction)])


@pytest.fixture(autouse=True)
def _warnings_are_errors():
    """No case may emit a floating-point (or any other) warning: they hide NaN."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with np.errstate(all="raise"):
            yield


def test_hit_at_known_distance():
    o, d = _ray([0.25, 0.25, 2.0])
    t, face = reference.first_hit(TRI_V, TRI_F, o, d, np.inf)
    assert t.dtype == np.float64 and face.dtype == np.int64
    assert t.shape == (1,) and face.shape == (1,)
    assert t[0] == 2.0
    assert face[0] == 0
    assert reference.occluded(TRI_V, TRI_F, o, d, np.inf).tolist() == [True]
    assert reference.hit_distance(TRI_V, TRI_F, o, d, np.inf).tolist() == [2.0]


def test_oblique_hit_and_back_side():
    # From below, going up and sideways: the back side is hit too (no culling).
    o, d = _ray([0.0, 0.0, -1.0], [0.2, 0.3, 1.0])
    t, face = reference.first_hit(TRI_V, TRI_F, o, d, np.inf)
    assert face[0] == 0
    np.testing.assert_allclose(t[0], np.linalg.norm([0.2, 0.3, 1.0]), rtol=1e-15)


# (0.6, 0.6) is past the hypotenuse u + v = 1; (-0.1, 0.5) is left of the u = 0 edge;
# (0.5, -1e-9) just below the v = 0 edge.
@pytest.mark.parametrize("xy", [[0.6, 0.6], [-0.1, 0.5], [0.5, -1e-9]])
def test_miss_beside_triangle(xy):
    o, d = _ray([*xy, 1.0])
    t, face = reference.first_hit(TRI_V, TRI_F, o, d, np.inf)
    assert face[0] == -1 and t[0] == np.inf
    assert not reference.occluded(TRI_V, TRI_F, o, d, np.inf)[0]


def test_edge_hit_counts():
    # Exactly on the edge v = 0: a hit, so rays cannot slip between two faces sharing it.
    o, d = _ray([0.5, 0.0, 1.0])
    t, face = reference.first_hit(TRI_V, TRI_F, o, d, np.inf)
    assert face[0] == 0 and t[0] == 1.0


def test_grazing_parallel_ray_misses_without_nan():
    # In the triangle's own plane, straight across it, and parallel above it.
    origins = np.array([[-1.0, 0.25, 0.0], [0.25, 0.25, 0.5]])
    directions = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    t, face = reference.first_hit(TRI_V, TRI_F, origins, directions, np.inf)
    assert face.tolist() == [-1, -1]
    assert np.all(t == np.inf)


def test_max_distance_cuts_hit():
    o, d = _ray([0.25, 0.25, 2.0])
    # Inclusive at exactly max_distance, a miss just short of it.
    assert reference.first_hit(TRI_V, TRI_F, o, d, 2.0)[1][0] == 0
    t, face = reference.first_hit(TRI_V, TRI_F, o, d, 1.999)
    assert face[0] == -1 and t[0] == np.inf
    assert reference.first_hit(TRI_V, TRI_F, o, d, 0.0)[1][0] == -1


def test_max_distance_per_ray():
    origins = np.array([[0.25, 0.25, 2.0]] * 3)
    directions = np.repeat(DOWN, 3, axis=0)
    max_distance = np.array([1.0, 2.0, np.inf])
    face = reference.first_hit(TRI_V, TRI_F, origins, directions, max_distance)[1]
    assert face.tolist() == [-1, 0, 0]


def test_degenerate_triangles_never_hit():
    vertices = np.array(
        [
            [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0],  # collinear
            [0.3, 0.1, 0.0],  # repeated vertex below
            [0.1, 0.1, 0.0], [0.7, 0.3, 0.0], [0.4, 0.2, 0.0],  # collinear, not axis aligned
        ]
    )
    faces = np.array([[0, 1, 2], [3, 3, 1], [4, 5, 6]])
    origins = np.array([[1.0, 0.0, 1.0], [0.3, 0.1, 1.0], [0.4, 0.2, 1.0], [0.5, 0.0, 1.0]])
    directions = np.repeat(DOWN, 4, axis=0)
    t, face = reference.first_hit(vertices, faces, origins, directions, np.inf)
    assert face.tolist() == [-1, -1, -1, -1]
    assert np.all(t == np.inf)
    # Rays along the degenerate segment itself: zero det, still no NaN.
    origins = np.array([[-1.0, 0.0, 0.0]])
    directions = np.array([[1.0, 0.0, 0.0]])
    assert reference.first_hit(vertices, faces, origins, directions, np.inf)[1][0] == -1


@pytest.mark.parametrize("z", [-1.0, 0.0], ids=["behind", "at"])
def test_triangle_behind_or_at_origin_misses(z):
    # Triangle behind the origin (t = -1) and exactly at it (t = 0): both misses.
    o, d = _ray([0.25, 0.25, z])
    t, face = reference.first_hit(TRI_V, TRI_F, o, d, np.inf)
    assert face[0] == -1 and t[0] == np.inf


def test_triangle_just_in_front_of_origin_hits():
    # Just above it: a hit at that tiny distance (no tnear offset is applied here).
    o, d = _ray([0.25, 0.25, 1e-12])
    t, face = reference.first_hit(TRI_V, TRI_F, o, d, np.inf)
    assert face[0] == 0 and t[0] == 1e-12


def test_nearest_of_stacked_triangles():
    # Three copies at z = 0, 1, 2; listed far-first so the answer is not simply face 0.
    vertices = np.concatenate([TRI_V + [0.0, 0.0, z] for z in (0.0, 1.0, 2.0)])
    faces = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    o, d = _ray([0.25, 0.25, 3.5])
    t, face = reference.first_hit(vertices, faces, o, d, np.inf)
    assert face[0] == 2 and t[0] == 1.5
    o, d = _ray([0.25, 0.25, -0.5], [0.0, 0.0, 1.0])
    t, face = reference.first_hit(vertices, faces, o, d, np.inf)
    assert face[0] == 0 and t[0] == 0.5
    # Between layers the max distance decides whether the next layer counts.
    o, d = _ray([0.25, 0.25, 1.5])
    assert reference.first_hit(vertices, faces, o, d, 0.4)[1][0] == -1
    assert reference.first_hit(vertices, faces, o, d, 0.5)[1][0] == 1


@pytest.mark.parametrize("block_pairs", [1, 2, 1000])
def test_ties_go_to_lowest_face_for_any_block_size(block_pairs):
    # Two identical triangles: same t, face 0 wins whether or not they share a block.
    vertices = np.concatenate([TRI_V, TRI_V])
    faces = np.array([[3, 4, 5], [0, 1, 2]])
    o, d = _ray([0.25, 0.25, 1.0])
    face = reference.first_hit(vertices, faces, o, d, np.inf, block_pairs=block_pairs)[1]
    assert face[0] == 0


def test_empty_inputs():
    t, face = reference.first_hit(TRI_V, np.zeros((0, 3), dtype=int), *_ray([0, 0, 1]), np.inf)
    assert face.tolist() == [-1] and t.tolist() == [np.inf]
    t, face = reference.first_hit(TRI_V, TRI_F, np.zeros((0, 3)), np.zeros((0, 3)), np.inf)
    assert t.shape == (0,) and face.shape == (0,)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(vertices=np.zeros((3, 2))), "vertices must be"),
        (dict(faces=np.array([[0, 1, 3]])), "faces index"),
        (dict(faces=np.array([[0.0, 1.0, 2.0]])), "integer"),
        (dict(directions=np.zeros((2, 3))), "directions must"),
        (dict(max_distance=np.array([1.0, 2.0])), "max_distance must"),
        (dict(max_distance=-1.0), "max_distance must"),
        (dict(max_distance=np.nan), "max_distance must"),
        (dict(origins=np.array([[np.nan, 0.0, 0.0]])), "origins must be finite"),
    ],
)
def test_bad_input_is_rejected(kwargs, message):
    args = dict(vertices=TRI_V, faces=TRI_F, origins=[[0.25, 0.25, 1.0]], directions=DOWN,
                max_distance=np.inf)
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        reference.first_hit(**args)


class _AllFacesTree:
    """Stand-in for trimesh's rtree index: every face is a candidate for every ray.

    trimesh's RayMeshIntersector needs the optional rtree package for its broad phase;
    handing ray_triangle_id this brute-force "tree" runs the same narrow phase without it.
    """

    def __init__(self, triangles):
        self.bounds = np.concatenate([triangles.min(axis=(0, 1)), triangles.max(axis=(0, 1))])
        self._all = range(len(triangles))

    def intersection(self, _bounds):
        return self._all


def _trimesh_first_hit(mesh, origins, directions):
    """trimesh's pure-numpy nearest hit, as ((n,) t with inf on miss, (n,) face with -1)."""
    index_tri, index_ray, locations = ray_triangle.ray_triangle_id(
        triangles=mesh.triangles,
        ray_origins=origins,
        ray_directions=directions,
        triangles_normal=mesh.face_normals,
        tree=_AllFacesTree(mesh.triangles),
        multiple_hits=False,
    )
    t = np.full(len(origins), np.inf)
    face = np.full(len(origins), -1, dtype=np.int64)
    t[index_ray] = np.einsum("ij,ij->i", locations - origins[index_ray], directions[index_ray])
    face[index_ray] = index_tri
    return t, face


def _random_rays(rng, n_rays):
    """Seeded rays around a unit sphere: origins outside (radius 2..3) aimed at points within
    radius 2 so that many miss, plus some origins inside (always a hit, from the back side)."""
    def unit(k):
        v = rng.normal(size=(k, 3))
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    n_inside = n_rays // 5
    n_outside = n_rays - n_inside
    origins_out = unit(n_outside) * rng.uniform(2.0, 3.0, size=(n_outside, 1))
    targets = unit(n_outside) * rng.uniform(0.0, 2.0, size=(n_outside, 1))
    origins_in = unit(n_inside) * rng.uniform(0.0, 0.8, size=(n_inside, 1))
    origins = np.concatenate([origins_out, origins_in])
    directions = np.concatenate([targets - origins_out, unit(n_inside)])
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return origins, directions


def test_agrees_with_trimesh_numpy_intersector():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    rng = np.random.default_rng(20240611)
    origins, directions = _random_rays(rng, 500)

    # trimesh's code emits its own floating-point warnings; only ours must be clean.
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t_expected, face_expected = _trimesh_first_hit(mesh, origins, directions)
    t, face = reference.first_hit(mesh.vertices, mesh.faces, origins, directions, np.inf)

    hit = face >= 0
    np.testing.assert_array_equal(hit, face_expected >= 0)
    assert 0.3 < hit.mean() < 0.9  # the scene really exercises both hits and misses
    assert hit[-100:].all()  # rays from inside a closed mesh always hit
    np.testing.assert_array_equal(face[hit], face_expected[hit])
    np.testing.assert_allclose(t[hit], t_expected[hit], rtol=0.0, atol=1e-9)

    # A finite max distance agrees with filtering the unbounded answer.
    max_distance = rng.uniform(0.0, 3.0, size=len(origins))
    t_cut, face_cut = reference.first_hit(
        mesh.vertices, mesh.faces, origins, directions, max_distance
    )
    within = hit & (t <= max_distance)
    np.testing.assert_array_equal(face_cut >= 0, within)
    np.testing.assert_array_equal(t_cut[within], t[within])


# One pair at a time; 7 of the 80 faces a block (a ragged last block); one ray against all
# faces (100); all 64 rays x 80 faces at once.
@pytest.mark.slow
@pytest.mark.parametrize("block_pairs", [1, 7, 100, 80 * 64])
def test_block_size_does_not_change_results(block_pairs):
    mesh = trimesh.creation.icosphere(subdivisions=1)
    origins, directions = _random_rays(np.random.default_rng(7), 64)
    expected = reference.first_hit(mesh.vertices, mesh.faces, origins, directions, np.inf)
    t, face = reference.first_hit(
        mesh.vertices, mesh.faces, origins, directions, np.inf, block_pairs=block_pairs
    )
    np.testing.assert_array_equal(t, expected[0])
    np.testing.assert_array_equal(face, expected[1])
