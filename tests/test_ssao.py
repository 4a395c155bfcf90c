"""Screen-space AO (``aobake.screen``, ``--method crytek | shanmugam | gtao | heightfield``): the
G-buffer they read, their closed forms, the height-field truth, refusals and split
invariance.

Tolerances: G-buffer channels are float32 (relative step 2^-23 at most); where a value is
exact by construction (a flat wall under Crytek's doubled normalisation or Shanmugam's
biased spheres) it is compared exactly; elsewhere the tolerance is derived in the test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

import aobake
from aobake import camera as cameras
from aobake import occluders
from aobake.settings import BakeConfig
from aobake.errors import InputError
from aobake.methods.ssao import (CrytekMethod, GtaoMethod, HeightfieldMethod, ShanmugamMethod)
from aobake.scene import load_scene
from aobake.screen import crytek, gtao, kernels, refine, shanmugam
from aobake.screen.gbuffer import CHANNELS, GBuffer, depth_step
from aobake.settings.screen import GtaoOptions, SsaoOptions
from aobake.targets.view import ViewTarget

from analytic import combine, quad

F32 = 2.0 ** -23
SCREEN = (CrytekMethod, ShanmugamMethod, GtaoMethod)


def _plane_views():
    """A 100 x 100 plane z = 0 seen head-on, at 45 degrees and grazing (about 11 degrees)."""
    mesh = quad([0.0, 0.0, 0.0], 50.0, 50.0)
    for eye in ([0.0, 0.0, 3.0], [0.0, -3.0, 3.0], [0.0, -5.0, 1.0]):
        yield mesh, cameras.look_at(eye, [0.0, 0.0, 0.0], [0.0, 1.0, 1.0], 40, size=(48, 36))


def _synthetic(depth, normals, fov=40.0, near=0.5, far=10.0) -> GBuffer:
    """A G-buffer from (H, W) view depths (inf = nothing) and (H, W, 3) view-space normals."""
    h, w = depth.shape
    cam = cameras.look_at([0, 0, 0], [0, 0, -1], [0, 1, 0], fov, size=(w, h), near=near, far=far)
    covered = np.isfinite(depth)
    channels = {"coverage": covered.astype(np.float32),
                "depth": np.where(covered, depth, 0).astype(np.float32)}
    for convention, name in (("opengl", "hwdepth_gl"), ("d3d", "hwdepth_d3d"),
                             ("reversed", "hwdepth_reversed")):
        channels[name] = cameras.hardware_depth(depth.ravel(), near, far,
                                                convention).reshape(h, w).astype(np.float32)
    for key in ("Ng", "N"):
        for axis, letter in enumerate("XYZ"):
            channels[f"{key}.{letter}"] = np.where(covered, normals[..., axis],
                                                   0).astype(np.float32)
    return GBuffer(channels, cam)


# -- the G-buffer -----------------------------------------------------------------------------

def test_gbuffer_handed_to_methods_equals_the_views_channels_bit_for_bit():
    mesh = combine(quad([0, 0, 0], 2.0, 2.0), trimesh.creation.icosphere(2, 0.5))
    cam = cameras.look_at([1.0, -2.0, 2.0], [0, 0, 0.2], [0, 0, 1], 40, size=(40, 30))
    scene = load_scene(mesh)
    config = BakeConfig(rays=8)
    built = occluders.build(scene, config)
    plan = ViewTarget(cam).sample(scene, config, lambda: built, 1, {}, [])
    result = aobake.bake_view(mesh, camera=cam, rays=8)
    assert plan.image is not None and set(plan.image.channels) == set(CHANNELS)
    for name in CHANNELS:
        np.testing.assert_array_equal(plan.image.channels[name], result.channels[name],
                                      err_msg=name)
    # the view's sample-stream ids are its pixel indices: what the methods read
    np.testing.assert_array_equal(plan.ids, np.flatnonzero(result.covered.ravel()))


@pytest.mark.parametrize("convention", ["opengl", "d3d", "reversed"])
def test_linearised_hardware_depth_equals_the_linear_depth(convention):
    mesh, cam = list(_plane_views())[1]
    image = GBuffer.from_view(aobake.bake_view(mesh, camera=cam, rays=1))
    linear, hard = image.frame("linear"), image.frame(convention)
    np.testing.assert_array_equal(linear.covered, hard.covered)
    d = linear.depth[linear.covered]
    # the linear channel's rounding plus two of the hardware buffer's float32 steps
    tolerance = d * F32 + 2 * depth_step(hard, d)
    assert (np.abs(hard.depth[hard.covered] - d) <= tolerance).all()
    # the hardware depth is coarser far away: its step grows as d^2 (not for reversed-Z)
    if convention != "reversed":
        near, far = hard.camera.near, hard.camera.far
        assert depth_step(hard, np.array([far * 0.9]))[0] > \
            depth_step(hard, np.array([near * 1.1]))[0]


# -- flat walls -----------------------------------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("depth", ["linear", "opengl"])
@pytest.mark.parametrize("method", [CrytekMethod, ShanmugamMethod])
def test_flat_wall_is_exactly_open_for_crytek_doubled_and_shanmugam(method, depth):
    for mesh, cam in _plane_views():
        image = GBuffer.from_view(aobake.bake_view(mesh, camera=cam, rays=1))
        for rotate, blur in ((False, False), (True, True)):
            options = SsaoOptions(ssao_samples=16, ssao_rotate=rotate, ssao_blur=blur,
                                  ssao_depth=depth)
            ao = method(0.4, options).image(image)
            covered = image.frame().covered
            assert (ao[covered] == 1.0).all(), (cam.eye, rotate, blur, ao[covered].min())


def test_flat_wall_crytek_raw_visible_fraction_is_at_least_half():
    for mesh, cam in _plane_views():
        frame = GBuffer.from_view(aobake.bake_view(mesh, camera=cam, rays=1)).frame()
        pixels = np.flatnonzero(frame.covered.ravel())
        visible = crytek.ao(frame, pixels, 0.4, 16, True, 4, "none")
        assert visible.min() >= 0.5
        # and the bias does not hide the wall: head-on, exactly one of each pair is behind
        # wherever the ball's image is on the image (off it, samples count as open)
        if cam.eye[1] == 0.0:
            r, c = np.divmod(pixels, frame.width)
            margin = math.ceil(0.4 / frame.pixel_size(3.0 - 0.4)) + 1
            inner = (r >= margin) & (r < frame.height - margin) & (c >= margin) & \
                (c < frame.width - margin)
            assert inner.sum() > 100 and (visible[inner] == 0.5).all()


@pytest.mark.slow
def test_flat_wall_gtao_gives_its_documented_flat_value():
    for mesh, cam in _plane_views():
        frame = GBuffer.from_view(aobake.bake_view(mesh, camera=cam, rays=1)).frame()
        pixels = np.flatnonzero(frame.covered.ravel())[::7]
        for slices, rotate in ((4, True), (2, False)):
            ao = gtao.ao(frame, pixels, 0.4, slices, 4, 0.615, rotate, 4)
            offset, _ = gtao.offsets(pixels, frame.width, rotate, 4)
            expected = np.array([min(1.0, gtao.flat_value(frame, p, slices, o))
                                 for p, o in zip(pixels, offset)])
            # horizon directions from float32 depths: an angle error of at most a few
            # float32 steps over the nearest sample's distance (1.3 pixels), and
            # |d AO / d h| <= 1/2 per slice
            angle = 4 * F32 * frame.height / (1.3 * 2 * frame.half_height)
            np.testing.assert_allclose(ao, expected, rtol=0, atol=angle)
            if cam.eye[1] == 0.0:  # facing the eye at the centre: every slice gives 1
                centre = (frame.height // 2) * frame.width + frame.width // 2
                assert gtao.ao(frame, np.array([centre]), 0.4, slices, 4, 0.615,
                               rotate, 4)[0] == pytest.approx(1.0, abs=angle)


@pytest.mark.slow
def test_flat_wall_heightfield_truth_is_open():
    for mesh, cam in _plane_views():
        image = GBuffer.from_view(aobake.bake_view(mesh, camera=cam, rays=1))
        for distance in (0.4, math.inf):
            out = HeightfieldMethod(32, distance).image(image)
            assert (out["ao"][image.frame().covered] == 1.0).all()


# -- closed forms ---------------------------------------------------------------------------

@pytest.mark.slow
def test_sphere_term_is_the_small_cap_limit_of_the_exact_occlusion():
    distance = 1.0
    for radius in (0.01, 0.1, 0.3, 0.6):
        for tilt in (0.0, 0.5, 0.9):  # cap wholly above the horizon
            cosine = math.cos(tilt)
            alpha = math.asin(radius / distance)
            assert tilt + alpha < math.pi / 2
            # the exact cosine-weighted occlusion by quadrature over the cap
            beta = np.linspace(0, alpha, 801)
            phi = np.linspace(0, 2 * math.pi, 801)
            bb, pp = np.meshgrid(beta, phi, indexing="ij")
            cos_to_n = math.cos(tilt) * np.cos(bb) - math.sin(tilt) * np.sin(bb) * np.cos(pp)
            integrand = cos_to_n * np.sin(bb) / math.pi
            quadrature = np.trapezoid(np.trapezoid(integrand, phi, axis=1), beta)
            exact = shanmugam.exact_cap(distance, radius, cosine)
            assert quadrature == pytest.approx(exact, rel=1e-5)
            # S_Omega cos / pi exceeds it by exactly 2 / (1 + cos alpha) = 1 + tan^2(alpha/2)
            term = shanmugam.sphere_term(distance, radius, cosine)
            assert term / exact == pytest.approx(1 + math.tan(alpha / 2) ** 2, rel=1e-12)
    assert shanmugam.sphere_term(1.0, 0.1, -0.3) == 0.0  # below the horizon: nothing


def test_shanmugam_one_raised_pixel_casts_exactly_its_sphere():
    h, w, depth, radius, samples = 64, 64, 2.0, 0.3, 16
    normals = np.zeros((h, w, 3))
    normals[..., 2] = 1.0  # a wall facing the eye
    flat = np.full((h, w), depth)
    frame = _synthetic(flat, normals).frame()
    p = np.array([32 * w + 32])
    kernel = kernels.disc_kernel(samples)
    reads = shanmugam.sample_pixels(frame, p, radius, kernel, None, 4)[0]
    assert shanmugam.ao(frame, p, radius, samples, rotate=False)[0] == 1.0
    rise = 0.15
    # the nearest neighbour read (not p itself): its sphere is then wholly above p's horizon
    candidates = [q for q in reads if q != p[0]]
    q = min(candidates, key=lambda q: np.hypot(*np.subtract(divmod(q, w), (32, 32))))
    raised = flat.copy()
    raised.ravel()[q] = depth - rise
    frame = _synthetic(raised, normals).frame()
    # expected: the paper's term for the sphere at q, once per sample that reads q
    pos = frame.positions(p)[0]
    pos_q = frame.positions(np.array([q]))[0]
    r_q = radius * (depth - rise) / depth / math.sqrt(samples)
    centre = pos_q - r_q * np.array([0.0, 0.0, 1.0])
    v = centre - pos
    assert np.linalg.norm(pos_q - pos) <= radius and r_q < np.linalg.norm(v)
    term = 2 * math.pi * (1 - math.cos(math.asin(r_q / np.linalg.norm(v)))) \
        * max(v[2] / np.linalg.norm(v), 0.0) / math.pi
    count = int((reads == q).sum())
    expected = 1.0 - min(1.0, count * term)
    got = shanmugam.ao(frame, p, radius, samples, rotate=False)[0]
    assert 0.0 < expected < 1.0
    # the G-buffer holds float32 depths: relative rounding of the geometry (2^-23) times a
    # few terms
    assert got == pytest.approx(expected, abs=1e-5)


def _crease():
    """A floor z = 0 (y < 1) and a wall y = 1 facing -y, seen into the corner."""
    floor = quad([0.0, -2.0, 0.0], 6.0, 3.0)
    wall = quad([0.0, 1.0, 2.0], 6.0, 2.0, axis_u=0, axis_v=2)
    cam = cameras.look_at([0.4, -2.0, 2.2], [0.0, 1.0, 0.2], [0, 0, 1], 40, size=(192, 144))
    return combine(floor, wall), cam


def _corner_exact(distance, radius):
    """Cosine-weighted AO bounded at ``radius`` of a point at ``distance`` from an infinite
    plane at right angles to its own (the inside of a right-angle corner).  Cosine-weighted
    directions project uniformly onto the unit disc of the point's plane (Malley); one with
    component d_y towards the wall meets it at distance/d_y, within the radius when
    d_y > h = distance/radius: the disc's segment beyond h, of area acos h - h sqrt(1 - h^2),
    is the occluded share times pi."""
    h = np.clip(np.asarray(distance, dtype=np.float64) / radius, 0.0, 1.0)
    return 1.0 - (np.arccos(h) - h * np.sqrt(1.0 - h * h)) / np.pi


def _corner_pixels(view, cam, radius):
    """(covered pixels (k,), distance of each hit to the other plane (k,)) of the crease view,
    of the hits at least ``radius`` away from the planes' free edges (the closed form's
    planes are infinite)."""
    pixels = np.flatnonzero(view.covered.ravel())
    p_view = np.stack([view.channels[f"P.{a}"].ravel()[pixels] for a in "XYZ"], axis=1)
    world = p_view.astype(np.float64) @ cam.world_to_view()[:3, :3] + cam.eye
    on_floor = np.abs(world[:, 2]) < np.abs(world[:, 1] - 1.0)
    distance = np.where(on_floor, 1.0 - world[:, 1], world[:, 2])
    inside = (np.abs(world[:, 0]) < 6.0 - radius) & (world[:, 1] > -5.0 + radius) & \
        (world[:, 2] < 4.0 - radius)
    return pixels[inside], distance[inside]


@pytest.mark.slow
def test_inside_a_right_angle_corner_the_bounded_truth_is_the_closed_form():
    mesh, cam = _crease()
    radius, rays = 0.5, 256
    # plain Monte Carlo: each pixel's AO is a binomial share of its rays, of known variance
    view = aobake.bake_view(mesh, camera=cam, rays=rays, max_distance=radius, sampler="random",
                            replicates=2, seed=2)
    pixels, distance = _corner_pixels(view, cam, radius)
    exact = _corner_exact(distance, radius)
    got = view.channels["ao"].ravel()[pixels].astype(np.float64)
    sigma = np.sqrt(exact * (1.0 - exact) / rays)
    near = exact < 1.0
    assert near.sum() > 500 and exact.min() < 0.55  # the corner is in the picture
    # per pixel within 5 sigma (P(|z| > 5) = 6e-7 a pixel), float32 storage aside
    assert (np.abs(got - exact) <= 5 * sigma + 4 * F32).all()
    # and the mean error over the pixels within 5 of its sigma: no bias at the corner
    mean_sigma = math.sqrt(float(np.sum(sigma[near] ** 2))) / near.sum()
    assert abs(float(np.mean(got[near] - exact[near]))) <= 5 * mean_sigma
    # outside the radius nothing is hit: exactly open
    assert (got[~near] == 1.0).all()


@pytest.mark.slow
def test_inside_a_right_angle_corner_gtao_with_a_hard_cut_is_the_closed_form():
    mesh, cam = _crease()
    radius, steps = 0.5, 256
    view = aobake.bake_view(mesh, camera=cam, rays=1)
    frame = GBuffer.from_view(view).frame()
    pixels, distance = _corner_pixels(view, cam, radius)
    # GTAO sees what is on screen: pixels whose ball of radius R projects inside the image
    p_view = frame.positions(pixels)
    world = p_view @ cam.world_to_view()[:3, :3] + cam.eye
    corners = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)])
    image, _ = cam.project((world[:, None, :] + radius * corners[None]).reshape(-1, 3))
    image = image.reshape(len(pixels), len(corners), 2)
    on_screen = ((image >= 0) & (image < [cam.width, cam.height])).all(axis=(1, 2))
    pick = np.flatnonzero(on_screen & (distance > 0.05 * radius) & (distance < radius))[::37]
    got = gtao.ao(frame, pixels[pick], radius, 64, steps, 0.0, False, 4)
    exact = _corner_exact(distance[pick], radius)
    # the horizon found by T steps is low by at most the angle between two samples at the
    # radius (as in the crease test above): 2 x 2 / T; the slice integrand is at most 1
    assert (np.abs(got - exact) <= 2 * 2 / steps).all(), np.abs(got - exact).max()
    assert len(pick) >= 10 and exact.min() < 0.7


@pytest.mark.parametrize("range_check", ["plane", "depth"])
def test_crytek_at_a_crease_counts_the_samples_behind_the_visible_surface(range_check):
    mesh, cam = _crease()
    result = aobake.bake_view(mesh, camera=cam, rays=1)
    frame = GBuffer.from_view(result).frame()
    radius, samples = 0.5, 32
    rotation = cam.world_to_view()[:3, :3]
    eye = cam.eye
    # view-space planes: (normal, a point), the side the normal points to is open
    planes = [(rotation @ [0, 0, 1.0], rotation @ (np.array([0, 0, 0.0]) - eye)),
              (rotation @ [0, -1.0, 0], rotation @ (np.array([0, 1.0, 0]) - eye))]
    crease_image, _ = cam.project(np.array([[-1.0, 1.0, 0.0], [1.0, 1.0, 0.0]]))
    # floor pixels at 0.1 .. 0.4 radius from the wall, on the image's middle column
    world = np.array([[0.0, 1.0 - f * radius, 0.0] for f in (0.1, 0.25, 0.4)])
    pix, _ = cam.project(world)
    pixels = (np.floor(pix[:, 1]).astype(int) * cam.width + np.floor(pix[:, 0]).astype(int))
    visible = crytek.ao(frame, pixels, radius, samples, True, 4, "none", 0, range_check)
    turns = kernels.rotations(4)
    kernel = kernels.sphere_kernel(samples) * radius
    for k, p in enumerate(pixels):
        pos = frame.positions(np.array([p]))[0]
        turn = turns[kernels.pattern_index(np.array([p]), frame.width, 4)[0]]
        s = pos + kernel @ turn.T  # (N, 3) view space
        unit = s / np.linalg.norm(s, axis=1, keepdims=True)
        # the visible surface along the eye's ray through each sample: the nearer hit of
        # the two planes within their halves (floor in front of the wall, wall above the floor)
        t_hit = np.full(len(s), np.inf)
        below = np.zeros(len(s))
        steep = np.zeros(len(s))
        for (n, a), (other_n, other_a) in (planes, planes[::-1]):
            cos = np.abs(unit @ n)
            t = (n @ a) / (unit @ n)
            hit = unit * t[:, None]
            nearer = (t > 0) & ((hit - other_a) @ other_n >= 0) & (t < t_hit)
            t_hit = np.where(nearer, t, t_hit)
            below = np.where(nearer, (a - s) @ n, below)  # depth of s under that plane
            steep = np.maximum(steep, np.sqrt(1 - cos ** 2) / cos)  # tan of either plane
        d_surface = t_hit * -unit[:, 2]  # view depth of the hit
        behind = -s[:, 2] - d_surface
        # the margin: a plane's depth changes by pixel_size x tan(angle to its normal) per
        # pixel; the fetch reads the centre of the pixel (half a pixel in x and y away) and
        # the bias allows as much again; near the crease the fetched pixel may lie on the
        # other plane: the steeper of the two
        margin = 2 * frame.pixel_size(d_surface) * steep
        if range_check == "depth":
            value = np.where((behind > 0) & (behind < radius), 0.0, 1.0)
            unclear = (np.abs(behind) <= margin) | (np.abs(behind - radius) <= margin)
        else:
            value = np.where(behind > 0, np.where(below < radius, 0.0, 0.5), 1.0)
            # within 2 pixels of the crease's image the fetched pixel may be on either plane
            x, y, _ = frame.project(s)
            (x0, y0), (x1, y1) = crease_image
            off = np.abs((x1 - x0) * (y0 - y) - (x0 - x) * (y1 - y0)) / np.hypot(x1 - x0,
                                                                                 y1 - y0)
            unclear = (np.abs(behind) <= margin) | ((off <= 2) & (behind > 0))
        clear = value[~unclear].sum()
        got = samples * visible[k]
        assert clear <= got <= clear + unclear.sum(), (k, got, clear, unclear.sum())
        assert unclear.sum() <= samples // 4  # the test says something
    # nearer the wall, darker
    assert visible[0] < visible[2]


def test_crytek_plane_range_check_gives_the_flat_value_at_any_angle():
    for mesh, cam in _plane_views():
        frame = GBuffer.from_view(aobake.bake_view(mesh, camera=cam, rays=1)).frame()
        pixels = np.flatnonzero(frame.covered.ravel())
        r, c = np.divmod(pixels, frame.width)
        # where the ball's image is on the image (off it, samples count as open)
        x, y, _ = frame.project(frame.positions(pixels)[:, None, :]
                                + 0.4 * kernels.sphere_kernel(16)[None] * 1.01)
        inner = ((x >= 0) & (x < frame.width) & (y >= 0) & (y < frame.height)).all(axis=1)
        # every rotation of the ball: the bounding sphere of the kernel's images
        assert inner.sum() > 50
        for normalise, flat in crytek.FLAT_VALUE.items():
            ao = crytek.ao(frame, pixels, 0.4, 16, False, 4, normalise, 0, "plane")
            assert (ao[inner] == flat).all(), (cam.eye, normalise, np.unique(ao[inner]))


def test_gtao_slice_integral_is_the_cosine_lobe_between_the_horizons():
    for gamma in (-1.0, -0.3, 0.0, 0.7):
        for h1, h2 in ((gamma - math.pi / 2, gamma + math.pi / 2), (-0.4, 0.9), (-1.2, 0.1)):
            theta = np.linspace(h1, h2, 20001)
            quadrature = np.trapezoid(np.cos(theta - gamma) * np.abs(np.sin(theta)), theta)
            assert gtao.slice_integral(h1, h2, gamma, 1.0) == pytest.approx(quadrature,
                                                                             abs=1e-7)


def test_gtao_at_a_crease_matches_the_bounded_truth_within_its_step_spacing():
    mesh, cam = _crease()
    radius = 0.5
    view = aobake.bake_view(mesh, camera=cam, rays=1)
    frame = GBuffer.from_view(view).frame()
    world = np.array([[x, 1.0 - f * radius, 0.0] for f in (0.15, 0.3, 0.6) for x in (-0.2, 0.2)])
    pix, _ = cam.project(world)
    pixels = np.floor(pix[:, 1]).astype(int) * cam.width + np.floor(pix[:, 0]).astype(int)
    # the truth at exactly those pixels' hit points, about their normals
    rotation = cam.world_to_view()[:3, :3]
    points = frame.positions(pixels) @ rotation + cam.eye
    truth = aobake.bake_points(mesh, points, frame.normals_at(pixels) @ rotation, rays=4096,
                               max_distance=radius)
    steps = 256
    got = gtao.ao(frame, pixels, radius, 64, steps, 0.0, False, 4)
    # GTAO with dense slices and a hard cut is the bounded AO of its slices' horizons, and
    # its samples lie on the surfaces in their slices: a horizon is low by at most the angle
    # between two samples at the radius, (2 R_pix / T) pixels at R_pix pixels (the squared
    # distribution's last spacing) times 2 for foreshortening (planes within 60 degrees of
    # facing the eye), and the slice integrand cos(h - g)|sin h| is at most 1
    tolerance = 2 * 2 / steps + 4 * truth.ao_stderr
    assert (np.abs(got - truth.ao) <= tolerance).all(), (got, truth.ao, tolerance)
    assert truth.ao.min() < 0.7 and tolerance.max() < 0.05  # the crease is in range


# -- the height-field truth -----------------------------------------------------------------

@pytest.mark.slow
def test_heightfield_truth_equals_ray_traced_truth_on_a_height_field_scene():
    """A box on a floor seen from straight above, nearly orthographic: the depth buffer is
    the scene (the box's walls are hidden, the box's top edges fall on pixel boundaries).
    From 20 units the floor hidden behind the box's edges (0.013 wide at the foot of a 0.5
    high box) made steep rays hit it early: mean -0.0013, over 4 standard errors; from
    1000 units it is 50 times narrower."""
    size, top = 96, 999.5
    floor = quad([0.0, 0.0, 0.0], 5.0, 5.0)
    box = trimesh.creation.box(extents=(1.0, 1.0, 0.5))
    box.apply_translation([0, 0, 0.25])
    mesh = combine(floor, box)
    # 1/32 of a unit per pixel at the box's top: its edges at +-0.5 on pixel boundaries
    fov = math.degrees(2 * math.atan(size / 2 / 32 / top))
    cam = cameras.look_at([0, 0, top + 0.5], [0, 0, 0], [0, 1, 0], fov, size=(size, size))
    radius = 0.3
    truth = aobake.bake_view(mesh, camera=cam, rays=256, max_distance=radius, seed=3)
    image = GBuffer.from_view(truth)
    height = HeightfieldMethod(256, radius, seed=5).image(image)
    from aobake.screen.score import depth_edges, dilate

    edges = dilate(depth_edges(image.frame()), 2)
    # the pixels either truth sees occluded (elsewhere both are exactly 1), off the edges
    region = truth.covered & ~edges & ((truth.channels["ao"] < 1) | (height["ao"] < 1))
    diff = (height["ao"] - truth.channels["ao"])[region]
    se = np.hypot(height["ao_stderr"], truth.channels["ao_stderr"])[region]
    assert len(diff) > 500 and (truth.channels["ao"][region] < 0.9).sum() > 300
    # the mean difference over independent pixels, against its own standard error
    assert abs(diff.mean()) <= 4 * math.sqrt(np.sum(se ** 2)) / len(diff)
    # and pixel by pixel: the differences have the spread the two stderrs claim (measured
    # 1.05; a stderr on 7 degrees of freedom is itself uncertain, hence the margin)
    z = diff / se
    assert 0.7 < np.sqrt(np.mean(z ** 2)) < 1.4


def test_heightfield_thickness_lets_rays_pass_behind_a_foreground_object():
    """A plate floating high above a floor, seen from above: rays from the floor beside it
    pass behind it (for the depth buffer) but far below it: blocked by the height field
    proper, not by one of thickness below the gap."""
    floor = quad([0.0, 0.0, 0.0], 5.0, 5.0)
    plate = quad([0.0, 0.0, 1.5], 0.5, 0.5)
    cam = cameras.look_at([0.9, 0, 4.0], [0.9, 0, 0], [0, 1, 0], 30, size=(64, 64))
    image = GBuffer.from_view(aobake.bake_view(combine(floor, plate), camera=cam, rays=1))
    frame = image.frame()
    # a floor pixel just beside the plate's image
    pix, _ = cam.project(np.array([[0.5 + 0.5 * 2.5 / 4.0 + 0.1, 0.0, 0.0]]))
    p = int(np.floor(pix[0, 1])) * 64 + int(np.floor(pix[0, 0]))
    assert frame.depth.ravel()[p] == pytest.approx(4.0, rel=1e-3)
    thick = HeightfieldMethod(256, 1.0).estimates(frame, np.array([p])).fields["ao"][0]
    thin = HeightfieldMethod(256, 1.0, thickness=0.5).estimates(
        frame, np.array([p])).fields["ao"][0]
    assert thin == 1.0 and thick < 0.9


# -- the refinements ------------------------------------------------------------------------

def test_rotation_pattern_repeats_every_n_pixels_and_fills_each_window():
    width, period = 37, 4
    r, c = np.meshgrid(np.arange(20), np.arange(width), indexing="ij")
    index = kernels.pattern_index((r * width + c).ravel(), width, period).reshape(r.shape)
    np.testing.assert_array_equal(index[period:], index[:-period])
    np.testing.assert_array_equal(index[:, period:], index[:, :-period])
    for top in range(0, 20 - period):
        for left in range(0, width - period, 5):
            window = index[top:top + period, left:left + period]
            assert len(np.unique(window)) == period * period
    assert (index[:, 1:] != index[:, :-1]).all()  # neighbours never share a rotation


def test_blur_never_mixes_across_a_depth_edge_or_a_crease():
    h, w = 24, 32
    depth = np.full((h, w), 2.0)
    depth[:, w // 2:] = 2.3  # a depth edge down the middle
    normals = np.zeros((h, w, 3))
    normals[..., 2] = 1.0
    normals[h // 2:, : w // 2] = [0.0, math.sin(1.0), math.cos(1.0)]  # a crease (57 deg)
    frame = _synthetic(depth, normals).frame()
    pixels = np.arange(h * w)
    # three surfaces: left above the crease, left below it, right (behind the edge)
    right = np.arange(w) >= w // 2
    region = np.where(right[None, :], 2, (np.arange(h)[:, None] >= h // 2).astype(int))
    raw_values = np.array([0.1, 0.7, 0.4])[region.ravel()]
    out = refine.blurred(frame, pixels, lambda q: raw_values[q], 4, 1.0, 30.0)
    # each keeps its value (a mean of equal values: to rounding)
    np.testing.assert_allclose(out, raw_values, rtol=0, atol=1e-15)
    # and it does average within a region
    noisy = raw_values + 0.01 * ((pixels % 4) - 1.5)
    smooth = refine.blurred(frame, pixels, lambda q: noisy[q], 4, 1.0, 30.0)
    inner = (np.abs(np.subtract.outer(np.arange(h), h // 2)) > 3)[:, None] & \
        (np.abs(np.arange(w) - w // 2) > 3)[None, :] & \
        (np.arange(h) > 2)[:, None] & (np.arange(h) < h - 3)[:, None] & \
        (np.arange(w) > 2)[None, :] & (np.arange(w) < w - 3)[None, :]
    np.testing.assert_allclose(smooth.reshape(h, w)[inner], raw_values.reshape(h, w)[inner],
                               atol=1e-12)


def test_rotation_and_blur_remove_the_kernels_structured_error():
    """On a sphere, unrotated Crytek repeats one kernel's error on every pixel; rotated and
    blurred, neighbouring pixels average N^2 kernels: the image is smoother."""
    mesh = combine(quad([0, 0, 0], 3.0, 3.0), trimesh.creation.icosphere(3, 0.6))
    cam = cameras.look_at([0, -2.5, 2.0], [0, 0, 0.3], [0, 0, 1], 40, size=(96, 72))
    image = GBuffer.from_view(aobake.bake_view(mesh, camera=cam, rays=1))
    frame = image.frame()

    def roughness(options):
        ao = CrytekMethod(0.4, options).image(image)
        both = frame.covered[:, 1:] & frame.covered[:, :-1]
        return np.mean(np.abs(np.diff(ao, axis=1))[both])

    raw = roughness(SsaoOptions(ssao_samples=8, ssao_rotate=True, ssao_blur=False))
    blurred = roughness(SsaoOptions(ssao_samples=8, ssao_rotate=True, ssao_blur=True))
    assert blurred < 0.5 * raw


# -- refusals and bad input -----------------------------------------------------------------

@pytest.mark.parametrize("name", ["crytek", "shanmugam", "gtao", "heightfield"])
def test_refused_on_targets_without_a_g_buffer(name):
    mesh = trimesh.creation.icosphere(1, 1.0)
    with pytest.raises(InputError, match="G-buffer"):
        aobake.bake(mesh, method=name, rays=8, max_distance=1.0)
    with pytest.raises(InputError, match="G-buffer"):
        aobake.bake_points(mesh, [[0, 0, 1.0]], [[0, 0, 1.0]], method=name, rays=8,
                           max_distance=1.0)


def test_bad_settings_are_refused_with_clear_messages():
    for radius in (0, -1.0, "0%", math.inf, "abc"):
        with pytest.raises(InputError, match="radius"):
            SsaoOptions(ssao_radius=radius)
    with pytest.raises(InputError, match="ssao samples"):
        SsaoOptions(ssao_samples=0)
    with pytest.raises(InputError, match="gtao slices"):
        GtaoOptions(gtao_slices=0)
    with pytest.raises(InputError, match="radius"):
        CrytekMethod(0.0)
    assert SsaoOptions(ssao_radius="2.5%").radius(10.0) == pytest.approx(0.25)
    with pytest.raises(InputError, match="ao only"):
        aobake.bake_view(trimesh.creation.icosphere(1, 1.0), method="crytek",
                         quantities=("ao", "obscurance"), size=(8, 8))


# -- split invariance -------------------------------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("name", ["crytek", "shanmugam", "gtao", "heightfield"])
def test_any_split_of_the_pixels_gives_the_same_bits(name):
    mesh = combine(quad([0, 0, 0], 2.0, 2.0), trimesh.creation.icosphere(2, 0.5))
    cam = cameras.look_at([1.0, -2.0, 2.0], [0, 0, 0.2], [0, 0, 1], 40, size=(48, 36))
    kw = dict(camera=cam, method=name, rays=16, max_distance=0.4)
    whole = aobake.bake_view(mesh, **kw)
    cut = aobake.bake_view(mesh, chunk_points=97, **kw)
    threads = aobake.bake_view(mesh, threads=2, **kw)
    for other in (cut, threads):
        np.testing.assert_array_equal(whole.channels["ao"], other.channels["ao"])
    assert whole.report["parameters"]["method"] == name
    if name != "heightfield":
        assert "rays" not in whole.channels and "ao_stderr" not in whole.channels


@pytest.mark.slow
def test_processes_executor_carries_the_g_buffer():
    mesh = combine(quad([0, 0, 0], 2.0, 2.0), trimesh.creation.icosphere(2, 0.5))
    cam = cameras.look_at([1.0, -2.0, 2.0], [0, 0, 0.2], [0, 0, 1], 40, size=(32, 24))
    kw = dict(camera=cam, method="gtao", max_distance=0.4)
    a = aobake.bake_view(mesh, **kw)
    b = aobake.bake_view(mesh, executor="processes", workers=2, chunk_points=150, **kw)
    np.testing.assert_array_equal(a.channels["ao"], b.channels["ao"])
