"""The camera model of ``aobake view`` (aobake/camera.py): rays through pixel centres, the
matrices, depth-buffer conventions, validation, framing, glTF cameras.

Tolerances are float64 rounding, not model slack: coordinates of ~1e3 pixels or ~1e2 scene
units carry a few ulps (~1e-13 relative) per operation, so 1e-9 (pixels, unit vectors) leaves
four decades for accumulation and still fails on any half-pixel or sign mistake.
"""

import json
import math
import struct

import numpy as np
import pytest

from aobake import camera as cam
from aobake.camera import (Camera, default_camera, fit_clip, gltf_camera, gltf_cameras,
                           hardware_depth, linear_depth, linearize_depth, look_at, parse_size,
                           parse_vector)
from aobake.errors import InputError

ATOL = 1e-9  # float64 rounding on pixel coordinates and unit vectors (module docstring)


def matrix_pixels(camera, points):
    """Pixel coordinates via the matrices: clip = P @ V @ [p, 1], NDC = clip / w, NDC y up,
    row 0 at the top; and the NDC z."""
    homogeneous = np.c_[points, np.ones(len(points))]
    clip = homogeneous @ (camera.view_to_clip() @ camera.world_to_view()).T
    ndc = clip[:, :3] / clip[:, 3:]
    x = (ndc[:, 0] + 1.0) / 2.0 * camera.width
    y = (1.0 - ndc[:, 1]) / 2.0 * camera.height
    return np.c_[x, y], ndc[:, 2]


def pixel_centres(camera):
    """(H*W, 2) float64 (c + 0.5, r + 0.5) in row-major order, built independently."""
    rows, cols = np.mgrid[0:camera.height, 0:camera.width]
    return np.c_[cols.ravel() + 0.5, rows.ravel() + 0.5]


@pytest.fixture
def axis_camera():
    """At the origin, looking down -Z, +Y up, 90 degrees vertical, 5 x 3 pixels (odd sizes:
    a centre pixel exists; aspect 5/3 tells vertical from horizontal fov)."""
    return look_at([0, 0, 0], [0, 0, -7], [0, 3, 0], 90.0, (5, 3), near=0.5, far=50.0)


def test_axis_camera_matrices_are_identity_and_opengl(axis_camera):
    np.testing.assert_allclose(axis_camera.world_to_view(), np.eye(4), atol=ATOL)
    clip = axis_camera.view_to_clip()
    # tan(45 deg) = 1: focal 1 vertically, 1 / aspect horizontally; z row of gluPerspective.
    np.testing.assert_allclose(clip[0, 0], 3 / 5, rtol=1e-12)
    np.testing.assert_allclose(clip[1, 1], 1.0, rtol=1e-12)
    np.testing.assert_allclose(clip[2, 2:], [-50.5 / 49.5, -50.0 / 49.5], rtol=1e-12)
    np.testing.assert_array_equal(clip[3], [0, 0, -1, 0])


def test_axis_camera_rays(axis_camera):
    origins, directions = axis_camera.pixel_rays()
    assert origins.shape == directions.shape == (15, 3)
    assert origins.dtype == directions.dtype == np.float64
    np.testing.assert_array_equal(origins, 0.0)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=ATOL)
    # Centre pixel (row 1, col 2) looks straight down -Z.
    np.testing.assert_allclose(directions[1 * 5 + 2], [0, 0, -1], atol=ATOL)
    # Corner pixel centres: NDC x = +-(1 - 1/5), y = +-(1 - 1/3); view x scales by
    # aspect * tan(45) = 5/3, y by tan(45) = 1.  Row 0 is the top (+Y), column 0 the left (-X).
    x, y = (1 - 1 / 5) * 5 / 3, 1 - 1 / 3
    for (row, col), (sx, sy) in {(0, 0): (-1, 1), (0, 4): (1, 1), (2, 0): (-1, -1),
                                 (2, 4): (1, -1)}.items():
        want = np.array([sx * x, sy * y, -1.0])
        np.testing.assert_allclose(directions[row * 5 + col], want / np.linalg.norm(want),
                                   atol=ATOL, err_msg=f"pixel ({row}, {col})")


def test_axis_camera_fov_is_vertical_and_edges_land_on_image_edges(axis_camera):
    # 45 degrees up = top edge (y = 0) at mid-width; 45 * aspect in tangent = right edge.
    points = np.array([[0, 1, -1], [0, -1, -1], [5 / 3, 0, -1], [-5 / 3, 1, -1]]) * 4.0
    pixels, depth = axis_camera.project(points)
    np.testing.assert_allclose(pixels, [[2.5, 0], [2.5, 3], [5, 1.5], [0, 0]], atol=ATOL)
    np.testing.assert_allclose(depth, 4.0, atol=ATOL)
    # Behind the eye: no pixel, negative depth.
    pixels, depth = axis_camera.project([[0, 0, 2.0]])
    assert np.isnan(pixels).all() and depth[0] == -2.0


def test_rays_project_back_to_pixel_centres(axis_camera):
    origins, directions = axis_camera.pixel_rays()
    points = origins + 3.0 * directions
    want = pixel_centres(axis_camera)
    pixels, depth = axis_camera.project(points)
    np.testing.assert_allclose(pixels, want, atol=ATOL)
    np.testing.assert_allclose(depth, 3.0 * -directions[:, 2], atol=ATOL)
    np.testing.assert_allclose(matrix_pixels(axis_camera, points)[0], want, atol=ATOL)


def random_camera(seed=1):
    rng = np.random.default_rng(seed)
    eye = rng.uniform(-20, 20, 3)
    target = rng.uniform(-20, 20, 3)
    return look_at(eye, target, rng.normal(size=3), 37.0, (320, 200), near=0.1, far=200.0), rng


def test_random_camera_is_rigid_and_right_handed():
    camera, _ = random_camera()
    view = camera.world_to_view()
    rotation = view[:3, :3]
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=ATOL)
    assert np.linalg.det(rotation) == pytest.approx(1.0, abs=ATOL)
    np.testing.assert_array_equal(view[3], [0, 0, 0, 1])
    np.testing.assert_allclose(view @ np.r_[camera.eye, 1], [0, 0, 0, 1], atol=ATOL)
    distance = np.linalg.norm(camera.target - camera.eye)
    np.testing.assert_allclose(view @ np.r_[camera.target, 1], [0, 0, -distance, 1], atol=ATOL)
    np.testing.assert_allclose(rotation @ camera.up, [0, 1, 0], atol=ATOL)
    assert abs(np.dot(camera.up, camera.forward)) < ATOL


def test_random_camera_projection_agrees_with_matrices():
    camera, rng = random_camera()
    origins, directions = camera.pixel_rays()
    assert directions.shape == (64000, 3)
    pick = rng.choice(len(directions), 500, replace=False)
    points = origins[pick] + rng.uniform(0.5, 150.0, (500, 1)) * directions[pick]
    want = pixel_centres(camera)[pick]
    pixels, depth = camera.project(points)
    np.testing.assert_allclose(pixels, want, atol=ATOL)
    matrix, ndc_z = matrix_pixels(camera, points)
    np.testing.assert_allclose(matrix, want, atol=ATOL)
    # Any world point in front: project() and the matrices agree; NDC z is hardware_depth.
    points = camera.eye + rng.uniform(-1, 1, (500, 3)) * 10 + 20 * camera.forward
    pixels, depth = camera.project(points)
    assert (depth > 0).all()
    matrix, ndc_z = matrix_pixels(camera, points)
    np.testing.assert_allclose(pixels, matrix, atol=ATOL)
    np.testing.assert_allclose(ndc_z, hardware_depth(depth, 0.1, 200.0, "opengl"), atol=ATOL)


NEAR, FAR = 0.25, 400.0


@pytest.mark.parametrize("convention, at_near, at_far", [
    ("opengl", -1.0, 1.0), ("d3d", 0.0, 1.0), ("reversed", 1.0, 0.0)])
def test_hardware_depth_ends_and_cleared_value(convention, at_near, at_far):
    values = hardware_depth([NEAR, FAR, np.inf, np.nan], NEAR, FAR, convention)
    np.testing.assert_allclose(values[:2], [at_near, at_far], atol=1e-12)
    np.testing.assert_array_equal(values[2:], [at_far, at_far])  # cleared buffer, exactly


def test_hardware_depth_matches_the_projection_matrices():
    depth = np.geomspace(NEAR / 2, FAR * 2, 101)
    view = np.c_[np.zeros((101, 2)), -depth, np.ones(101)]
    camera = look_at([0, 0, 0], [0, 0, -1], [0, 1, 0], 60.0, (4, 4), near=NEAR, far=FAR)
    clip = view @ camera.view_to_clip().T
    np.testing.assert_allclose(hardware_depth(depth, NEAR, FAR, "opengl"),
                               clip[:, 2] / clip[:, 3], rtol=0, atol=1e-12)

    def d3d(n, f):  # XMMatrixPerspectiveFovRH's z row; w = -z_view
        z = -depth * f / (n - f) + n * f / (n - f)
        return z / depth

    np.testing.assert_allclose(hardware_depth(depth, NEAR, FAR, "d3d"), d3d(NEAR, FAR),
                               atol=1e-12)
    np.testing.assert_allclose(hardware_depth(depth, NEAR, FAR, "reversed"), d3d(FAR, NEAR),
                               atol=1e-12)
    # Monotonic: increasing for opengl/d3d, decreasing for reversed-Z.
    assert (np.diff(hardware_depth(depth, NEAR, FAR, "d3d")) > 0).all()
    assert (np.diff(hardware_depth(depth, NEAR, FAR, "reversed")) < 0).all()


@pytest.mark.parametrize("convention", cam.DEPTH_CONVENTIONS)
def test_linearize_depth_inverts_hardware_depth(convention):
    depth = np.geomspace(NEAR, FAR, 57)
    back = linearize_depth(hardware_depth(depth, NEAR, FAR, convention), NEAR, FAR, convention)
    # Conditioning: near far, z moves by ~n/d^2 per unit depth, so an ulp of z is ~1e-13
    # relative in depth at FAR / NEAR = 1600.
    np.testing.assert_allclose(back, depth, rtol=1e-9)
    cleared = hardware_depth([np.inf], NEAR, FAR, convention)
    np.testing.assert_allclose(linearize_depth(cleared, NEAR, FAR, convention), [FAR],
                               rtol=1e-12)


def test_linear_depth_and_depth_errors():
    np.testing.assert_array_equal(linear_depth([-2.0, 3.0]), [2.0, -3.0])
    with pytest.raises(InputError, match="convention"):
        hardware_depth([1.0], NEAR, FAR, "vulkan")
    with pytest.raises(InputError, match="positive"):
        hardware_depth([1.0, -1.0], NEAR, FAR, "opengl")
    with pytest.raises(InputError, match="near < far"):
        linearize_depth([0.5], FAR, NEAR, "d3d")


GOOD = dict(look_from=[0, 0, 5], look_at=[0, 0, 0], up=[0, 1, 0], fov_y=45.0, size=(64, 48))


@pytest.mark.parametrize("change, message", [
    (dict(look_at=[0, 0, 5]), "look-from equals look-at"),
    (dict(up=[0, 0, 2]), "up .* parallel to the view direction"),
    (dict(up=[0, 0, -1e-3]), "parallel"),
    (dict(up=[0, 0, 0]), "up vector is zero"),
    (dict(look_from=[0, np.nan, 5]), "look-from must be finite"),
    (dict(look_at=[np.inf, 0, 0]), "look-at must be finite"),
    (dict(up=[0, 1]), "up must be 3 numbers"),
    (dict(fov_y=0.0), r"fov_y must be in \(0, 180\)"),
    (dict(fov_y=180.0), r"fov_y must be in \(0, 180\)"),
    (dict(fov_y=-10.0), r"fov_y must be in \(0, 180\)"),
    (dict(fov_y=float("nan")), r"fov_y must be in \(0, 180\)"),
    (dict(size=(0, 48)), "positive integers"),
    (dict(size=(64.0, 48)), "positive integers"),
    (dict(size=(20000, 8)), "exceeds 16384 pixels per side"),
    (dict(size=(16384, 8192)), "exceeds 2\\^26"),
    (dict(near=2.0, far=1.0), r"near \(2.0\) must be less than far"),
    (dict(near=0.0), "near must be positive"),
])
def test_bad_cameras_raise_input_error(change, message):
    with pytest.raises(InputError, match=message):
        look_at(**{**GOOD, **change})


def test_good_camera_orthogonalises_up_and_is_immutable():
    camera = look_at(**{**GOOD, "up": [0, 2, 1]})
    np.testing.assert_allclose(camera.up, [0, 1, 0], atol=ATOL)
    with pytest.raises(ValueError):
        camera.eye[0] = 1.0
    record = json.loads(json.dumps(camera.record()))
    assert record["view_to_clip"] is None and record["near"] is None
    assert record["matrix_layout"] == "row-major, column vectors (v = M @ [p, 1])"
    assert record["pixel_centre"] == "+0.5" and record["image_origin"].startswith("top-left")
    np.testing.assert_allclose(record["world_to_view"], camera.world_to_view(), atol=0)
    with pytest.raises(InputError, match="near/far"):
        camera.view_to_clip()


@pytest.mark.parametrize("text", ["1920", "0x10", "axb", "-5x3", "20000x10", "1920x1080x3",
                                  "1920.5x1080", ""])
def test_bad_size_strings(text):
    with pytest.raises(InputError, match="size"):
        parse_size(text)


@pytest.mark.parametrize("text", ["1,2", "1,2,3,4", "a,b,c", "1,2,nan", "1;2;3", ""])
def test_bad_vector_strings(text):
    with pytest.raises(InputError, match="vector"):
        parse_vector(text)


def test_parsers_accept_good_text():
    assert parse_size(" 1920X1080 ") == (1920, 1080)
    np.testing.assert_array_equal(parse_vector("1, -2.5,3e2"), [1.0, -2.5, 300.0])


@pytest.mark.parametrize("up_axis", ["x", "y", "z"])
@pytest.mark.parametrize("size", [(960, 540), (300, 800)])
def test_default_camera_frames_the_box(up_axis, size):
    lo, hi = np.array([-3.0, 10.0, 2.0]), np.array([5.0, 11.0, 30.0])
    camera = default_camera(lo, hi, size=size, up_axis=up_axis)
    assert (camera.width, camera.height) == size
    corners = cam._corners(lo, hi)
    pixels, depth = camera.project(corners)
    assert (pixels[:, 0] > 0).all() and (pixels[:, 0] < size[0]).all(), pixels
    assert (pixels[:, 1] > 0).all() and (pixels[:, 1] < size[1]).all(), pixels
    assert (depth > camera.near).all() and (depth < camera.far).all()
    # The box centre is at the image centre, and the up axis points up in the image.
    axis = np.eye(3)["xyz".index(up_axis)]
    centre = (lo + hi) / 2
    pixels, _ = camera.project(np.stack([centre, centre + axis]))
    np.testing.assert_allclose(pixels[0], [size[0] / 2, size[1] / 2], atol=ATOL)
    assert pixels[1, 1] < pixels[0, 1]
    # Three-quarter view from above: the eye is on the up side of the centre.
    assert np.dot(camera.eye - centre, axis) > 0
    # Tight framing: the corners reach 1/1.05 of the half-width or half-height (the
    # bisection stops within 0.1% of the distance), and a nearer eye on the same line
    # (0.998 of the distance) would put a corner past that margin.
    def reach(c):
        pix, _ = c.project(corners)
        return max(np.abs(pix[:, 0] / size[0] * 2 - 1).max(),
                   np.abs(pix[:, 1] / size[1] * 2 - 1).max())

    assert 0.99 / 1.05 < reach(camera) <= 1 / 1.05
    closer = cam.look_at(centre + 0.998 * (camera.eye - centre), centre, camera.up,
                         camera.fov_y, size)
    assert reach(closer) > 1 / 1.05


def test_fit_clip_rule():
    camera = look_at([0, 0, 10], [0, 0, 0], [0, 1, 0], 50.0, (8, 8))
    fitted = fit_clip(camera, [-1, -1, -1], [1, 1, 1])  # corner depths 9 .. 11
    assert fitted.near == pytest.approx(0.99 * 9) and fitted.far == pytest.approx(1.01 * 11)
    inside = fit_clip(camera, [-1, -1, -1], [1, 1, 20])  # eye inside: depths -10 .. 11
    assert inside.far == pytest.approx(1.01 * 11)
    assert inside.near == pytest.approx(1.01 * 11 * 1e-4)
    behind = fit_clip(camera, [-1, -1, 20], [1, 1, 30])  # wholly behind: farthest corner
    assert behind.far == pytest.approx(1.01 * math.sqrt(2 + 400))
    assert 0 < behind.near < behind.far
    with pytest.raises(InputError, match="exceeds high"):
        fit_clip(camera, [1, 0, 0], [0, 1, 1])


# ---- glTF ------------------------------------------------------------------------------

def quaternion(axis, degrees):
    """[x, y, z, w] rotating by ``degrees`` about unit ``axis``."""
    half = math.radians(degrees) / 2
    return [*(np.array(axis, float) * math.sin(half)).tolist(), math.cos(half)]


def gltf_document():
    """A camera two levels down:
    root (matrix, column-major: translate (1, 2, 3)) -> arm (rotate 90 about +Y)
    -> "rig" node (translate (0, 0, 5), rotate 90 about +X) with the perspective camera "main";
    also an unnamed camera on node "side" and an orthographic camera "ortho".
    In the arm's frame the rig's eye is (0, 0, 5), its -Z looks along R_x(90)(0, 0, -1) =
    (0, 1, 0) and its +Y is R_x(90)(0, 1, 0) = (0, 0, 1); R_y(90) takes (x, y, z) to
    (z, y, -x): eye (5, 0, 0) + (1, 2, 3) = (6, 2, 3), forward (0, 1, 0), up (1, 0, 0).
    """
    root = np.eye(4)
    root[:3, 3] = [1, 2, 3]
    return {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 3]}],
        "nodes": [
            {"name": "root", "matrix": root.T.ravel().tolist(), "children": [1]},
            {"name": "arm", "rotation": quaternion([0, 1, 0], 90), "children": [2]},
            {"name": "rig", "camera": 0, "translation": [0, 0, 5],
             "rotation": quaternion([1, 0, 0], 90)},
            {"name": "side", "camera": 1, "translation": [0, 0, 9]},
            {"name": "top", "camera": 2},
        ],
        "cameras": [
            {"name": "main", "type": "perspective",
             "perspective": {"yfov": 0.7, "aspectRatio": 1.5, "znear": 0.05, "zfar": 80.0}},
            {"type": "perspective", "perspective": {"yfov": 1.0, "znear": 0.1}},
            {"name": "ortho", "type": "orthographic",
             "orthographic": {"xmag": 1, "ymag": 1, "znear": 0.1, "zfar": 10}},
        ],
    }


def glb_bytes(document):
    """A GLB container: 12-byte header, then the JSON chunk padded with spaces to 4 bytes."""
    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)
    chunk = struct.pack("<II", len(text), 0x4E4F534A) + text
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunk)) + chunk


@pytest.fixture(params=["gltf", "glb"])
def gltf_file(request, tmp_path):
    path = tmp_path / f"scene.{request.param}"
    if request.param == "gltf":
        path.write_text(json.dumps(gltf_document()))
    else:
        path.write_bytes(glb_bytes(gltf_document()))
    return path


def test_gltf_camera_pose_through_parents(gltf_file):
    assert list(gltf_cameras(gltf_file)) == ["main", "side", "ortho"]
    camera = gltf_camera(gltf_file)
    assert camera.name == "main"
    np.testing.assert_allclose(camera.eye, [6, 2, 3], atol=ATOL)
    np.testing.assert_allclose(camera.forward, [0, 1, 0], atol=ATOL)
    np.testing.assert_allclose(camera.up, [1, 0, 0], atol=ATOL)
    assert camera.fov_y == pytest.approx(math.degrees(0.7), rel=1e-12)
    assert (camera.width, camera.height) == (810, 540)  # 540 x aspectRatio 1.5
    assert (camera.near, camera.far) == (0.05, 80.0)
    # A point straight ahead projects to the image centre.
    pixels, depth = camera.project([[6, 12, 3]])
    np.testing.assert_allclose(pixels, [[405, 270]], atol=ATOL)
    assert depth[0] == pytest.approx(10.0)


def test_gltf_unnamed_camera_takes_node_name_and_size(gltf_file):
    camera = gltf_camera(gltf_file, "side", size=(100, 50))
    np.testing.assert_allclose(camera.eye, [0, 0, 9], atol=ATOL)
    np.testing.assert_allclose(camera.forward, [0, 0, -1], atol=ATOL)
    assert (camera.width, camera.height, camera.far) == (100, 50, None)


def test_gltf_bad_requests(gltf_file):
    with pytest.raises(InputError, match="no camera named 'nope'; available: 'main', 'side'"):
        gltf_camera(gltf_file, "nope")
    with pytest.raises(InputError, match="orthographic cameras are not supported"):
        gltf_camera(gltf_file, "ortho")


def test_gltf_bad_files(tmp_path):
    good = glb_bytes(gltf_document())
    cases = {
        "truncated.glb": (good[:-10], "truncated GLB"),
        "stub.glb": (good[:8], "truncated GLB"),
        "magic.glb": (b"glTX" + good[4:], "not a GLB"),
        "version.glb": (good[:4] + struct.pack("<I", 1) + good[8:], "version 1"),
        "chunk.glb": (good[:16] + b"BIN\x00" + good[20:], "not JSON"),
        "json.gltf": (b"{not json", "glTF JSON is not valid JSON"),
        "empty.gltf": (json.dumps({"asset": {"version": "2.0"}}).encode(), "no cameras"),
    }
    for name, (data, message) in cases.items():
        path = tmp_path / name
        path.write_bytes(data)
        with pytest.raises(InputError, match=message) as error:
            gltf_camera(path)
        assert name in str(error.value), error.value
    with pytest.raises(InputError, match="cannot read"):
        gltf_camera(tmp_path / "missing.gltf")


def test_gltf_camera_parameter_errors(tmp_path):
    document = gltf_document()
    document["cameras"][0]["perspective"]["yfov"] = -1
    path = tmp_path / "fov.gltf"
    path.write_text(json.dumps(document))
    with pytest.raises(InputError, match="yfov must be a positive number"):
        gltf_camera(path)
    document = gltf_document()
    document["cameras"][0]["perspective"]["yfov"] = 3.5  # > pi: a fov over 180 degrees
    path.write_text(json.dumps(document))
    with pytest.raises(InputError, match=r"fov.gltf: camera 'main': camera: fov_y"):
        gltf_camera(path)
    document = gltf_document()
    document["nodes"][2]["children"] = [0]  # a cycle root -> arm -> rig -> root
    path.write_text(json.dumps(document))
    with pytest.raises(InputError, match="two parents|own ancestor"):
        gltf_cameras(path)
