"""The compiled face and vertex normals (aobake/_normals.c: triangle_normals,
vertex_normal_sums) give the numpy formulation's bits (aobake.scene)."""

import numpy as np
import pytest
import trimesh

from aobake import _native
from aobake.scene import face_normals, make_scene, vertex_normals


def _meshes():
    """Random soups at many scales, with degenerate faces, duplicate vertices, repeated
    corners, collinear corners, subnormal and overflowing cross products, and spheres."""
    rng = np.random.default_rng(11)
    for trial in range(40):
        nv, nf = int(rng.integers(3, 300)), int(rng.integers(1, 600))
        v = rng.normal(size=(nv, 3)) * 10.0 ** float(rng.integers(-170, 170))
        f = rng.integers(0, nv, size=(nf, 3))
        if trial % 2:
            v[: nv // 2] = v[nv // 2: 2 * (nv // 2)]  # duplicate vertices
        if trial % 3 == 0:
            f[::5, 2] = f[::5, 0]  # repeated corners
        if trial % 4 == 0:
            v[::7] = 0.5 * (v[1::7][: len(v[::7])] + v[2::7][: len(v[::7])]) \
                if len(v[2::7]) >= len(v[::7]) else v[::7]  # collinear corners
        if trial % 5 == 0:
            v = np.round(v * 4) / 4  # coincident vertices, exact zeros
        yield v, f
    for sub in (0, 2, 4):
        ico = trimesh.creation.icosphere(subdivisions=sub)
        yield ico.vertices, ico.faces
        yield ico.vertices * 1e-160, ico.faces  # squares underflow
        yield ico.vertices * 1e160, ico.faces  # squares overflow
        yield ico.vertices + 1e12, ico.faces[:, ::-1]
    tiny = np.array([[0, 0, 0], [5e-324, 0, 0], [0, 5e-324, 0], [1, 1, 1]], dtype=np.float64)
    yield tiny, np.array([[0, 1, 2], [0, 1, 3], [3, 2, 1], [3, 3, 3]])
    yield np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]), np.array([[0, 1, 2]])
    yield np.zeros((5, 3)), np.array([[0, 1, 2]])  # every vertex at one point


def _same(a, b):
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_compiled_normals_are_the_numpy_bits(kernel):
    for number, (v, f) in enumerate(_meshes()):
        for weighting in ("angle", "area"):
            got = vertex_normals(v, f, weighting)
            with _native.numpy_only():
                want = vertex_normals(v, f, weighting)
            assert _same(got, want), (number, weighting)
        got = face_normals(v, f)
        with _native.numpy_only():
            want = face_normals(v, f)
        assert _same(got, want), number


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_kernel_lengths_are_linalg_norm(kernel):
    """make_scene's areas take the kernel's lengths for np.linalg.norm of the cross products."""
    for number, (v, f) in enumerate(_meshes()):
        unit = np.empty((len(f), 3))
        length = np.empty(len(f))
        cross = np.empty((len(f), 3))
        assert kernel.triangle_normals(v, np.ascontiguousarray(f, dtype=np.int64), unit, length,
                                       cross, np.empty((3, 0)))
        tri = v[f]
        want = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        assert _same(cross, want), number
        assert _same(length, np.linalg.norm(want, axis=1)), number


def test_make_scene_is_the_same_on_the_numpy_path(kernel):
    rng = np.random.default_rng(5)
    ico = trimesh.creation.icosphere(subdivisions=3)
    faces = ico.faces.copy()
    faces[::4] = faces[::4, [0, 2, 1]]  # flipped windings
    faces[::9, 1] = faces[::9, 0]  # degenerate faces
    cases = [(ico.vertices * 3.0 + 7.0, faces),
             (np.concatenate([ico.vertices, ico.vertices]), faces + len(ico.vertices) *
              rng.integers(0, 2, size=faces.shape))]  # duplicate vertices
    for v, f in cases:
        for mode, fix in (("angle", "fix"), ("area", "warn"), ("file", "fix"), ("angle", "off")):
            normals = v - v.mean(axis=0) if mode == "file" else None
            got = make_scene(v, f, normals, mode, fix_normals=fix)
            with _native.numpy_only():
                want = make_scene(v, f, normals, mode, fix_normals=fix)
            for name in ("vertex_normals", "face_normals", "face_areas", "faces"):
                assert _same(getattr(got, name), getattr(want, name)), (mode, fix, name)
            assert got.warnings == want.warnings and got.repair == want.repair


def test_the_kernel_declines_what_numpy_rejects(kernel):
    v = np.zeros((3, 3))
    with pytest.raises(IndexError):
        vertex_normals(v, np.array([[0, 1, 3]]))
    with pytest.raises(IndexError):
        face_normals(v, np.array([[0, 1, 3]]))
    assert not kernel.vertex_normal_sums(np.array([[0, 1, -1]]), np.zeros((1, 3)),
                                         np.empty((3, 0)), np.empty((3, 3)))
    with pytest.raises(ValueError, match="unknown normal weighting"):
        vertex_normals(v, np.array([[0, 1, 2]]), "volume")
    # float32 vertices and an empty mesh: the numpy path's
    v32 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float32)
    assert vertex_normals(v32, np.array([[0, 1, 2]])).dtype == np.float64
    assert vertex_normals(np.zeros((2, 3)), np.zeros((0, 3), dtype=np.int64)).shape == (2, 3)
