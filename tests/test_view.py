"""``aobake view``: the G-buffer's conventions on generated scenes, the per-pixel truth, its
intervals, and bad cameras.

Tolerances: G-buffer channels are float32 (relative rounding 2^-24 of the value; a few
ulps where a value is computed through a rotation); AO values are compared bit for bit
with ``bake_points`` at the same points and ids.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats

import aobake
from aobake import camera as cameras
from aobake import occluders
from aobake.settings import BakeConfig
from aobake.scene import load_scene
from aobake.targets.view import ViewTarget

from analytic import combine, floor_and_ceiling, polygon_form_factors, quad
from conftest import run_cli

#: float32 relative rounding, with room for a rotation's few float64 roundings before it
F32 = 4 * 2.0 ** -24


def _plane_view(depth=3.0, size=(64, 48), fov=40.0):
    """A large square at z = 0 facing +z, seen straight down from z = depth."""
    mesh = quad([0.0, 0.0, 0.0], 50.0, 50.0)
    cam = cameras.look_at([0.0, 0.0, depth], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], fov, size=size)
    return mesh, cam


def test_plane_reads_back_depth_distance_normals_and_hardware_depth():
    depth = 3.0
    mesh, cam = _plane_view(depth)
    result = aobake.bake_view(mesh, camera=cam, rays=8)
    ch = result.channels
    assert result.covered.all() and (ch["coverage"] == 1).all()
    np.testing.assert_allclose(ch["depth"], depth, rtol=F32)
    np.testing.assert_allclose(ch["P.Z"], -depth, rtol=F32)
    _, directions = cam.pixel_rays()
    forward = cam.forward
    cos = (directions @ forward).reshape(cam.height, cam.width)
    np.testing.assert_allclose(ch["distance"], depth / cos, rtol=F32)
    for key in ("Ng", "N"):  # the plane faces the eye: view-space +Z
        np.testing.assert_allclose(ch[f"{key}.Z"], 1.0, rtol=F32)
        np.testing.assert_allclose(ch[f"{key}.X"], 0.0, atol=F32)
        np.testing.assert_allclose(ch[f"{key}.Y"], 0.0, atol=F32)
    # hardware depth: the OpenGL projection's z / w, and its D3D and reversed forms
    near, far = cam_near_far = result.camera.near, result.camera.far
    assert cam_near_far == (result.report["camera"]["near"], result.report["camera"]["far"])
    clip = result.camera.view_to_clip() @ np.array([0.0, 0.0, -depth, 1.0])
    z_gl = clip[2] / clip[3]
    np.testing.assert_allclose(ch["hwdepth_gl"], z_gl, rtol=F32, atol=F32)
    np.testing.assert_allclose(ch["hwdepth_d3d"], (z_gl + 1) / 2, rtol=F32, atol=F32)
    d3d_reversed = near * (far - depth) / (depth * (far - near))  # near -> 1, far -> 0
    np.testing.assert_allclose(ch["hwdepth_reversed"], d3d_reversed, rtol=1e-5, atol=F32)
    assert (ch["object_id"] == 0).all() and set(np.unique(ch["primitive_id"])) == {0.0, 1.0}
    # the open plane: AO 1 exactly (every ray escapes)
    assert (ch["ao"] == 1).all()


def test_a_world_point_lands_on_the_pixel_the_matrices_say():
    mesh, _ = _plane_view()
    cam = cameras.look_at([1.5, -2.0, 4.0], [0.2, 0.3, 0.0], [0.0, 0.0, 1.0], 55.0,
                          size=(80, 50))
    result = aobake.bake_view(mesh, camera=cam, rays=1)
    ch = result.channels
    rec = result.report["camera"]
    world_to_view = np.array(rec["world_to_view"])
    view_to_clip = np.array(rec["view_to_clip"])
    rows, cols = np.nonzero(result.covered)
    pick = np.linspace(0, len(rows) - 1, 25).astype(int)
    for r, c in zip(rows[pick], cols[pick]):
        p_view = np.array([ch["P.X"][r, c], ch["P.Y"][r, c], ch["P.Z"][r, c], 1.0])
        world = np.linalg.solve(world_to_view, p_view)
        assert abs(world[2]) < 1e-5  # on the plane z = 0
        clip = view_to_clip @ world_to_view @ world
        ndc = clip[:3] / clip[3]
        x = (ndc[0] + 1) / 2 * rec["width"]
        y = (1 - ndc[1]) / 2 * rec["height"]
        # the pixel centre, up to the float32 rounding of P (a tiny fraction of a pixel)
        assert abs(x - (c + 0.5)) < 1e-3 and abs(y - (r + 0.5)) < 1e-3
        np.testing.assert_allclose(ch["hwdepth_gl"][r, c], ndc[2], atol=1e-5)


def _plan(mesh, target, config):
    scene = load_scene(mesh)
    built = occluders.build(scene, config)
    return target.sample(scene, config, lambda: built, 1, {}, [])


def test_pixel_ao_equals_bake_points_at_the_hit_point_with_the_pixel_id():
    import trimesh

    mesh = combine(trimesh.creation.icosphere(2, 0.5), quad([0, 0, -0.5], 2.0, 2.0))
    config = BakeConfig(rays=32, seed=11, quantities=("ao", "obscurance"))
    target = ViewTarget(size=(48, 36))
    view = aobake.bake_view(mesh, config, size=(48, 36))
    plan = _plan(mesh, target, config)
    points = aobake.bake_points(mesh, plan.points, plan.normals, config, point_ids=plan.ids,
                                point_sizes=plan.sizes)
    index = plan.ids
    for name in ("ao", "ao_stderr", "ao_ci_low", "obscurance"):
        np.testing.assert_array_equal(view.channels[name].ravel()[index],
                                      points.values[name].astype(np.float32))
    np.testing.assert_array_equal(view.channels["rays"].ravel()[index], points.rays)
    uncovered = ~view.covered
    assert uncovered.any()
    for name in ("ao", "depth", "distance", "rays", "P.X", "N.Z"):
        assert (view.channels[name][uncovered] == 0).all(), name
    for name, cleared in (("hwdepth_gl", 1), ("hwdepth_d3d", 1), ("hwdepth_reversed", 0),
                          ("object_id", -1), ("primitive_id", -1)):
        assert (view.channels[name][uncovered] == cleared).all(), name
    assert all(np.isfinite(c).all() for c in view.channels.values())


def test_pixel_intervals_cover_the_exact_ao():
    """Floor pixels between a floor and a ceiling square: AO = 1 - the ceiling's form
    factor (exact for the polygon).  The 95% intervals of independent pixels over seeds
    cover it in at least 93% of trials (one-sided binomial test at 1e-4), with 16 rays."""
    h, half = 0.4, 1.0
    mesh = floor_and_ceiling(h, half)
    cam = cameras.look_at([0.0, -0.9, 0.3], [0.0, 0.2, 0.0], [0.0, 0.0, 1.0], 60.0,
                          size=(40, 30))
    corners = np.array([[-half, -half, h], [half, -half, h], [half, half, h], [-half, half, h]])
    covered = total = 0
    for seed in range(6):
        result = aobake.bake_view(mesh, camera=cam, rays=16, seed=seed)
        ch = result.channels
        floor = result.covered & (np.abs(ch["Ng.X"] * 0) == 0) & (ch["primitive_id"] < 2)
        rec = result.report["camera"]
        world_to_view = np.array(rec["world_to_view"])
        p = np.stack([ch[f"P.{a}"][floor] for a in "XYZ"], 1).astype(np.float64)
        world = (p - world_to_view[:3, 3]) @ world_to_view[:3, :3]
        world[:, 2] = 0.0  # on the floor (P is float32)
        exact = 1.0 - polygon_form_factors(world, np.tile([0.0, 0.0, 1.0], (len(world), 1)),
                                           corners)
        low, high = ch["ao_ci_low"][floor], ch["ao_ci_high"][floor]
        covered += int(np.count_nonzero((low <= exact + 1e-6) & (exact - 1e-6 <= high)))
        total += len(exact)
    assert total > 2000
    p_value = stats.binom.cdf(covered, total, 0.93)
    assert p_value >= 1e-4, f"coverage {covered / total:.4f} of {total}"


@pytest.mark.slow
def test_cli_view_writes_exr_with_gbuffer_and_camera_file(tmp_path, box_ply):
    out = tmp_path / "view.exr"
    result = run_cli("view", box_ply, "--out", out, "--rays", "8", "--size", "32x24",
                     "--quiet")
    assert result.exit_code == 0, result.output
    from readers import read_image

    _, channels, _ = read_image(out)
    for name in ("coverage", "depth", "distance", "hwdepth_gl", "P.X", "Ng.Z", "N.Y",
                 "object_id", "primitive_id", "ao", "ao_stderr", "ao_ci_low", "ao_ci_high",
                 "rays"):
        assert name in channels, name
    side = json.loads((tmp_path / "view.camera.json").read_text())
    assert side["camera"]["matrix_layout"].startswith("row-major")
    assert side["camera"]["width"] == 32 and side["camera"]["height"] == 24
    png = tmp_path / "view.png"
    assert run_cli("view", box_ply, "--out", png, "--rays", "4", "--size", "16x12",
                   "--quiet").exit_code == 0
    assert png.exists()


@pytest.mark.parametrize("args, message", [
    (["--look-from", "1,1,1", "--look-at", "1,1,1"], "look-from equals look-at"),
    (["--look-from", "0,0,5", "--look-at", "0,0,0", "--up", "0,0,1"], "parallel"),
    (["--look-from", "0,0,50", "--look-at", "0,0,100"], "sees nothing"),
])
@pytest.mark.slow
def test_bad_cameras_get_one_clear_error(tmp_path, box_ply, args, message):
    out = tmp_path / "v.exr"
    result = run_cli("view", box_ply, "--out", out, "--rays", "4", "--size", "8x8", *args)
    assert result.exit_code == 1
    assert result.output.startswith("aobake: error:") and message in result.output
    assert "Traceback" not in result.output and not out.exists()


@pytest.mark.parametrize("fov", ["0", "180", "nan"])
def test_fov_out_of_range_is_a_usage_error(tmp_path, box_ply, fov):
    result = run_cli("view", box_ply, "--out", tmp_path / "v.exr", "--fov", fov)
    assert result.exit_code == 2


@pytest.mark.slow
def test_camera_inside_a_closed_mesh_warns(tmp_path, box_ply, caplog):
    cam = cameras.look_at([0.0, 0.0, 0.0], [1.0, 0.2, 0.1], [0.0, 0.0, 1.0], 60.0,
                          size=(16, 12))
    with caplog.at_level("WARNING"):
        result = aobake.bake_view(str(box_ply), camera=cam, rays=4)
    assert any("inside a closed mesh" in w for w in result.report["warnings"])
    assert result.covered.all()


def _with_camera(glb: bytes, camera: dict, node: dict) -> bytes:
    """A GLB with one more camera and a root node holding it (JSON chunk rewritten)."""
    import struct

    length = struct.unpack_from("<I", glb, 12)[0]
    doc = json.loads(glb[20:20 + length])
    rest = glb[20 + length:]
    doc.setdefault("cameras", []).append(camera)
    doc["nodes"].append(dict(node, camera=len(doc["cameras"]) - 1))
    doc["scenes"][doc.get("scene", 0)]["nodes"].append(len(doc["nodes"]) - 1)
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + rest
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


@pytest.mark.slow
def test_cli_view_through_a_gltf_camera_node(tmp_path):
    """A camera node 3 units above a floor, looking down its -Z: every pixel reads depth 3."""
    import trimesh

    floor = quad([0.0, 0.0, 0.0], 20.0, 20.0)
    glb = trimesh.Scene(floor).export(file_type="glb")
    path = tmp_path / "scene.glb"
    path.write_bytes(_with_camera(glb, {"type": "perspective", "name": "overhead",
                                        "perspective": {"yfov": 0.8, "znear": 0.1,
                                                        "zfar": 100.0}},
                                  {"translation": [0.5, -0.25, 3.0]}))
    out = tmp_path / "v.exr"
    result = run_cli("view", path, "--camera", "overhead", "--out", out, "--size", "24x16",
                     "--rays", "4", "--quiet")
    assert result.exit_code == 0, result.output
    from readers import read_image

    pixels, names, _ = read_image(out)
    depth = pixels[..., names.index("depth")]
    np.testing.assert_allclose(depth, 3.0, rtol=F32)
    side = json.loads((tmp_path / "v.camera.json").read_text())["camera"]
    assert side["name"] == "overhead" and side["near"] == 0.1 and side["far"] == 100.0
    np.testing.assert_allclose(side["eye"], [0.5, -0.25, 3.0])
    missing = run_cli("view", path, "--camera", "nope", "--out", tmp_path / "w.exr")
    assert missing.exit_code == 1 and "overhead" in missing.output
