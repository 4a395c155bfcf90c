"""The compiled atlas packer (aobake/_pack.c) gives the numpy reference's atlas, bit for bit.

``packing._chart_masks`` (the charts' texel marks, grown by the padding) and
``packing._pack_in_order`` (the whole packing loop) each have a numpy formulation, the
reference, and a compiled one.  Checked here: the same masks, the same placements and
turns, the same sequence of packs in the scale search, and bit-identical UVs, on charts of
generated meshes (xatlas runs in a child process, as everywhere in the tests) and on random
mask sets fed straight to the packer.  Nothing is timed.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np
import pytest
import trimesh

from aobake import _native
from aobake.errors import InputError
from aobake.targets.texels import charts, packing, unwrap


def _pieces(count=20, seed=3):
    """Many small boxes of assorted sizes, turned at random: many charts (> FEW_CHARTS)."""
    rng = np.random.default_rng(seed)
    parts = []
    for _ in range(count):
        box = trimesh.creation.box(rng.uniform(0.05, 0.4, 3))
        box.apply_transform(trimesh.transformations.random_rotation_matrix(rng.random(3)))
        box.apply_translation(rng.uniform(-2, 2, 3))
        parts.append(box)
    return trimesh.util.concatenate(parts)


MESHES = {
    "sphere": lambda: trimesh.creation.uv_sphere(radius=1.0, count=[20, 20]),
    "torus": lambda: trimesh.creation.torus(major_radius=1.0, minor_radius=0.4,
                                            major_sections=32, minor_sections=16),
    "box": lambda: trimesh.creation.box((1.0, 2.0, 3.0)),
    "capsule": lambda: trimesh.creation.capsule(height=3.0, radius=0.5, count=[16, 16]),
    "pieces": _pieces,
}

# Runs in a child (xatlas may crash): each mesh's charts, and a few whole atlases made
# with the compiled packer and with the numpy one.
CHILD = textwrap.dedent("""
    import sys
    import numpy as np
    from aobake.targets.texels import charts, unwrap
    src, dst = sys.argv[1], sys.argv[2]
    out = {}
    with np.load(src) as d:
        names = [str(n) for n in d["names"]]
        for name in names:
            v, f = d[name + "/v"], d[name + "/f"]
            vm, faces, uv, fc, unit = charts.chart_mesh(v, f)
            out.update({name + "/faces": faces, name + "/uv": uv, name + "/fc": fc})
        for i, (name, w, h, p, density) in enumerate(zip(d["atlas_mesh"], d["atlas_w"],
                                                          d["atlas_h"], d["atlas_p"],
                                                          d["atlas_density"])):
            v, f = d[str(name) + "/v"], d[str(name) + "/f"]
            for compiled in (True, False):
                vm, faces, uv, image, info = unwrap._xatlas_atlas(
                    v, f, (int(w), int(h)), int(p), chart_image=True,
                    texel_density=float(density) if density > 0 else None, compiled=compiled)
                key = "%d/%s" % (i, "compiled" if compiled else "numpy")
                out.update({key + "/uv": uv, key + "/image": image,
                            key + "/packing_compiled": info["packing_compiled"],
                            key + "/info": np.array([info[k] for k in ("coverage", "utilization",
                                                     "texels_per_unit", "packs", "width",
                                                     "height")], np.float64)})
    np.savez(dst, **out)
""")

#: whole atlases in the child: (mesh, width, height, padding, texel density or 0)
ATLASES = [("torus", 96, 64, 2, 0.0), ("pieces", 80, 128, 1, 0.0), ("capsule", 64, 64, 4, 0.0),
           ("torus", 0, 0, 2, 12.0), ("box", 0, 0, 1, 9.0)]


def _child_env():
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
    return env


@pytest.fixture(scope="module")
def charted():
    """The child's answers: per mesh name its (uv, faces, face_chart); per ATLASES index
    and packer its uv, image, info and packing_compiled.  Skips where the kernel was not
    built (the child asks for the compiled packer)."""
    if not _native.built():
        pytest.skip("aobake._kernels was not built (no C compiler at install)")
    meshes = {name: make() for name, make in MESHES.items()}
    arrays = {"names": np.array(list(meshes))}
    for name, mesh in meshes.items():
        arrays[name + "/v"] = np.asarray(mesh.vertices, np.float64)
        arrays[name + "/f"] = np.asarray(mesh.faces, np.int64)
    for key, column in zip(("mesh", "w", "h", "p", "density"), zip(*ATLASES)):
        arrays["atlas_" + key] = np.array(column)
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp, "in.npz"), Path(tmp, "out.npz")
        np.savez(src, **arrays)
        subprocess.run([sys.executable, "-c", CHILD, str(src), str(dst)], check=True,
                       timeout=300, capture_output=True, env=_child_env())
        with np.load(dst) as d:
            return {key: d[key] for key in d.files}


def _charts(charted, name):
    return charted[name + "/uv"], charted[name + "/faces"], charted[name + "/fc"]


def _same_masks(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x.dtype == y.dtype == bool and x.shape == y.shape
        np.testing.assert_array_equal(x, y)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(MESHES))
def test_chart_masks_are_the_same(charted, kernel, name):
    """The compiled marks are numpy's: origins, covered and padded masks, at scales from
    a few texels per chart to many, for every padding."""
    uv, faces, fc = _charts(charted, name)
    n = int(fc.max()) + 1
    area = float(charts.uv_face_areas(uv, faces).sum())
    for padding in (0, 1, 2, 4, 8):
        for side in (7.0, 40.0, 150.0):  # the surface as a square of this many texels
            scale = side / np.sqrt(area)
            reference = packing._chart_masks(uv, faces, fc, n, scale, padding)
            got = packing._chart_masks(uv, faces, fc, n, scale, padding, kernel)
            assert reference[0].tobytes() == got[0].tobytes()
            _same_masks(reference[1], got[1])
            _same_masks(reference[2], got[2])


def _spy_packs(monkeypatch):
    """Record every _pack's outcome (fits, texels placed, rows used) in a list."""
    packs = []
    original = packing._pack

    def spy(padded, width, height, kernels=None):
        got = original(padded, width, height, kernels)
        packs.append((got[0] is not None, got[1], got[2]))
        return got

    monkeypatch.setattr(packing, "_pack", spy)
    return packs


def _layout_both(kernel, monkeypatch, function, *args):
    """``function(*args, kernels)`` with numpy and with the kernel: both results (or
    InputError messages) and both sequences of packs."""
    outcomes = []
    for kernels in (None, kernel):
        packs = _spy_packs(monkeypatch)
        try:
            result = function(*args, kernels)
        except InputError as exc:
            result = str(exc)
        outcomes.append((result, packs))
        monkeypatch.undo()
    return outcomes


@pytest.mark.slow
@pytest.mark.parametrize("name", list(MESHES))
def test_layouts_are_the_same(charted, kernel, monkeypatch, name):
    """``_layout``: the same scale search (every pack's outcome), scale, UVs (bit for bit),
    chart image and info, from roomy images down to ones where packs fail and the search
    shrinks the scale or gives up."""
    uv, faces, fc = _charts(charted, name)
    failures = 0
    for R, P in ((128, 2), (96, 0), (64, 4), (160, 8), (32, 1), (24, 2)):
        (reference, packs_ref), (got, packs_got) = _layout_both(
            kernel, monkeypatch, packing._layout, uv, faces, fc, R, P, R == 64)
        assert packs_ref == packs_got, (R, P)
        failures += sum(not fits for fits, _, _ in packs_ref)
        if isinstance(reference, str):
            assert reference == got
            continue
        assert reference[0].tobytes() == got[0].tobytes(), (R, P)
        assert np.isfinite(got[0]).all() and got[1] > 0, (R, P)
        assert reference[1] == got[1]
        if reference[2] is not None:
            np.testing.assert_array_equal(reference[2], got[2])
        assert reference[3] == got[3]
    assert failures > 0  # the low resolutions exercised the retries


@pytest.mark.slow
@pytest.mark.parametrize("name", ["torus", "pieces", "box"])
def test_layouts_at_a_density_are_the_same(charted, kernel, monkeypatch, name):
    """``_layout_at_density`` (the strip grown until the charts fit): the same packs and
    the same atlas."""
    uv, faces, fc = _charts(charted, name)
    area = float(charts.uv_face_areas(uv, faces).sum())
    for side, P in ((30.0, 1), (90.0, 2), (50.0, 8)):
        (reference, packs_ref), (got, packs_got) = _layout_both(
            kernel, monkeypatch, packing.layout_at_density, uv, faces, fc,
            side / np.sqrt(area), P, False)
        assert packs_ref == packs_got
        assert reference[0].tobytes() == got[0].tobytes()
        assert reference[1] == got[1] and reference[3] == got[3] and reference[4] == got[4]


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(ATLASES)))
def test_whole_atlases_are_the_same(charted, index):
    """``_xatlas_atlas`` in the child with compiled=True and False: the same UVs, chart
    image and info (a non-square image, texel densities), and info says which packer ran."""
    a, b = f"{index}/compiled", f"{index}/numpy"
    assert charted[a + "/uv"].tobytes() == charted[b + "/uv"].tobytes()
    np.testing.assert_array_equal(charted[a + "/image"], charted[b + "/image"])
    assert charted[a + "/info"].tobytes() == charted[b + "/info"].tobytes()
    assert bool(charted[a + "/packing_compiled"]) and not bool(charted[b + "/packing_compiled"])


# --- random mask sets, straight to the packer ----------------------------------------


def _random_mask(rng, width):
    """A random padded-mask-like shape: blobs, rings, bars, single texels, empty columns,
    wider than the strip, or empty."""
    kind = rng.integers(8)
    h, w = (int(x) for x in rng.integers(1, 40, 2))
    if kind == 0:
        return np.ones((1, 1), bool)
    if kind == 1:  # a bar longer than the strip is wide: fits only turned, if at all
        return np.ones((int(rng.integers(1, 4)), width + int(rng.integers(1, 6))), bool)
    if kind == 2:  # a ring: room inside for small ones
        m = np.ones((h + 4, w + 4), bool)
        m[2:-2, 2:-2] = False
        return m
    if kind == 3:  # columns without texels (the profile skips them)
        m = rng.random((h, w)) < 0.7
        m[:, rng.random(w) < 0.4] = False
        m[rng.integers(h), rng.integers(w)] = True
        return m
    if kind == 4:
        return np.zeros((h, w), bool)  # no texels: not placed
    m = rng.random((h, w)) < rng.uniform(0.3, 1.0)
    m[rng.integers(h), rng.integers(w)] = True
    return m


def _both_packs(kernel, masks, width, height, order, upright):
    """One pack by numpy and by the kernel: the same result, and the packers end in the
    same state (occupancy, skyline, free runs, free squares and whether they were made),
    so what is not decisive here cannot diverge later either."""
    reference, packer = packing._pack_numpy(masks, width, height, order, upright)
    state = (np.zeros((height, width), np.uint8), np.zeros(width, np.int32),
             np.zeros((height + packing.HOLE_CAP, width), np.int16),
             np.zeros((height, width), np.int16), np.zeros(height, np.int16))
    got = packing._pack_compiled(kernel, masks, width, height, order, upright, state)
    assert reference == got, (width, height, upright)
    assert packing._pack_in_order(masks, width, height, order, upright, kernel) == got
    np.testing.assert_array_equal(state[0].view(bool), packer.occupied)
    np.testing.assert_array_equal(state[1], packer.sky)
    np.testing.assert_array_equal(state[2], packer.free_run)
    if packer.square is None:
        assert (state[3] == -1).all() and (state[4] == -1).all()
    else:
        np.testing.assert_array_equal(state[3], packer.square)
        np.testing.assert_array_equal(state[4], packer.row_best)
    return reference


@pytest.mark.slow
@pytest.mark.parametrize("name", list(MESHES))
def test_chart_masks_pack_the_same(charted, kernel, name):
    """The generated meshes' masks, in every order, in a roomy and a tight strip."""
    uv, faces, fc = _charts(charted, name)
    n = int(fc.max()) + 1
    area = float(charts.uv_face_areas(uv, faces).sum())
    for side, padding, strip in ((60.0, 2, 80), (75.0, 1, 80), (40.0, 4, 64)):
        _, _, padded = packing._chart_masks(uv, faces, fc, n, side / np.sqrt(area), padding,
                                            kernel)
        for how, upright in packing.ORDERS:
            _both_packs(kernel, padded, strip, strip, packing._order(padded, how), upright)


@pytest.mark.slow
def test_random_mask_sets_pack_the_same(kernel):
    """Random masks in random strips, every order and both upright settings: the same
    placements, turns, texels placed and rows used, also when they do not fit."""
    rng = np.random.default_rng(11)
    fits = fails = 0
    for trial in range(60):
        # strips wider than HOLE_RUN too: free runs cut far left of a chart
        width = int(rng.integers(8, 120 if trial % 3 else 320))
        height = int(rng.integers(8, 160))
        masks = [_random_mask(rng, width) for _ in range(int(rng.integers(1, 25)))]
        for how, upright in packing.ORDERS:
            place, _, _ = _both_packs(kernel, masks, width, height, packing._order(masks, how),
                                      upright)
            fits += place is not None
            fails += place is None
    assert fits > 20 and fails > 20


def test_free_runs_are_cut_as_far_left_as_numpy(kernel):
    """A chart placed with more than HOLE_RUN free texels to its left (beside a one-row
    bar): the free runs are cut exactly HOLE_RUN - 1 columns back (the state comparison
    sees each one)."""
    for left in (150, 128, 127, 20):
        place, _, _ = _both_packs(kernel, [np.ones((1, left), bool), np.ones((3, 7), bool)],
                                  left + 60, 60, np.arange(2), False)
        assert place == [(0, 0, 0), (0, left, 0)]


@pytest.mark.slow
def test_small_charts_fill_holes_and_search_everywhere_the_same(kernel):
    """Many small charts after large hollow ones in a tight strip: holes (the lazily made
    free squares, the rows tried) and the exhaustive search decide most places."""
    rng = np.random.default_rng(5)
    for trial in range(4):
        width, height = int(rng.integers(60, 140)), int(rng.integers(50, 100))
        rings = []
        for _ in range(int(rng.integers(2, 6))):
            h, w = (int(x) for x in rng.integers(20, 50, 2))
            m = np.ones((h, w), bool)
            m[2:-2, 2:-2] = False
            rings.append(m)
        small = [rng.random(tuple(int(x) for x in rng.integers(1, 9, 2))) < 0.8
                 for _ in range(150)]
        small = [m if m.any() else np.ones((1, 1), bool) for m in small]
        masks = rings + small
        _both_packs(kernel, masks, width, height, np.arange(len(masks)), False)
        _both_packs(kernel, masks, width, height, packing._order(masks, "texels"), True)


def test_exhaustive_search_limit_is_the_same(kernel):
    """Charts too large for holes inside a frame filling the strip: each needs the
    exhaustive search (where both turns of a square tie: the first is kept), which stops
    after MAX_SEARCHES charts although room is left."""
    frame = np.ones((252, 252), bool)
    frame[1:-1, 1:-1] = False
    square = np.ones((40, 40), bool)
    square[:, -1] = False  # a column without texels: the turns' scores differ in order
    masks = [frame] + [np.ones((40, 40), bool)] * 10 + [square] * 4
    place, _, _ = _both_packs(kernel, masks, 252, 252, np.arange(len(masks)), False)
    assert place is not None and {k for _, _, k in place[1:11]} == {0}
    masks = [frame] + [np.ones((40, 40), bool)] * 30
    place, placed, used = _both_packs(kernel, masks, 252, 252, np.arange(len(masks)), False)
    assert place is None and used == 252
    assert placed == int(frame.sum()) + packing.MAX_SEARCHES * 1600


def test_hole_search_stops_after_hole_rows(kernel):
    """A hole tried only within the first HOLE_ROWS rows with a large enough free square:
    a comb of 7 x 7 pockets gives exactly HOLE_ROWS such rows, none holding a 6 x 8 chart
    either way up; a pocket that holds it lies below them, so the chart drops onto the
    skyline instead.  (A packer trying one row more would take the pocket.)"""
    comb = np.ones((280, 40), bool)
    for i in range(packing.HOLE_ROWS // 2):  # 2 rows per pocket with a free 6 x 6 square
        comb[1 + 8 * i:8 + 8 * i, 2:9] = False
    comb[265:272, 20:29] = False  # 9 wide, 7 tall: holds the chart lying down
    chart = np.ones((6, 8), bool)
    place, _, _ = _both_packs(kernel, [comb, chart], 40, 400, np.arange(2), False)
    assert place == [(0, 0, 0), (280, 0, 0)]
    comb[1:8, 2:9] = True  # one pocket fewer: the hole is within reach
    place, _, _ = _both_packs(kernel, [comb, chart], 40, 400, np.arange(2), False)
    assert place == [(0, 0, 0), (265, 20, 0)]


@pytest.mark.slow
def test_pack_keeps_the_fewest_rows_the_same(kernel):
    """``_pack`` over ORDERS (few charts): the same choice, the same layout."""
    rng = np.random.default_rng(2)
    for trial in range(10):
        width = int(rng.integers(16, 80))
        masks = [_random_mask(rng, width) for _ in range(int(rng.integers(1, 12)))]
        assert packing._pack(masks, width, 3 * width) == packing._pack(masks, width, 3 * width,
                                                                         kernel)


def test_pack_kernel_refuses_bad_buffers(kernel):
    """Shapes that do not match the buffers, and orders naming no chart, are refused."""
    masks = np.ones(12, np.uint8)
    offsets, shapes = np.array([0, 12], np.int64), np.array([[3, 4]], np.int64)
    out = np.zeros((1, 3), np.int64)
    constants = (packing.HOLE_CAP, packing.HOLE_RUN, packing.HOLE_ROWS, packing.MAX_SEARCHES)
    assert kernel.pack_charts(masks, offsets, shapes, np.array([0]), 8, 8, False, *constants,
                              out) == (True, 12, 3)
    with pytest.raises(ValueError, match="order"):
        kernel.pack_charts(masks, offsets, shapes, np.array([1]), 8, 8, False, *constants, out)
    with pytest.raises(ValueError, match="shape"):
        kernel.pack_charts(masks, offsets, np.array([[3, 5]], np.int64), np.array([0]), 8, 8,
                           False, *constants, out)
    with pytest.raises(ValueError, match="out_place"):
        kernel.pack_charts(masks, offsets, shapes, np.array([0]), 8, 8, False, *constants,
                           np.zeros((2, 3), np.int64))
    xy = np.array([[0.5, 0.5], [2.5, 0.5], [0.5, 2.5]])
    size, offset = np.array([[2, 2]], np.int64), np.array([0, 4], np.int64)
    with pytest.raises(ValueError, match="leave"):  # 2 x 2 texels cannot hold the triangle
        kernel.chart_marks(xy, np.array([[0, 1, 2]], np.int64), np.zeros(1, np.int64), offset,
                           size, 0, np.zeros(4, np.uint8), np.zeros(4, np.uint8))


# --- which packer ran, through the child process and the report ------------------------


@pytest.mark.slow
def test_unwrap_reports_the_packer_that_ran(kernel):
    """The caller's choice reaches the isolated child (numpy_only is thread-local) and
    comes back in ``Unwrapped.packing_compiled``; the atlas is the same."""
    mesh = MESHES["torus"]()
    compiled = unwrap.unwrap(mesh.vertices, mesh.faces, 48, 1)
    with _native.numpy_only():
        reference = unwrap.unwrap(mesh.vertices, mesh.faces, 48, 1)
    assert compiled.packing_compiled is True and reference.packing_compiled is False
    assert compiled.uv.tobytes() == reference.uv.tobytes()
    np.testing.assert_array_equal(compiled.faces, reference.faces)
    np.testing.assert_array_equal(compiled.vmapping, reference.vmapping)


def test_own_uvs_report_no_packing(kernel):
    """A lightmap baked into the mesh's own UVs packs nothing: atlas_packing 'not used'."""
    import aobake

    n = 6  # a grid over the unit square, its UVs its x and y
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)).ravel()
    faces = np.concatenate([np.stack([i, i + 1, i + n + 1], 1), np.stack([i, i + n + 1, i + n], 1)])
    mesh = trimesh.Trimesh(vertices, faces, process=False,
                           visual=trimesh.visual.TextureVisuals(uv=vertices[:, :2]))
    result = aobake.bake_texels(mesh, quantities=("ao",), rays=4, resolution=16, padding=1,
                                threads=1)
    assert result.report["texture"]["atlas"] == "mesh UVs"
    assert result.report["parameters"]["kernels"]["atlas_packing"] == "not used"
