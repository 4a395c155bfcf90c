"""Same input + seed -> bit-identical results for any thread count and chunk size."""

import numpy as np
import pytest
import trimesh

import aobake
from aobake.outputs import write_vertices


def scene():
    knot = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3)
    floor = trimesh.creation.box(extents=[4, 0.1, 4])
    floor.apply_translation([0, -0.4, 0])
    return trimesh.util.concatenate([knot, floor])


@pytest.mark.slow
@pytest.mark.parametrize("sampler", ["random", "sobol"])
def test_threads_and_chunks_do_not_change_results(sampler, tmp_path):
    opts = dict(rays=40, sampler=sampler, quantities=("ao", "obscurance", "bent-normal"), seed=11)
    runs = [aobake.bake(scene(), threads=t, chunk_rays=c, **opts)
            for t, c in ((1, 65536), (2, 65536), (2, 97), (1, 1), (2, 4000))]
    first = runs[0].fields()
    for other in runs[1:]:
        for name, array in first.items():
            assert np.array_equal(array, other.fields()[name]), name
    # And the files written are byte-identical.
    blobs = []
    for i, res in enumerate(runs[:3]):
        for ext in (".ply", ".glb", ".npz"):
            path = tmp_path / f"run{i}{ext}"
            write_vertices(path, res.positions, res.faces, res.fields(), {"config": res.report["config"]})
            blobs.append((ext, path.read_bytes()))
    for ext in (".ply", ".glb", ".npz"):
        data = [b for e, b in blobs if e == ext]
        assert all(d == data[0] for d in data), ext


def test_seed_changes_results():
    a = aobake.bake(scene(), rays=32, seed=1)
    b = aobake.bake(scene(), rays=32, seed=2)
    assert not np.array_equal(a.ao, b.ao)


def test_vertices_split_at_seams_get_identical_values():
    # Two copies of one vertex (same position and normal) must not differ by noise.
    mesh = scene()
    v, f, n = mesh.vertices, mesh.faces, mesh.vertex_normals
    v2, n2 = np.vstack([v, v[f[0]]]), np.vstack([n, n[f[0]]])
    f2 = f.copy()
    f2[0] = len(v) + np.arange(3)
    split = trimesh.Trimesh(v2, f2, vertex_normals=n2, process=False)
    res = aobake.bake(split, rays=32, normals="file")
    assert np.array_equal(res.ao[f[0]], res.ao[len(v):])


def test_morton_order_matches_bitwise_interleave():
    """The bit-spreading Morton sort equals a literal per-bit interleave, ties in input order."""
    from aobake.trace import morton_order

    rng = np.random.default_rng(3)
    points = rng.random((5000, 3)) * [1e-4, 1.0, 1e5] + [0.0, -3.0, 1e5]
    points[100:200] = points[100]  # ties
    points[:, 1][::7] = points[0, 1]
    lo, hi = points.min(axis=0), points.max(axis=0)
    q = ((points - lo) * (1023.0 / (hi - lo))).astype(np.int64)
    code = np.zeros(len(points), dtype=np.int64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
    order = morton_order(points)
    np.testing.assert_array_equal(order, np.argsort(code, kind="stable"))
    assert morton_order(np.zeros((0, 3))).shape == (0,)
    np.testing.assert_array_equal(morton_order(np.ones((4, 3))), np.arange(4))


@pytest.mark.slow
def test_bakes_do_not_depend_on_the_compiled_kernel(kernel):
    """Without aobake._kernels (no compiler at install) every bake gives the same bits,
    and the report says which implementation ran."""
    import trimesh

    import aobake
    from aobake import _native
    mesh = trimesh.creation.torus(major_radius=1.0, minor_radius=0.4, major_sections=24,
                                  minor_sections=12)
    quantities = ("ao", "obscurance", "bent-normal")

    def run():
        vertex = aobake.bake(mesh, quantities=quantities, rays=48, sampler="sobol", threads=2)
        texel = aobake.bake_texels(mesh, quantities=("ao", "bent-normal"), rays=16, resolution=32,
                                   padding=1, threads=2)
        return vertex, texel

    compiled = run()
    with _native.numpy_only():
        reference = run()
    everything = {"ray_generation": "compiled", "escape_counts": "compiled",
                  "rasterizer": "not used", "atlas_packing": "not used", "seam_solve": "not used",
                  "gutters": "not used"}
    assert compiled[0].report["parameters"]["kernels"] == everything
    assert compiled[1].report["parameters"]["kernels"] == dict(  # the torus has no UVs: unwrapped
        everything, rasterizer="compiled", atlas_packing="compiled", seam_solve="compiled",
        gutters="compiled")
    assert compiled[1].report["texture"]["seams"]["iterations"] > 0  # the solve ran
    assert reference[0].report["parameters"]["kernels"] == {
        "ray_generation": "numpy", "escape_counts": "numpy", "rasterizer": "not used",
        "atlas_packing": "not used", "seam_solve": "not used", "gutters": "not used"}
    assert set(reference[1].report["parameters"]["kernels"].values()) == {"numpy"}
    for name, array in compiled[0].fields().items():
        np.testing.assert_array_equal(array, getattr(reference[0], name), err_msg=name)
    assert compiled[1].channels.keys() == reference[1].channels.keys()
    for name, image in compiled[1].channels.items():
        np.testing.assert_array_equal(image, reference[1].channels[name], err_msg=name)


def test_radix_sort_gives_the_stable_argsort(kernel):
    """The compiled radix sort is the stable argsort (ties in input order) at every bound,
    as numpy's, and returns the keys in that order."""
    from aobake.rng import stable_sort

    rng = np.random.default_rng(5)
    for n, bound in [(0, 8), (1, 1), (5, 2), (3000, 2**11), (3000, 2**11 + 1), (20000, 2**22),
                     (20000, 2**30), (5000, 2**32)]:
        key = rng.integers(0, bound, n, dtype=np.int64)
        key[: n // 3] = key[0] if n else 0  # many ties
        order, ordered = stable_sort(key, bound, kernel)
        reference, reference_keys = stable_sort(key, bound, None)
        np.testing.assert_array_equal(order, np.argsort(key, kind="stable"))
        np.testing.assert_array_equal(order, reference)
        np.testing.assert_array_equal(ordered, reference_keys)
        assert ordered.dtype == reference_keys.dtype == np.int64
