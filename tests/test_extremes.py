"""Numerical extremes: scales, far-from-origin scenes, thin gaps, degenerate input,
tau and max distance at 0 and infinity, a single ray."""

import math

import numpy as np
import pytest
import trimesh

import aobake
from analytic import dof_for, floor_and_ceiling, polygon_form_factor, up, z_bound


def ceiling_scene():
    return floor_and_ceiling(1.0, 3)


@pytest.mark.parametrize("scale, shift", [(1e-4, 0.0), (1e4, 0.0), (1.0, 1e5), (1e-3, 1e5)])
def test_scaled_and_translated_scene_gives_same_ao(scale, shift):
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.0], [2.9, 0.0, 0.0], [0, 0, 1.0]])
    nrm = np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0], [0, 0, -1.0]])
    opts = dict(rays=256, max_distance="40%", sampler="random", quantities=("ao", "obscurance"))
    base = aobake.bake_points(ceiling_scene(), pts, nrm, **opts)
    moved = ceiling_scene()
    moved.apply_scale(scale)
    moved.apply_translation([shift, shift, shift])
    tau = base.report["parameters"]["tau"] / scale
    res = aobake.bake_points(moved, pts * scale + shift, nrm, tau=tau, **opts)
    k = z_bound(len(pts), None)
    for name in ("ao", "obscurance"):
        a, b = getattr(base, name), getattr(res, name)
        se = np.hypot(getattr(base, name + "_stderr"), getattr(res, name + "_stderr"))
        assert np.all(np.abs(a - b) <= k * se + 0.0), (name, a, b)
    # Query points have no triangles: their offset is 64 float32 ulps of their coordinates,
    # which follow the scale up to the power-of-two steps of the float32 grid.
    ratio = res.report["parameters"]["ray_offset"] / (base.report["parameters"]["ray_offset"] * scale)
    assert 0.5 <= ratio <= 2.0, ratio


@pytest.mark.slow
@pytest.mark.parametrize("scale, shift", [(1e-4, 0.0), (1.0, 1e5)])
def test_scaled_and_translated_lightmap_gives_same_texels(scale, shift):
    """A fresh atlas and its texels do not depend on units or position: the same texels are
    covered and every texel's AO agrees within the two reported errors."""
    torus = trimesh.creation.torus(major_radius=1.0, minor_radius=0.4, major_sections=32,
                                   minor_sections=16)
    floor = trimesh.creation.box(extents=[4, 4, 0.1])
    floor.apply_translation([0, 0, -0.45])
    scene = trimesh.util.concatenate([torus, floor])
    opts = dict(rays=32, resolution=64, padding=1, sampler="random")
    base = aobake.bake_texels(scene, **opts)
    moved = scene.copy()
    moved.vertices = moved.vertices * scale + shift
    res = aobake.bake_texels(moved, **opts)
    np.testing.assert_array_equal(res.covered, base.covered)
    both = res.covered
    se = np.hypot(res.channels["ao_stderr"], base.channels["ao_stderr"])[both]
    diff = np.abs(res.channels["ao"] - base.channels["ao"])[both]
    # (where both errors are 0 -- every ray of the texel hit, or every one escaped -- allow
    # the change one ray can make: 1 / rays per texel)
    assert np.all(diff <= np.maximum(z_bound(int(both.sum()), None) * se, 1.0 / opts["rays"]))


def test_thin_gap_neither_leaks_nor_self_shadows():
    size, gap = 1.0, 1e-3  # gap is 1e-3 of the scene size
    thickness = 0.01
    lower = trimesh.creation.box(extents=[size, size, thickness])
    lower.apply_translation([0, 0, -thickness / 2])
    upper = trimesh.creation.box(extents=[size, size, thickness])
    upper.apply_translation([0, 0, gap + thickness / 2])
    mesh = trimesh.util.concatenate([lower, upper])
    # Inside the gap, facing up (lower plate) and down (upper plate): exact form factor
    # of the upper plate's underside seen from the point.
    half = size / 2
    corners = np.array([[-half, -half, gap], [half, -half, gap], [half, half, gap], [-half, half, gap]])
    inside = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 0.0]])
    exact = np.array([1 - polygon_form_factor(p, [0, 0, 1], corners) for p in inside])
    # Outer faces: nothing above the upper plate's top, nothing below the lower plate's bottom.
    outer = np.array([[0.0, 0.0, gap + thickness], [0.1, 0.1, -thickness]])
    pts = np.vstack([inside, inside + [0, 0, gap], outer])
    nrm = np.array([[0, 0, 1.0]] * 2 + [[0, 0, -1.0]] * 2 + [[0, 0, 1.0], [0, 0, -1.0]])
    res = aobake.bake_points(mesh, pts, nrm, rays=512, sampler="random")
    k = z_bound(4, dof_for("random", 512))
    # No leak: AO in the gap is the tiny exact opening, within k stderr (stderr 0 means all occluded).
    assert np.all(np.abs(res.ao[:4] - np.tile(exact, 2)) <= k * res.ao_stderr[:4] + np.tile(exact, 2))
    assert np.all(res.ao[:4] < 0.01)
    # No self-shadowing: the outer faces are fully open, exactly.
    assert np.all(res.ao[4:] == 1.0)


def test_degenerate_duplicate_and_unreferenced_input():
    box = trimesh.creation.box()
    v = np.vstack([box.vertices, [[5, 5, 5], [6, 6, 6]]])  # two unreferenced vertices
    f = np.vstack([box.faces, box.faces[:3],  # duplicate faces
                   [[0, 0, 1], [2, 2, 2], [0, 1, 0]]])  # zero-area triangles
    # collinear (zero-area) triangle with distinct vertices:
    v = np.vstack([v, [[0, 0, 0], [1, 0, 0], [2, 0, 0]]])
    f = np.vstack([f, [[len(v) - 3, len(v) - 2, len(v) - 1]]])
    res = aobake.bake(trimesh.Trimesh(v, f, process=False), rays=16,
                      quantities=("ao", "obscurance", "bent-normal"))
    for name, array in res.fields().items():
        assert np.isfinite(array).all(), name
    unref = [8, 9]
    assert np.all(res.rays[unref] == 0)
    assert np.all(res.ao[unref] == 0.5) and np.all(res.ao_stderr[unref] == 0.5)
    assert any("no defined normal" in w for w in res.report["warnings"])
    assert res.report["scene"]["degenerate_triangles"] >= 4


def _under_ceiling(**opts):
    pts = np.array([[0.0, 0.0, 0.0], [0.5, 0.5, 0.0]])
    nrm = up(2)
    return aobake.bake_points(ceiling_scene(), pts, nrm, quantities=("ao", "obscurance"),
                              sampler="random", **opts)


def test_tau_zero_gives_ao_and_tau_inf_gives_one():
    zero = _under_ceiling(rays=64, tau=0.0, max_distance=math.inf)
    assert np.array_equal(zero.obscurance, zero.ao)  # rho = 0 for hits, 1 for misses
    inf = _under_ceiling(rays=64, tau=math.inf, max_distance=math.inf)
    assert np.all(inf.obscurance == 1.0) and np.all(inf.obscurance_stderr == 0)
    assert np.all(inf.ao < 1.0)


@pytest.mark.parametrize("d", [0.0, 1e-12], ids=["zero", "tiny"])
def test_max_distance_zero_or_tiny_sees_nothing(d):
    res = _under_ceiling(rays=32, max_distance=d)
    assert np.all(res.ao == 1.0) and np.all(res.obscurance == 1.0)


def test_max_distance_inf_inside_a_box():
    box = trimesh.creation.box(extents=[1, 1, 1])
    res = aobake.bake_points(box, [[0, 0, 0]], [[0, 0, 1.0]], rays=32, max_distance="inf",
                             quantities=("ao", "obscurance"))
    assert res.ao[0] == 0.0 and 0 < res.obscurance[0] < 1


def test_single_ray(sampler):
    res = _under_ceiling(rays=1, max_distance=math.inf)
    assert np.isfinite(res.ao).all() and np.isfinite(res.ao_stderr).all()
    assert np.all(res.rays == 1)
    # No spread to measure from one ray: the worst-case bound 1 / (2 sqrt(1)).
    assert np.all(res.ao_stderr == 0.5)


@pytest.mark.parametrize("scale, shift", [(1e-140, 0.0), (1e-20, 0.0), (1e15, 0.0), (1e140, 0.0),
                                          (1.0, 1e12), (1e-30, 1e-20)])
def test_extreme_scales_bake_the_same_ao(scale, shift):
    """The tracer rescales every scene by a power of two for Embree's float32: any scale the
    float64 input can hold bakes the same AO within the error bars (the audit saw 1e-15 give
    0.34 for 0.48, 1e15 give 1.0 and a 1e12 offset give 0.0 everywhere)."""
    import warnings

    from aobake.scene import make_scene

    mesh = trimesh.util.concatenate([trimesh.creation.icosphere(subdivisions=2),
                                     trimesh.creation.box(extents=[4, 0.2, 4])])
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    base = aobake.bake(make_scene(v, f), rays=64, sampler="random")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # and no numpy warning on the way
        moved = aobake.bake(make_scene(v * scale + shift, f), rays=64, sampler="random")
    se = np.hypot(base.ao_stderr, moved.ao_stderr)
    k = z_bound(len(se), None)
    assert np.all(np.abs(moved.ao - base.ao) <= k * se), np.max(np.abs(moved.ao - base.ao) / se)


@pytest.mark.parametrize("scale", [1e-200, 1e200])
def test_scales_beyond_float64_areas_are_refused_naming_the_limit(scale):
    from aobake.errors import InputError
    from aobake.scene import make_scene

    box = trimesh.creation.box()
    with pytest.raises(InputError, match=r"box\.obj: .*\|coordinates\| <= 1e\+150 and extent >= 1e-150"):
        make_scene(box.vertices * scale, box.faces, source="box.obj")


def test_unreferenced_nan_vertex_is_refused_at_load(tmp_path):
    path = tmp_path / "nan.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0 0\nf 1 2 3\n")
    from aobake.errors import InputError

    with pytest.raises(InputError, match=r"nan\.obj: 1 vertices have NaN"):
        aobake.load_scene(path)
