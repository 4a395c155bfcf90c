"""Alpha-cutout occluders (``--alpha-cutout``): glTF materials with alphaMode MASK let rays
through where the base colour's alpha is below alphaCutoff.

The scene (a glTF written here, PNG textures embedded): an opaque floor and, at height
HEIGHT over it, a square plate with a checkerboard alpha texture of 1-texel squares.
Sampled bilinearly, such a checker's alpha is 1/2 exactly on the texel edges, so at the
cutoff 1/2 the opaque part is exactly the checker's opaque squares (``test_bilinear_...``).

* with the option, a floor point's AO is 1 - sum of Lambert's form factors of the opaque
  squares (about half the plate's), within a Bonferroni bound of the reported stderr;
* without it, the plate occludes fully: AO = 1 - the plate's form factor;
* a texture opaque in its top half occludes with the plate's half the top row maps to (glTF
  UVs: v = 0 at the image's top), and a base-colour factor alpha below the cutoff cuts the
  whole face out;
* the cut-out bake is bit-identical for threads and executors; primary rays (a view) pass
  cut-out texels too.
"""

from __future__ import annotations

import numpy as np
import pytest

import aobake
from aobake.backends.cutout import bilinear
from analytic import dof_for, polygon_form_factor, polygon_form_factors, z_bound
from gltf_scenes import png, write_gltf

FWER = 1e-4
THREADS = 2
#: the plate: half-width HALF at HEIGHT, a CHECKER x CHECKER texel checkerboard over it
HALF, HEIGHT, CHECKER = 1.0, 0.5, 32
RAYS = 4096


def square(half, z, down=False):
    """(vertices, faces, uv) of a square [-half, half]^2 at height z; glTF UVs: u along x,
    v = 0 at y = +half (the image's top row over the +y edge)."""
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    uv = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    return v, faces[:, ::-1] if down else faces, uv


def checker() -> np.ndarray:
    """(CHECKER, CHECKER) uint8 alpha: 255 where row + column is even (row 0 = image top)."""
    i, j = np.indices((CHECKER, CHECKER))
    return np.where((i + j) % 2 == 0, 255, 0).astype(np.uint8)


def scene_file(tmp_path, alpha=None, factor=(1, 1, 1, 1), cutoff=0.5, name="scene.gltf"):
    fv, ff, fuv = square(3.0, 0.0)
    pv, pf, puv = square(HALF, HEIGHT, down=True)
    plate = {"alphaMode": "MASK", "factor": list(factor)}
    if cutoff is not None:
        plate["alphaCutoff"] = cutoff
    if alpha is not None:
        plate["png"] = png(alpha)
    return write_gltf(tmp_path / name, [
        dict(vertices=fv, faces=ff, uv=fuv, material={"alphaMode": "OPAQUE"}),
        dict(vertices=pv, faces=pf, uv=puv, material=plate)])


def floor_points():
    g = np.linspace(-0.35, 0.35, 3)
    x, y = np.meshgrid(g, g + 0.05)
    points = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    return points, np.tile([0.0, 0.0, 1.0], (len(points), 1))


def opaque_squares(alpha: np.ndarray) -> list:
    """The plate's squares (4 corners each) under opaque texels (row 0 at y = +HALF)."""
    n = alpha.shape[0]
    size = 2 * HALF / n
    out = []
    for row, col in zip(*np.nonzero(alpha >= 128)):
        x0, y1 = -HALF + col * size, HALF - row * size
        out.append(np.array([[x0, y1 - size, HEIGHT], [x0 + size, y1 - size, HEIGHT],
                             [x0 + size, y1, HEIGHT], [x0, y1, HEIGHT]]))
    return out


def exact_ao(points, normals, polygons) -> np.ndarray:
    return 1.0 - sum(polygon_form_factors(points, normals, p) for p in polygons)


def bake(path, **options):
    points, normals = floor_points()
    return aobake.bake_points(path, points, normals, rays=RAYS, threads=THREADS, **options)


def within_error(result, exact, tests):
    k = z_bound(tests, dof_for("sobol", RAYS), FWER)
    error = np.abs(result.ao - exact)
    assert (error <= k * result.ao_stderr).all(), (error / result.ao_stderr).max()


def test_bilinear_checker_is_the_checker_at_one_half():
    alpha = checker().astype(np.float64) / 255.0
    rng = np.random.default_rng(0)
    uv = rng.random((20000, 2))
    col = np.floor(uv[:, 0] * CHECKER).astype(int)
    row = np.floor((1.0 - uv[:, 1]) * CHECKER).astype(int)
    looked = bilinear(alpha, uv)
    np.testing.assert_array_equal(looked >= 0.5, alpha[row, col] >= 0.5)


@pytest.mark.slow
def test_a_checker_plate_occludes_its_opaque_squares_exactly(tmp_path):
    path = scene_file(tmp_path, checker())
    points, normals = floor_points()
    result = bake(path, alpha_cutout=True)
    squares = opaque_squares(checker())
    exact = exact_ao(points, normals, squares)
    full = exact_ao(points, normals, [square(HALF, HEIGHT)[0]])
    # about half the plate's cosine-weighted measure, not the plate's, not nothing
    np.testing.assert_allclose(1 - exact, (1 - full) / 2, rtol=0.05)
    within_error(result, exact, 2 * len(points))
    assert result.report["parameters"]["alpha_cutout"]["faces"] == 2
    plain = bake(path)
    within_error(plain, full, 2 * len(points))
    assert "alpha_cutout" not in plain.report["parameters"]


@pytest.mark.slow
def test_uv_orientation_and_the_factor_alpha(tmp_path):
    top = np.zeros((8, 8), dtype=np.uint8)
    top[:4] = 255  # the image's top half: over the plate's +y half
    points, normals = floor_points()
    half = np.array([[-HALF, 0.0, HEIGHT], [HALF, 0.0, HEIGHT], [HALF, HALF, HEIGHT],
                     [-HALF, HALF, HEIGHT]])
    result = bake(scene_file(tmp_path, top, cutoff=None, name="top.gltf"), alpha_cutout=True)
    within_error(result, exact_ao(points, normals, [half]), 2 * len(points))
    # no texture, factor alpha 0.4 < 0.5: the plate is cut out entirely (AO 1 exactly)
    clear = bake(scene_file(tmp_path, None, factor=(1, 1, 1, 0.4), name="clear.gltf"),
                 alpha_cutout=True)
    assert (clear.ao == 1.0).all()


@pytest.mark.slow
def test_bit_identical_for_threads_and_executors(tmp_path):
    path = scene_file(tmp_path, checker())
    points, normals = floor_points()
    one = aobake.bake_points(path, points, normals, rays=256, alpha_cutout=True, threads=1,
                             quantities=("ao", "obscurance"))
    for options in ({"threads": 2, "chunk_rays": 300},
                    {"executor": "processes", "workers": 2, "chunk_points": 4}):
        other = aobake.bake_points(path, points, normals, rays=256, alpha_cutout=True,
                                   quantities=("ao", "obscurance"), **options)
        for name in ("ao", "obscurance", "ao_stderr"):
            np.testing.assert_array_equal(getattr(other, name), getattr(one, name))


@pytest.mark.slow
def test_primary_rays_pass_cut_out_texels_and_bad_setups_are_said(tmp_path):
    path = scene_file(tmp_path, checker())
    view = aobake.bake_view(path, look={"look_from": (0.0, 0.0, 3.0),
                                        "look_at": (0.0, 0.0, 0.0)},
                            size=(64, 64), fov=20.0, rays=4, alpha_cutout=True, threads=THREADS)
    depth = view.channels["depth"][view.covered]  # 3 - 0.5 on the plate, 3 on the floor
    # the plate covers the view: about half its pixels see the floor through it
    assert 0.3 < np.mean(depth > 3 - HEIGHT / 2) < 0.7
    plain = aobake.bake_view(path, look={"look_from": (0.0, 0.0, 3.0),
                                         "look_at": (0.0, 0.0, 0.0)},
                             size=(64, 64), fov=20.0, rays=4, threads=THREADS)
    assert (plain.channels["depth"][plain.covered] < 3 - HEIGHT / 2).all()
    with pytest.raises(aobake.InputError, match="--alpha-cutout"):
        aobake.bake_points(path, *floor_points(), rays=4, alpha_cutout=True, method="discs")


def test_cage_rays_land_on_opaque_texels_only(tmp_path):
    """High-to-low: a cage ray meets the alpha-tested plate where its texel is opaque (the
    checker's squares) and passes to the floor where it is cut out; without the option it
    lands on the plate everywhere.  Rays straight down through each texel's centre, from
    above the plate to a low point between plate and floor."""
    from aobake.settings import BakeConfig
    from aobake.occluders import build
    from aobake.scene import load_scene
    from aobake.targets.projected_cage import project

    scene = load_scene(scene_file(tmp_path, checker()))
    size = 2 * HALF / CHECKER
    row, col = np.indices((CHECKER, CHECKER)).reshape(2, -1)
    x, y = -HALF + (col + 0.5) * size, HALF - (row + 0.5) * size  # row 0 at y = +HALF
    low = np.column_stack([x, y, np.full(x.size, HEIGHT / 2)])
    cage = low + [0.0, 0.0, HEIGHT]
    opaque = checker()[row, col] >= 128
    plate = np.isclose(scene.vertices[scene.faces].mean(axis=1)[:, 2], HEIGHT)
    for cut in (True, False):
        projection = project(build(scene, BakeConfig(alpha_cutout=cut)), scene, low, cage)
        assert projection.hit.all()
        on_plate = plate[projection.faces]
        expected = opaque if cut else np.ones_like(opaque)
        np.testing.assert_array_equal(on_plate, expected)
        np.testing.assert_allclose(projection.points[:, 2], np.where(expected, HEIGHT, 0.0),
                                   atol=1e-6)


@pytest.mark.parametrize("front", [False, True])
def test_compiled_march_is_the_numpy_march(tmp_path, front):
    """The cut-out pass in C (aobake._embree's march: each ray's layers in one loop) gives the
    numpy march's bits: the same t and face for every ray, through up to three stacked
    plates (checkers of different sizes, one facing up, a noise alpha with factor 0.8 and
    cutoff 0.3), on rays in every direction, some ending inside the stack."""
    from aobake.settings import BakeConfig
    from aobake.occluders import build
    from aobake.scene import load_scene

    rng = np.random.default_rng(7)
    parts = []
    for k, (z, down, alpha, factor, cutoff) in enumerate((
            (0.2, True, checker(), 1.0, 0.5),
            (0.5, False, np.kron(checker()[:8, :8], np.ones((3, 3), np.uint8)), 1.0, 0.5),
            (0.8, True, (rng.random((17, 23)) * 255).astype(np.uint8), 0.8, 0.3))):
        v, f, uv = square(HALF, z, down=down)
        parts.append(dict(vertices=v, faces=f, uv=uv * (1.0 + k),  # UVs beyond 1: repeat
                          material={"alphaMode": "MASK", "factor": [1, 1, 1, factor],
                                    "alphaCutoff": cutoff, "png": png(alpha)}))
    scene = load_scene(write_gltf(tmp_path / "stack.gltf", parts))
    occluders = build(scene, BakeConfig(alpha_cutout=True))
    cutout = occluders.cutout
    if cutout.backend.native_scene() is None:
        pytest.skip("aobake._embree was not built")
    n = 20000
    origins = np.column_stack([rng.uniform(-1.2, 1.2, (n, 2)), rng.uniform(-0.5, 1.5, n)])
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    local = occluders.to_local(origins).astype(np.float32)
    tmax = (rng.uniform(0.05, 3.0, n) * occluders.scale).astype(np.float32)
    compiled = cutout.march(local, directions.astype(np.float32), tmax, front=front)
    reference = cutout.march(local, directions.astype(np.float32), tmax, front=front,
                             compiled=False)
    np.testing.assert_array_equal(compiled[0], reference[0])
    np.testing.assert_array_equal(compiled[1], reference[1])
    hit = reference[1] >= 0
    assert 0.05 < hit.mean() < 0.95 and np.isinf(reference[0][~hit]).any()
    # many rays passed a cut-out texel first: their face is not the first face they meet
    t_first, first = cutout.backend.intersect(local, directions.astype(np.float32), tmax)
    passed = (first >= 0) & (first != reference[1])
    assert passed.mean() > 0.1 and (hit & passed).any()
