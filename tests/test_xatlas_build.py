"""aobake._xatlas (xatlas built from third_party/xatlas, with three speed patches) charts
exactly like the xatlas package, which is its fallback: the same vertices, faces and UVs,
bit for bit, on meshes with many charts, several parts and a chart cap."""

import numpy as np
import pytest
import trimesh

from aobake.targets.texels import unwrap

built = pytest.mark.skipif(unwrap.charting_library() != "aobake._xatlas",
                           reason="aobake._xatlas was not built (needs a C++ compiler)")


def _bumpy(subdivisions: int, seed: int):
    """A sphere with radial noise (not a regular icosphere: those crash xatlas, #146)."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions)
    rng = np.random.default_rng(seed)
    v = mesh.vertices * (1.0 + 0.15 * rng.standard_normal((len(mesh.vertices), 1)))
    return v.astype(np.float32), mesh.faces.astype(np.uint32)


def _meshes():
    torus = trimesh.creation.torus(1.0, 0.3, major_sections=48, minor_sections=24)
    box = trimesh.creation.box().subdivide().subdivide()
    return {
        "bumpy sphere": [_bumpy(4, 1)],
        "three parts": [_bumpy(3, 2),
                        (torus.vertices.astype(np.float32), torus.faces.astype(np.uint32)),
                        (box.vertices.astype(np.float32), box.faces.astype(np.uint32))],
    }


@built
@pytest.mark.parametrize("name", ["bumpy sphere", "three parts"])
@pytest.mark.parametrize("cap", [0.0, 40.0])
def test_built_xatlas_charts_exactly_like_the_package(name, cap):
    meshes = _meshes()[name]
    ours = unwrap.xatlas_charts(meshes, cap, 4.0, library="aobake._xatlas")
    theirs = unwrap.xatlas_charts(meshes, cap, 4.0, library="xatlas")
    assert ours[:2] == theirs[:2]
    assert len(ours[2]) == len(theirs[2]) == len(meshes)
    charts = 0
    for (vm, fi, uv), (vm2, fi2, uv2), (_, faces) in zip(ours[2], theirs[2], meshes):
        assert vm.dtype == vm2.dtype and fi.dtype == fi2.dtype and uv.dtype == uv2.dtype
        np.testing.assert_array_equal(vm, vm2)
        np.testing.assert_array_equal(fi, fi2)
        np.testing.assert_array_equal(uv.view(np.uint32), uv2.view(np.uint32))  # bits
        assert fi.shape == faces.shape
        charts += unwrap.connected_labels(len(vm), fi.astype(np.int64)).max() + 1
    assert charts > 10  # a real charting, not one chart per mesh


@built
def test_built_xatlas_rejects_what_the_package_rejects():
    v, f = _bumpy(2, 3)
    bad = f.copy()
    bad[0, 0] = len(v) + 5  # an index out of range
    for library in ("aobake._xatlas", "xatlas"):
        with pytest.raises((ValueError, RuntimeError), match="Adding mesh failed"):
            unwrap.xatlas_charts([(v, bad)], 0.0, 4.0, library=library)
    from aobake import _xatlas

    with pytest.raises(ValueError, match="expected"):
        _xatlas.chart([(v, len(v) + 1, f, len(f))], 0.0, 4.0)  # a short buffer
    with pytest.raises(TypeError):
        _xatlas.chart([(v, len(v))], 0.0, 4.0)
