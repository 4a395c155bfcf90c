"""Texel targets: rasteriser, UV checks, unwrapping, splatting; dilation; tangents.

Texel convention under test: row 0 of an (H, W) image is the top (v near 1);
texel (r, c) has its centre at u = (c + 0.5) / W, v = 1 - (r + 0.5) / H.
"""

import numpy as np
import pytest
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import Delaunay

from aobake import post, tangents
from aobake.errors import InputError
from aobake import child as children
from aobake.targets.texels import charts
from aobake.targets.texels import raster as texels
from aobake.targets.texels import unwrap as unwrapping
from aobake.targets.texels.splat import splat, splat_count
from aobake.targets.texels.raster import rasterize
from aobake.targets.texels.surface import surface_points
from aobake.targets.texels.uvcheck import check_uvs
from aobake.targets.texels.unwrap import unwrap

QUAD_UV = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
QUAD_FACES = np.array([[0, 1, 2], [0, 2, 3]])


def centre_uv(texel, width, height):
    r, c = np.divmod(texel, width)
    return np.stack([(c + 0.5) / width, 1.0 - (r + 0.5) / height], axis=1)


def sample_uv(uv, faces, samples):
    return np.einsum("sk,skd->sd", samples.bary, uv[faces[samples.face]])


def assert_same_samples(a, b):
    for name in ("texel", "face", "bary", "sample", "is_fallback", "coverage", "shared"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


# --- exact coverage -------------------------------------------------------------


@pytest.mark.parametrize("k", [1, 2, 3, 4, 9])
def test_unit_quad_covers_every_texel_once(k):
    w, h = 6, 4
    s = rasterize(QUAD_UV, QUAD_FACES, w, h, texel_samples=k)
    assert s.n_samples == w * h * k  # no sub-position lost or counted twice
    assert np.all(s.coverage == 1.0)
    assert np.all(s.shared == 1)
    assert not s.is_fallback.any()
    assert np.array_equal(splat_count(s), np.full((h, w), k))
    # every (texel, k) exactly once
    key = s.texel * k + s.sample
    assert np.array_equal(np.sort(key), np.arange(w * h * k))


def test_single_triangle_coverage_counts():
    # Face 1 = uv (0,0), (1,1), (0,1) is the upper-left half of the image:
    # texels with r + c <= 3 at 4 x 4.  6 centres lie strictly inside and 4 on
    # the shared diagonal, which exactly one of the two faces owns.
    s = rasterize(QUAD_UV, QUAD_FACES[1:], 4, 4)
    other = rasterize(QUAD_UV, QUAD_FACES[:1], 4, 4)
    regular, other_regular = s.n_samples - s.is_fallback.sum(), other.n_samples - other.is_fallback.sum()
    assert regular in (6, 10)
    assert regular + other_regular == 16
    assert np.array_equal(s.shared + other.shared, np.ones((4, 4)))
    r, c = s.rows_cols()
    assert np.all(r + c <= 3)
    # The face that does not own the diagonal still overlaps those texels, so
    # it gets one fallback sample there (on its edge); 4 in total between them.
    assert s.is_fallback.sum() + other.is_fallback.sum() == 4
    fb_r, fb_c = np.divmod(np.concatenate([s.texel[s.is_fallback], other.texel[other.is_fallback]]), 4)
    assert np.all(fb_r + fb_c == 3)
    # texels the triangle does not reach at all stay empty
    assert np.all(s.coverage[r.max():, c.max():][np.add.outer(np.arange(4), np.arange(4))[r.max():, c.max():] > 3] == 0)
    assert s.coverage.sum() + other.coverage.sum() == 16 + 4 * texels.FALLBACK_COVERAGE_FRACTION


def test_triangle_away_from_centres_matches_brute_force():
    uv = np.array([[0.07, 0.11], [0.93, 0.29], [0.41, 0.88]])
    w, h = 13, 9
    s = rasterize(uv, np.array([[0, 1, 2]]), w, h)
    # brute force: texel centres strictly inside (none lies on an edge here)
    cuv = centre_uv(np.arange(w * h), w, h)
    a, b, c = uv
    def side(p, q):
        return (q[0] - p[0]) * (cuv[:, 1] - p[1]) - (q[1] - p[1]) * (cuv[:, 0] - p[0])
    e = np.stack([side(a, b), side(b, c), side(c, a)], 1)
    assert np.all(np.abs(e) > 1e-9)
    inside = np.all(e > 0, axis=1)
    assert np.array_equal(np.sort(s.texel[~s.is_fallback]), np.flatnonzero(inside))


@pytest.mark.parametrize("k", [1, 4])
def test_shared_edges_and_vertices_on_texel_centres_counted_once(k):
    # A triangulation whose vertices sit on texel centres, texel corners and
    # random points: every centre must be covered by exactly one triangle.
    w = h = 16
    rng = np.random.default_rng(1)
    centres = centre_uv(rng.choice(w * h, 40, replace=False), w, h)
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    grid = np.stack(np.meshgrid(np.arange(0, 17, 4), np.arange(0, 17, 4)), -1).reshape(-1, 2) / 16
    pts = np.unique(np.concatenate([corners, grid, centres, rng.random((30, 2))]), axis=0)
    tri = Delaunay(pts).simplices
    s = rasterize(pts, tri, w, h, texel_samples=k)
    assert np.all(s.shared == 1)
    assert s.n_samples == w * h * k
    assert np.all(s.coverage == 1)
    assert check_uvs(pts, tri, w, h).overlapping_texels == 0


# --- texel convention -------------------------------------------------------------


def test_centre_samples_map_back_to_texel_centres():
    w, h = 7, 5
    s = rasterize(QUAD_UV, QUAD_FACES, w, h)
    np.testing.assert_allclose(sample_uv(QUAD_UV, QUAD_FACES, s), centre_uv(s.texel, w, h), atol=1e-12)
    # row 0 is the top of the image: v close to 1
    r, _ = s.rows_cols()
    assert np.all(sample_uv(QUAD_UV, QUAD_FACES, s)[r == 0][:, 1] > 0.8)


def test_row_zero_is_top():
    top = np.array([[0.0, 0.5], [1.0, 0.5], [1.0, 1.0], [0.0, 1.0]])  # v in [0.5, 1]
    s = rasterize(top, QUAD_FACES, 4, 4)
    assert np.all(s.coverage[:2] == 1) and np.all(s.coverage[2:] == 0)


@pytest.mark.parametrize("k", [4, 5], ids=["grid", "lattice"])
def test_jittered_samples_stay_in_their_texel(k):
    w, h = 8, 8
    s = rasterize(QUAD_UV, QUAD_FACES, w, h, texel_samples=k, seed=7)
    p = sample_uv(QUAD_UV, QUAD_FACES, s)
    r, c = s.rows_cols()
    x, y = p[:, 0] * w, (1 - p[:, 1]) * h
    assert np.all((x >= c - 1e-9) & (x <= c + 1 + 1e-9) & (y >= r - 1e-9) & (y <= r + 1 + 1e-9))


def test_square_k_is_stratified():
    # K = 4: one sub-position in each quarter of every texel
    tex = np.arange(100)
    cells = []
    for k in range(4):
        dx, dy = texels.subsample_offsets(tex, k, 4, seed=3)
        cells.append((dx >= 0.5).astype(int) + 2 * (dy >= 0.5))
    assert np.all(np.sort(np.stack(cells, 1), axis=1) == [0, 1, 2, 3])


# --- UV checks -------------------------------------------------------------------


def shell(x0, x1, y0=0.0, y1=1.0, mirror=False):
    uv = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    if mirror:
        uv[:, 0] = x0 + x1 - uv[:, 0]
    return uv


def test_overlap_detection_counts_shared_texels():
    w = h = 8
    uv = np.concatenate([shell(0.0, 0.5), shell(0.25, 0.75)])
    faces = np.concatenate([QUAD_FACES, QUAD_FACES + 4])
    chk = check_uvs(uv, faces, w, h)
    assert chk.overlapping_texels == 2 * h  # columns 2 and 3 covered twice
    assert not chk.valid and "more than one face" in chk.message
    s = rasterize(uv, faces, w, h)
    assert np.count_nonzero(s.shared == 2) == 2 * h
    assert s.coverage.max() == 1.0  # stacked shells do not exceed full coverage


def test_separate_shells_are_valid():
    uv = np.concatenate([shell(0.0, 0.5), shell(0.5, 1.0)])  # touching, not overlapping
    faces = np.concatenate([QUAD_FACES, QUAD_FACES + 4])
    chk = check_uvs(uv, faces, 8, 8)
    assert chk.valid and chk.overlapping_texels == 0 and chk.mirrored_faces == 0


def test_mirrored_and_degenerate_and_out_of_range_faces():
    uv = np.concatenate([shell(0.0, 0.3), shell(0.35, 0.65), shell(0.7, 1.0, mirror=True)])
    faces = np.concatenate([QUAD_FACES, QUAD_FACES + 4, QUAD_FACES + 8])
    chk = check_uvs(uv, faces, 16, 16)
    assert chk.mirrored_faces == 2 and chk.valid
    uv2 = np.concatenate([uv, [[0.5, 0.5], [0.5, 0.5], [0.6, 0.6]], [[0.9, 0.9], [1.2, 0.9], [0.9, 0.95]]])
    faces2 = np.concatenate([faces, [[12, 13, 14], [15, 16, 17]]])
    chk2 = check_uvs(uv2, faces2, 16, 16)
    assert chk2.degenerate_faces == 1
    assert chk2.out_of_range_faces == 1 and not chk2.valid


# --- fallback samples ---------------------------------------------------------------


@pytest.mark.parametrize("k", [1, 4])
def test_sliver_gets_fallback_samples_on_the_triangle(k):
    # A thin sliver between texel-centre rows: no centre lands on it.
    w = h = 16
    uv = np.array([[0.02, 0.5 + 0.1 / h], [0.98, 0.5 + 0.3 / h], [0.5, 0.5 + 0.45 / h]])
    f = np.array([[0, 1, 2]])
    s = rasterize(uv, f, w, h, texel_samples=k)
    fb = s.is_fallback
    assert fb.sum() > (10 if k == 1 else 0)  # with K = 4 some jittered points do land
    assert np.all(s.coverage.ravel()[np.unique(s.texel)] > 0)
    assert np.all((s.bary[fb] >= 0) & (s.bary[fb] <= 1))
    np.testing.assert_allclose(s.bary[fb].sum(1), 1.0)
    # the point is within half a texel diagonal of its texel's centre
    p = sample_uv(uv, f, s)[fb]
    d = (p - centre_uv(s.texel[fb], w, h)) * [w, h]
    assert np.all(np.hypot(d[:, 0], d[:, 1]) <= np.sqrt(0.5) + 1e-9)
    # one sample per fallback texel, and its coverage is > 0 but below 1/K
    assert len(np.unique(s.texel[fb])) == fb.sum()
    cov = s.coverage.ravel()[s.texel[fb]]
    assert np.all(cov == texels.FALLBACK_COVERAGE_FRACTION / k)
    s1 = rasterize(uv, f, w, h, texel_samples=1)
    assert s1.is_fallback.all()  # K = 1: every sample is a fallback here


def test_every_overlapped_texel_gets_a_sample():
    rng = np.random.default_rng(5)
    uv = rng.random((60, 2))
    faces = rng.integers(0, 60, (40, 3))
    s = rasterize(uv, faces, 32, 32, texel_samples=2)
    assert np.array_equal(np.unique(s.texel), np.flatnonzero(s.coverage.ravel() > 0))
    assert np.all((s.bary >= -1e-12) & (s.bary <= 1 + 1e-12))


# --- determinism ---------------------------------------------------------------------


def test_same_seed_same_samples_any_chunking_and_threads():
    rng = np.random.default_rng(2)
    uv = rng.random((50, 2))
    faces = rng.integers(0, 50, (60, 3))
    a = rasterize(uv, faces, 40, 30, texel_samples=5, seed=11)
    b = rasterize(uv, faces, 40, 30, texel_samples=5, seed=11, chunk_pairs=97)
    assert_same_samples(a, b)
    b = rasterize(uv, faces, 40, 30, texel_samples=5, seed=11, chunk_pairs=211, threads=2)
    assert_same_samples(a, b)
    c = rasterize(uv, faces, 40, 30, texel_samples=5, seed=12)
    assert not np.array_equal(a.bary, c.bary)


# --- unwrap ---------------------------------------------------------------------------


def chart_labels(n_vertices, faces):
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    graph = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n_vertices, n_vertices))
    return connected_components(graph, directed=False)[1]


def assert_valid_atlas(vertices, faces, un, res, pad):
    assert un.vmapping.dtype == np.int64 and un.faces.dtype == np.int64 and un.uv.dtype == np.float64
    assert un.uv.min() >= 0 and un.uv.max() <= 1
    chk = check_uvs(un.uv, un.faces, res, res)
    assert chk.valid and chk.overlapping_texels == 0 and chk.out_of_range_faces == 0
    # new vertices map back to the original positions, faces in input order
    np.testing.assert_array_equal(vertices[un.vmapping][un.faces], vertices[faces])
    # charts are >= 2 * padding empty texels apart (padding around each chart)
    s = rasterize(un.uv, un.faces, res, res)
    chart = np.full(res * res, -1)
    chart[s.texel] = chart_labels(len(un.uv), un.faces)[un.faces[s.face, 0]]
    chart = chart.reshape(res, res)
    for dr in range(-2 * pad, 2 * pad + 1):
        for dc in range(-2 * pad, 2 * pad + 1):
            a = chart[max(0, dr):res + min(0, dr), max(0, dc):res + min(0, dc)]
            b = chart[max(0, -dr):res + min(0, -dr), max(0, -dc):res + min(0, -dc)]
            assert not np.any((a >= 0) & (b >= 0) & (a != b))
    return s


@pytest.mark.slow
def test_unwrap_icosphere():
    mesh = trimesh.creation.icosphere(subdivisions=3)
    res, pad = 128, 2
    assert_valid_atlas(mesh.vertices, mesh.faces, unwrap(mesh.vertices, mesh.faces, res, pad), res, pad)


@pytest.fixture(scope="module")
def unit_torus_atlas():
    """A 48 x 24 torus at unit size and its 128^2 atlas (shared by the scale cases)."""
    mesh = trimesh.creation.torus(major_radius=1.0, minor_radius=0.4, major_sections=48,
                                  minor_sections=24)
    return mesh, unwrap(mesh.vertices, mesh.faces, 128, 2)


@pytest.mark.slow
@pytest.mark.parametrize("scale, shift", [(1e-4, 0.0), (1e4, 0.0), (1.0, 1e5)])
def test_unwrap_does_not_depend_on_scale_or_position(unit_torus_atlas, scale, shift):
    """xatlas works in float32 with absolute tolerances; unwrap normalises the mesh first, so
    a mesh 1e-4 across or 1e5 from the origin gets the atlas of the same mesh at unit size
    (before: a division by zero, and 2204 collapsed UV triangles)."""
    mesh, ref = unit_torus_atlas
    vertices = mesh.vertices * scale + shift
    un = unwrap(vertices, mesh.faces, 128, 2)
    chk = check_uvs(un.uv, un.faces, 128, 128)
    assert chk.valid and chk.degenerate_faces == 0, chk.message
    np.testing.assert_array_equal(un.faces, ref.faces)
    np.testing.assert_allclose(un.uv, ref.uv, atol=1e-6)


@pytest.mark.slow
def test_unwrap_into_a_non_square_image():
    """xatlas packs square layouts: a W x H atlas uses the top-left min(W, H) square, on the
    texel grid of the W x H image, with the usual padding."""
    mesh = trimesh.creation.icosphere(subdivisions=2)
    w, h, pad = 96, 48, 2
    un = unwrap(mesh.vertices, mesh.faces, (w, h), pad)
    chk = check_uvs(un.uv, un.faces, w, h)
    assert chk.valid and chk.overlapping_texels == 0
    s = rasterize(un.uv, un.faces, w, h)
    rows, cols = np.divmod(s.texel, w)
    assert cols.max() < h  # inside the 48 x 48 square
    assert max(rows.max(), cols.max()) >= 0.8 * h  # the layout's longer side fills the square
    np.testing.assert_array_equal(mesh.vertices[un.vmapping][un.faces], mesh.vertices[mesh.faces])


@pytest.mark.slow
def test_unwrap_large_mesh_in_parts():
    """Above charts.PART_FACES triangles the mesh is charted in spatial parts with capped
    chart areas: still one valid, padded, deterministic atlas that uses the image."""
    mesh = trimesh.creation.torus(major_radius=1.0, minor_radius=0.35, major_sections=180,
                                  minor_sections=130)
    rng = np.random.default_rng(5)
    vertices = mesh.vertices + rng.normal(scale=2e-3, size=mesh.vertices.shape)  # not too regular
    assert len(mesh.faces) > 2 * charts.PART_FACES
    res, pad = 512, 2
    un = unwrap(vertices, mesh.faces, res, pad)
    s = assert_valid_atlas(vertices, mesh.faces, un, res, pad)
    # the packed layout reaches most of the image on both axes (AIM/ACCEPT)
    rows, cols = np.divmod(s.texel, res)
    assert rows.max() >= 0.9 * res and cols.max() >= 0.9 * res
    again = unwrap(vertices, mesh.faces, res, pad)
    for x, y in zip(un, again):
        np.testing.assert_array_equal(x, y)


@pytest.mark.slow
def test_unwrap_v_orientation_matches_xatlas_chart_image():
    # xatlas's v runs down its chart image (row 0 first); unwrap flips it to
    # OBJ's v-up so that our row r is xatlas's row r.
    mesh = trimesh.creation.icosphere(subdivisions=2)
    # xatlas runs in child processes only (see unwrap._unwrap_isolated: its thread
    # pool can deadlock; a child can be timed out, this test process cannot).
    f, uv_x, image = _xatlas_chart_image_in_child(mesh.vertices, mesh.faces, 64, 1)
    un = unwrap(mesh.vertices, mesh.faces, 64, 1)
    np.testing.assert_allclose(un.uv[:, 1], 1.0 - uv_x[:, 1])
    charts = image.sum(axis=-1) > 0
    ours = rasterize(un.uv, un.faces, 64, 64).coverage > 0
    assert np.all(charts[ours])
    unflipped = rasterize(uv_x, f, 64, 64).coverage > 0
    assert not np.all(charts[unflipped])


def _xatlas_chart_image_in_child(positions, faces, resolution, padding):
    """unwrap._xatlas_atlas(..., chart_image=True) in a child process with a time limit."""
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    code = ("import sys, numpy as np; from aobake.targets.texels import unwrap; d = np.load(sys.argv[1]);"
            "vm, f, uv, img, _ = unwrap._xatlas_atlas(d['p'], d['f'], int(d['r']), int(d['pad']),"
            " chart_image=True); np.savez(sys.argv[2], f=f, uv=uv, img=img)")
    root = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp, "in.npz"), Path(tmp, "out.npz")
        np.savez(src, p=positions, f=faces, r=resolution, pad=padding)
        for _ in range(2):
            try:
                subprocess.run([sys.executable, "-c", code, str(src), str(dst)], cwd=root,
                               check=True, timeout=120)
                break
            except subprocess.TimeoutExpired:
                continue
        with np.load(dst) as data:
            return data["f"], data["uv"], data["img"]


@pytest.mark.slow
def test_unwrap_is_deterministic():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    a = unwrap(mesh.vertices, mesh.faces, 64, 1)
    b = unwrap(mesh.vertices, mesh.faces, 64, 1)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def _stand_in(monkeypatch, **code):
    """The unwrap's child code swapped for a stand-in: ``code`` (a new child's) and/or
    ``warm`` (a prestarted child's)."""
    monkeypatch.setattr(unwrapping, "WORKER", unwrapping.WORKER._replace(**code))


@pytest.mark.slow
def test_unwrap_timeout_retries_then_fails(monkeypatch):
    _stand_in(monkeypatch, code="import time; time.sleep(30)")
    monkeypatch.setattr(unwrapping, "XATLAS_TIMEOUT_BASE_S", 0.5)
    monkeypatch.setattr(unwrapping, "XATLAS_TIMEOUT_PER_FACE_S", 0.0)
    mesh = trimesh.creation.box()
    with pytest.raises(InputError, match="did not finish"):
        unwrap(mesh.vertices, mesh.faces, 64, 1)


def test_unwrap_crash_becomes_input_error(monkeypatch):
    _stand_in(monkeypatch, code="import os, signal; os.kill(os.getpid(), signal.SIGSEGV)")
    mesh = trimesh.creation.box()
    with pytest.raises(InputError, match="SIGSEGV"):
        unwrap(mesh.vertices, mesh.faces, 32, 1)


@pytest.mark.slow
def test_prestarted_child_takes_the_unwrap():
    """The CLI starts the xatlas child before reading the mesh; the unwrap hands it its job
    (the same atlas as a child started then), and it is gone afterwards."""
    mesh = trimesh.creation.box()
    fresh = unwrap(mesh.vertices, mesh.faces, 64, 1)
    unwrapping.prestart()
    child = children.waiting(unwrapping.WORKER)
    assert child is not None and child.poll() is None
    warm = unwrap(mesh.vertices, mesh.faces, 64, 1)
    assert children.waiting(unwrapping.WORKER) is None and child.poll() is not None
    assert warm.uv.tobytes() == fresh.uv.tobytes() and (warm.faces == fresh.faces).all()


@pytest.mark.slow
def test_prestarted_child_discarded_or_failing(monkeypatch):
    """discard_prestarted ends the waiting child; a prestarted child that fails hands the
    job to a new one (its failure says nothing about the mesh), and when that one crashes
    too, the crash is reported; an exception while the child works ends it."""
    unwrapping.prestart()
    child = children.waiting(unwrapping.WORKER)
    unwrapping.discard_prestarted()
    assert child.poll() is not None and children.waiting(unwrapping.WORKER) is None
    unwrapping.discard_prestarted()  # nothing to end: no error
    mesh = trimesh.creation.box()
    crash = "import os, signal, sys; sys.stdin.readline(); os.kill(os.getpid(), signal.SIGSEGV)"
    _stand_in(monkeypatch, warm=crash)  # crashes once given its job
    unwrapping.prestart()
    assert unwrap(mesh.vertices, mesh.faces, 32, 1).charts > 0  # a new child did it
    _stand_in(monkeypatch, code="import os, signal; os.kill(os.getpid(), signal.SIGSEGV)")
    unwrapping.prestart()
    with pytest.raises(InputError, match="SIGSEGV"):
        unwrap(mesh.vertices, mesh.faces, 32, 1)
    _stand_in(monkeypatch, warm="import sys, time; sys.stdin.readline(); time.sleep(60)")
    unwrapping.prestart()
    child = children.waiting(unwrapping.WORKER)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(child, "communicate", interrupted)
    with pytest.raises(KeyboardInterrupt):
        unwrap(mesh.vertices, mesh.faces, 32, 1)
    assert child.wait(timeout=10) is not None  # killed, not left running


# --- surface points and splatting -------------------------------------------------


def test_surface_points_on_a_plane():
    positions = np.array([[0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0]], float)
    normals = np.tile([0.0, 0.0, 1.0], (4, 1))
    normals[2] = [0.0, 0.0, -1.0]  # a flipped vertex normal
    s = rasterize(QUAD_UV, QUAD_FACES, 8, 4)
    pts, n, fn = surface_points(positions, normals, QUAD_FACES, s)
    uvs = centre_uv(s.texel, 8, 4)
    np.testing.assert_allclose(pts[:, :2], uvs * [2, 1], atol=1e-12)
    np.testing.assert_allclose(fn, np.tile([0, 0, 1.0], (len(fn), 1)))
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    assert np.all(n @ [0, 0, 1.0] > 0)  # flipped/zero interpolations fall back to the face normal
    _, n_flat, _ = surface_points(positions, None, QUAD_FACES, s)
    np.testing.assert_allclose(n_flat, fn)


def test_splat_means_per_texel():
    s = rasterize(QUAD_UV, QUAD_FACES, 4, 2, texel_samples=4)
    vals = np.stack([s.sample.astype(float), np.ones(s.n_samples)], 1)
    img = splat(s, vals)
    assert img.shape == (2, 4, 2)
    np.testing.assert_allclose(img[..., 0], 1.5)  # mean of 0..3
    np.testing.assert_allclose(img[..., 1], 1.0)
    assert splat(s, vals[:, 0]).shape == (2, 4, 1)
    with pytest.raises(ValueError):
        splat(s, vals, width=5)


# --- dilation ------------------------------------------------------------------------


def chebyshev_distance_to(mask):
    rr, cc = np.nonzero(mask)
    h, w = mask.shape
    r, c = np.mgrid[:h, :w]
    return np.min(np.maximum(np.abs(r[..., None] - rr), np.abs(c[..., None] - cc)), axis=-1)


@pytest.mark.parametrize("padding", [1, 2, 5])
def test_dilate_fills_rings_and_keeps_covered_texels(padding):
    rng = np.random.default_rng(4)
    mask = np.zeros((24, 30), bool)
    mask[5:9, 6:12] = True
    mask[15, 20] = True
    image = rng.random((24, 30, 3))
    out, filled = post.dilate(image, mask, padding)
    np.testing.assert_array_equal(out[mask], image[mask])
    dist = chebyshev_distance_to(mask)
    np.testing.assert_array_equal(filled, dist <= padding)
    np.testing.assert_array_equal(out[~filled], image[~filled])
    assert np.all(out[filled] >= image[mask].min(0)) and np.all(out[filled] <= image[mask].max(0))


def test_dilate_constant_and_zero_padding():
    mask = np.zeros((10, 10), bool)
    mask[3:5, 4] = True
    image = np.where(mask[..., None], 0.25, np.nan) * np.ones((1, 1, 2))
    out, filled = post.dilate(image, mask, 3)
    np.testing.assert_array_equal(out[filled], 0.25)
    same, same_mask = post.dilate(image, mask, 0)
    assert same is image and np.array_equal(same_mask, mask)


# --- tangents -------------------------------------------------------------------------


def plane_mesh(mirror=False):
    grid = np.stack(np.meshgrid(np.linspace(0, 1, 4), np.linspace(0, 1, 3)), -1).reshape(-1, 2)
    positions = np.c_[grid * [2.0, 1.0], np.zeros(len(grid))]
    uv = grid.copy()
    if mirror:
        uv[:, 0] = 1 - uv[:, 0]
    faces = Delaunay(grid).simplices
    # wind every face counter-clockwise seen from +z
    p = positions[faces]
    flip = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 2] < 0
    faces[flip] = faces[flip][:, ::-1]
    normals = np.tile([0.0, 0.0, 1.0], (len(grid), 1))
    return positions, normals, uv, faces


def test_tangents_on_flat_plane():
    positions, normals, uv, faces = plane_mesh()
    t = tangents.vertex_tangents(positions, normals, uv, faces)
    np.testing.assert_allclose(t, np.tile([1.0, 0, 0, 1.0], (len(t), 1)), atol=1e-12)
    tm = tangents.vertex_tangents(*plane_mesh(mirror=True))
    np.testing.assert_allclose(tm, np.tile([-1.0, 0, 0, -1.0], (len(t), 1)), atol=1e-12)


def test_tangent_space_round_trip_is_orthonormal():
    rng = np.random.default_rng(6)
    n = rng.normal(size=(200, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t = np.c_[rng.normal(size=(200, 3)), np.where(rng.random(200) < 0.5, -1.0, 1.0)]
    v = rng.normal(size=(200, 3))
    local = tangents.to_tangent_space(v, n, t)
    np.testing.assert_allclose(np.linalg.norm(local, axis=1), np.linalg.norm(v, axis=1))
    np.testing.assert_allclose(tangents.from_tangent_space(local, n, t), v, atol=1e-12)
    np.testing.assert_allclose(tangents.to_tangent_space(n, n, t), np.tile([0, 0, 1.0], (200, 1)), atol=1e-12)
    basis = [tangents.to_tangent_space(np.tile(e, (200, 1)), n, t) for e in np.eye(3)]
    m = np.stack(basis, axis=2)  # (s, 3, 3) rotation per sample
    np.testing.assert_allclose(np.einsum("sij,skj->sik", m, m), np.tile(np.eye(3), (200, 1, 1)), atol=1e-12)
    # handedness: det = w
    np.testing.assert_allclose(np.linalg.det(m), t[:, 3], atol=1e-12)


@pytest.mark.slow
def test_tangents_on_unwrapped_sphere_are_perpendicular_and_unit():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    un = unwrap(mesh.vertices, mesh.faces, 64, 1)
    pos = mesh.vertices[un.vmapping]
    nrm = mesh.vertex_normals[un.vmapping]
    t = tangents.vertex_tangents(pos, nrm, un.uv, un.faces)
    np.testing.assert_allclose(np.linalg.norm(t[:, :3], axis=1), 1.0)
    assert np.max(np.abs(np.sum(t[:, :3] * nrm, axis=1))) < 1e-9
    assert set(np.unique(t[:, 3])) <= {-1.0, 1.0}


@pytest.mark.slow
def test_compiled_rasteriser_equals_numpy_rasteriser_bit_for_bit(kernel):
    """aobake._kernels.raster_rows does _raster_chunk's tests and _nearest_on_triangle's
    fallback operation for operation, and emits the samples in the order the numpy path
    sorts them into, for any pieces and threads (signed zeros included: bytes compared)."""
    rng = np.random.default_rng(9)
    fields = ("texel", "face", "bary", "sample", "is_fallback", "coverage", "shared")
    for trial in range(40):
        n = int(rng.integers(3, 60))
        uv = rng.random((n, 2)) * rng.choice([1.0, 1.3])
        if trial % 4 == 0:
            uv = np.round(uv * 8) / 8  # vertices and edges exactly on texel boundaries
        faces = rng.integers(0, n, (int(rng.integers(1, 70)), 3))
        k = int(rng.integers(1, 10))  # squares (grid) and non-squares (lattice)
        w, h = (int(x) for x in rng.integers(1, 40, 2))
        a = rasterize(uv, faces, w, h, k, trial, compiled=True,
                      chunk_pairs=int(rng.integers(7, 500)), threads=int(rng.integers(1, 4)))
        b = rasterize(uv, faces, w, h, k, trial, compiled=False)
        for name in fields:
            x, y = getattr(a, name), getattr(b, name)
            assert x.dtype == y.dtype and x.shape == y.shape, (trial, name)
            assert x.tobytes() == y.tobytes(), (trial, name)


@pytest.mark.slow
def test_compiled_rasteriser_on_an_atlas_equals_numpy(kernel):
    """Many triangles per row and per texel (an unwrapped sphere, shells overlapping
    where it is mirrored): the row kernel's order is the numpy path's."""
    mesh = trimesh.creation.icosphere(subdivisions=3)
    un = unwrap(mesh.vertices, mesh.faces, 96, 1)
    uv = np.concatenate([un.uv, un.uv[:, ::-1]])  # a second, overlapping shell
    faces = np.concatenate([un.faces, un.faces + len(un.uv)])
    for k, threads, pairs in ((4, 2, 300), (1, 1, 1 << 16), (5, 3, 50)):
        a = rasterize(uv, faces, 96, 80, k, 3, compiled=True, threads=threads, chunk_pairs=pairs)
        b = rasterize(uv, faces, 96, 80, k, 3, compiled=False)
        assert a.is_fallback.any() and (a.shared >= 2).any()
        for name in ("texel", "face", "bary", "sample", "is_fallback", "coverage", "shared"):
            assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), (k, name)


@pytest.mark.slow
def test_compiled_surface_points_equal_numpy_bit_for_bit(kernel, monkeypatch):
    """aobake._kernels.surface_interp interpolates and normalises as the numpy formulation,
    operation for operation: points and shading normals (zero, flipped and turned-face
    normals included) are the same bits, for any threads, with and without vertex normals."""
    mesh = trimesh.creation.icosphere(subdivisions=2)
    rng = np.random.default_rng(4)
    vertices = mesh.vertices * rng.uniform(0.5, 2.0, (len(mesh.vertices), 1)) + 1e3
    normals = mesh.vertex_normals * rng.uniform(0.0, 3.0, (len(mesh.vertices), 1))
    normals[::7] = 0.0  # zero normals: the face's
    normals[::11] *= -1.0  # against the face
    faces = mesh.faces.copy()
    faces[::9] = faces[::9, ::-1]  # turned against their vertex normals
    un = unwrap(vertices, faces, 64, 1)
    samples = rasterize(un.uv, un.faces, 64, 64, 3, 1)
    for vertex_normals in (normals, None):
        reference = surface_points(vertices, vertex_normals, faces, samples)
        monkeypatch.setattr("aobake.targets.texels.surface._SURFACE_BLOCK", 97)  # many blocks
        for threads in (1, 3):
            fast = surface_points(vertices, vertex_normals, faces, samples, threads, kernel)
            for a, b in zip(fast, reference):
                np.testing.assert_array_equal(a, b)
        monkeypatch.undo()


@pytest.mark.parametrize("spans", [(1,), (5,), (40000,), (7, 3), (35947, 40000), (3, 1, 9),
                                   (2 ** 40, 2 ** 30)])
def test_split_corners_is_numpy_unique_along_rows(spans):
    """The packed 1-D unique gives np.unique(axis=0)'s keys and inverse, also where the
    packing would overflow (the row-wise fallback) and for indices that are never used."""
    from aobake.targets.texels.atlas import split_corners

    rng = np.random.default_rng(len(spans) * 1000 + spans[0] % 997)
    columns = [rng.integers(0, span, (500, 3)) for span in spans]
    keys, faces = split_corners(*columns)
    want_keys, inverse = np.unique(np.stack([c.reshape(-1) for c in columns], axis=1), axis=0,
                                   return_inverse=True)
    assert np.array_equal(keys, want_keys)
    assert np.array_equal(faces, inverse.reshape(-1, 3))
    assert keys.dtype == np.int64 and faces.dtype == np.int64
