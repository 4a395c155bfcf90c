"""aobake._xatlas (xatlas built from third_party/xatlas, with speed patches) charts exactly
like the xatlas package, which is its fallback: the same vertices, faces and UVs, bit for
bit, on meshes with many charts, several parts and a chart cap, when it places the charts
as the package does; unplaced (what aobake uses), each chart's UVs are the placed ones but
for a whole-texel translation (and an axis swap where packing turned the chart)."""

import numpy as np
import pytest
import trimesh

from aobake.targets.texels import charts

built = pytest.mark.skipif(charts.charting_library() != "aobake._xatlas",
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


def each_mesh(test):
    """The test with aobake._xatlas built, on each of ``_meshes()`` (its ``meshes``
    argument), uncapped and with a chart cap (``cap``)."""
    def run(name, cap):
        test(_meshes()[name], cap)

    run.__name__, run.__doc__ = test.__name__, test.__doc__
    return built(pytest.mark.parametrize("name", ["bumpy sphere", "three parts"])(
        pytest.mark.parametrize("cap", [0.0, 40.0])(run)))


@pytest.mark.slow
@each_mesh
def test_built_xatlas_charts_exactly_like_the_package(meshes, cap):
    ours = charts.xatlas_charts(meshes, cap, 4.0, library="aobake._xatlas", placed=True)
    theirs = charts.xatlas_charts(meshes, cap, 4.0, library="xatlas")
    assert ours[:2] == theirs[:2]
    assert len(ours[2]) == len(theirs[2]) == len(meshes)
    n_charts = 0
    for (vm, fi, uv), (vm2, fi2, uv2), (_, faces) in zip(ours[2], theirs[2], meshes):
        assert vm.dtype == vm2.dtype and fi.dtype == fi2.dtype and uv.dtype == uv2.dtype
        np.testing.assert_array_equal(vm, vm2)
        np.testing.assert_array_equal(fi, fi2)
        np.testing.assert_array_equal(uv.view(np.uint32), uv2.view(np.uint32))  # bits
        assert fi.shape == faces.shape
        n_charts += charts.connected_labels(len(vm), fi.astype(np.int64)).max() + 1
    assert n_charts > 10  # a real charting, not one chart per mesh


def _placement_errors(placed, unplaced, faces):
    """Per chart of ``faces`` (m, 3) int64: the largest deviation of ``placed`` (k, 2)
    float64 texels from ``unplaced`` (k, 2) (or it with its axes swapped, whichever fits)
    plus one whole-texel translation."""
    chart = charts.connected_labels(len(placed), faces)
    vertex_chart = np.full(len(placed), -1)
    vertex_chart[faces.reshape(-1)] = np.repeat(chart, 3)
    out = []
    for c in range(int(chart.max()) + 1):
        v = np.flatnonzero(vertex_chart == c)
        fits = []
        for swapped in (False, True):
            d = placed[v] - (unplaced[v][:, ::-1] if swapped else unplaced[v])
            fits.append(float(np.abs(d - np.round(d[0])).max()))
        out.append(min(fits))
    return out


@pytest.mark.slow
@each_mesh
def test_unplaced_charts_are_the_placed_ones_translated(meshes, cap):
    placed = charts.xatlas_charts(meshes, cap, 4.0, library="aobake._xatlas", placed=True)
    unplaced = charts.xatlas_charts(meshes, cap, 4.0, library="aobake._xatlas")
    width, height = placed[:2]
    assert unplaced[:2] == (1, 1) and width > 1 and height > 1
    # The placed UVs are float32(float32(x + t) / W) (xatlas's sum, the binding's division),
    # read back times W: each rounding at most half a float32 ulp at the atlas's size.
    tolerance = 2.0 * float(np.spacing(np.float32(max(width, height))))
    for (vm, fi, uv), (vm2, fi2, uv2) in zip(placed[2], unplaced[2]):
        np.testing.assert_array_equal(vm, vm2)
        np.testing.assert_array_equal(fi, fi2)
        assert uv2.min() >= 0.5 - 1e-6  # each chart at its own texel-centre origin
        errors = _placement_errors(uv.astype(np.float64) * [width, height],
                                   uv2.astype(np.float64), fi.astype(np.int64))
        assert max(errors) <= tolerance


@built
@pytest.mark.slow
def test_built_xatlas_rejects_what_the_package_rejects():
    v, f = _bumpy(2, 3)
    bad = f.copy()
    bad[0, 0] = len(v) + 5  # an index out of range
    for library in ("aobake._xatlas", "xatlas"):
        with pytest.raises((ValueError, RuntimeError), match="Adding mesh failed"):
            charts.xatlas_charts([(v, bad)], 0.0, 4.0, library=library)
    from aobake import _xatlas

    with pytest.raises(ValueError, match="expected"):
        _xatlas.chart([(v, len(v) + 1, f, len(f))], 0.0, 4.0)  # a short buffer
    with pytest.raises(TypeError):
        _xatlas.chart([(v, len(v))], 0.0, 4.0)
