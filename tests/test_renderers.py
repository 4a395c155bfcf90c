"""Cameras others load (issue 32 point 4): ``aobake view --export-camera`` (a glTF with the
camera node) and ``--export-mitsuba`` (a Mitsuba 3 scene), and the recipes of
docs/renderers.md run where the tool installs: Mitsuba 3 (the ``mitsuba`` extra), Blender's
glTF importer, Cycles and EEVEE (``AOBAKE_BLENDER_PYTHON``: a Python with ``bpy``; .ci/run
makes one).

Tolerances: the round trip through glTF is float64 JSON (a few ulps: 1e-12); Blender holds
its matrices in float32 (1e-6 relative); a render agrees with aobake's view when the
difference is within the two error bars: z = (render - aobake) / sqrt(se_render^2 +
se_aobake^2) per pixel, both standard errors measured (16 renders' spread; aobake's 16
positions per pixel), so z is about Student's t with ~15 degrees of freedom:
E[z^2] = 15 / 13, within_95 about 0.94.  The bounds below are wide enough for that and
narrow enough to catch a half-pixel shift or a wrong normal (z_rms 3 and more, measured).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np
import pytest
import trimesh
from conftest import run_cli

import aobake
from aobake import camera as cameras
from aobake.errors import OutputError, UsageError
from aobake.outputs import camera_export, image
from aobake.outputs import read as read_values
from aobake.outputs.gltf import read_gltf
from aobake.outputs.image import write_exr

ROOT = Path(__file__).resolve().parent.parent
BLENDER_SCRIPT = Path(__file__).resolve().parent / "blender_renderers.py"
BLENDER = os.environ.get("AOBAKE_BLENDER_PYTHON")
needs_blender = pytest.mark.skipif(not BLENDER, reason="AOBAKE_BLENDER_PYTHON (a Python "
                                   "with bpy) not set: .ci/run makes one")
#: a view of the test scene: every pixel sees the floor
LOOK = ["--look-from", "2.5,-3.5,4.5", "--look-at", "0.3,0,0.4", "--up", "0,0,1", "--fov", "35"]
SIZE = (32, 24)
#: independent renders whose spread is a render's stderr
RENDERS = 16
#: Blender's import: glTF +Y up -> Blender +Z up, Blender (x, y, z) = glTF (x, -z, y)
GLTF_TO_BLENDER = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])


def _scene(tmp_path) -> Path:
    """A floor (z = 0, 20 x 20) with a unit box and a leaning slab on it: AO from 0.3 to 1."""
    floor = trimesh.Trimesh([[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]],
                            [[0, 1, 2], [0, 2, 3]], process=False)
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    box.apply_translation((0.0, 0.0, 0.5))
    slab = trimesh.creation.box(extents=(1.2, 0.1, 0.8))
    slab.apply_transform(trimesh.transformations.rotation_matrix(0.5, (1, 0, 0)))
    slab.apply_translation((1.3, 0.6, 0.4))
    path = tmp_path / "scene.ply"
    trimesh.util.concatenate([floor, box, slab]).export(path)
    return path


def _view(tmp_path, *extra, out="view.exr"):
    mesh = _scene(tmp_path)
    result = run_cli("view", mesh, "--out", tmp_path / out, *LOOK, "--size",
                     f"{SIZE[0]}x{SIZE[1]}", "--report", tmp_path / "report.json", *extra)
    assert result.exit_code == 0, result.output
    return mesh, json.loads((tmp_path / "report.json").read_text())


# ---- the glTF --------------------------------------------------------------------------------

@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
@pytest.mark.slow
def test_the_exported_gltf_reads_back_the_same_camera(tmp_path, suffix):
    mesh, report = _view(tmp_path, "--rays", 4, "--export-camera", tmp_path / f"cam{suffix}")
    assert str(tmp_path / f"cam{suffix}") in report["outputs"] or (tmp_path / f"cam{suffix}"
                                                                   ).is_file()
    again = run_cli("view", tmp_path / f"cam{suffix}", "--camera", "first", "--out",
                    tmp_path / "again.exr", "--size", f"{SIZE[0]}x{SIZE[1]}", "--rays", 4,
                    "--report", tmp_path / "again.json")
    assert again.exit_code == 0, again.output
    before, after = report["camera"], json.loads((tmp_path / "again.json").read_text())["camera"]
    for key in ("world_to_view", "view_to_clip", "eye", "up", "forward"):
        np.testing.assert_allclose(after[key], before[key], rtol=1e-12, atol=1e-12, err_msg=key)
    for key in ("fov_y_deg", "aspect", "near", "far"):
        assert after[key] == pytest.approx(before[key], rel=1e-12), key
    assert (after["width"], after["height"]) == (before["width"], before["height"])
    assert after["name"] == camera_export.CAMERA_NAME
    # the target is a point on the same axis (glTF has none: eye + forward)
    offset = np.subtract(after["target"], after["eye"])
    np.testing.assert_allclose(offset / np.linalg.norm(offset), before["forward"], atol=1e-12)
    # the same pixels see the same surfaces: the exported mesh is the scene (float32)
    views = [read_values(tmp_path / name).columns["depth"] for name in ("view.exr",
                                                                        "again.exr")]
    np.testing.assert_allclose(views[1], views[0], rtol=1e-5)


@pytest.mark.slow
def test_the_gltf_camera_node_is_the_inverse_of_world_to_view(tmp_path):
    mesh, report = _view(tmp_path, "--rays", 4, "--ground-plane", "--up-axis", "z",
                         "--export-camera", tmp_path / "cam.glb")
    gltf, _ = read_gltf(tmp_path / "cam.glb")
    record = report["camera"]
    (camera,) = gltf["cameras"]
    lens = camera["perspective"]
    assert camera["type"] == "perspective"
    assert lens["yfov"] == pytest.approx(math.radians(record["fov_y_deg"]), rel=1e-15)
    assert lens["aspectRatio"] == pytest.approx(SIZE[0] / SIZE[1], rel=1e-15)
    assert (lens["znear"], lens["zfar"]) == (record["near"], record["far"])
    assert camera["extras"] == {"width": SIZE[0], "height": SIZE[1]}
    node = next(n for n in gltf["nodes"] if "camera" in n)
    matrix = np.array(node["matrix"]).reshape(4, 4).T  # glTF stores column-major
    np.testing.assert_allclose(matrix, np.linalg.inv(record["world_to_view"]), atol=1e-12)
    # the camera looks down its node's -Z with +Y up: the view's forward and up
    np.testing.assert_allclose(-matrix[:3, 2], record["forward"], atol=1e-12)
    np.testing.assert_allclose(matrix[:3, 1], record["up"], atol=1e-12)
    # the mesh without normals (glTF: flat, the view's geometric normal), and the ground
    names = [m["name"] for m in gltf["meshes"]]
    assert names == ["aobake_mesh", "ground_plane"]
    for m in gltf["meshes"]:
        assert set(m["primitives"][0]["attributes"]) == {"POSITION"}
    assert gltf["materials"][0]["doubleSided"] is True
    assert gltf["asset"]["extras"]["camera"]["world_to_view"] == record["world_to_view"]
    ground = gltf["accessors"][gltf["meshes"][1]["primitives"][0]["attributes"]["POSITION"]]
    height = report["parameters"]["ground_plane"]["height"]
    assert ground["min"][2] == ground["max"][2] == pytest.approx(height)
    half = (ground["max"][0] - ground["min"][0]) / 2
    assert half == pytest.approx(camera_export.GROUND_HALF_SIZE
                                 * report["scene"]["diagonal"], rel=1e-6)


@pytest.mark.slow
def test_the_library_exports_a_views_camera(tmp_path):
    mesh = _scene(tmp_path)
    cam = cameras.look_at([2.5, -3.5, 4.5], [0.3, 0, 0.4], [0, 0, 1], 35.0, SIZE)
    result = aobake.bake_view(str(mesh), camera=cam, rays=4)
    written = camera_export.export_view(result, str(mesh), gltf=tmp_path / "a.glb",
                                        mitsuba=tmp_path / "a.xml")
    assert written == [tmp_path / "a.glb", tmp_path / "a.xml", tmp_path / "a.ply"]
    back = cameras.gltf_camera(tmp_path / "a.glb", size=SIZE)
    np.testing.assert_allclose(back.world_to_view(), result.camera.world_to_view(), atol=1e-12)
    np.testing.assert_allclose(back.view_to_clip(), result.camera.view_to_clip(), rtol=1e-12)
    # the lower-level writer: any mesh, any camera with clip planes
    scene = trimesh.load(mesh)
    path = camera_export.write_gltf(tmp_path / "b.gltf", scene.vertices, scene.faces,
                                    result.camera)
    assert cameras.gltf_camera(path, size=SIZE).fov_y == pytest.approx(35.0, rel=1e-14)
    with pytest.raises(aobake.InputError, match="near/far"):
        camera_export.write_gltf(tmp_path / "c.glb", scene.vertices, scene.faces, cam)
    with pytest.raises(OutputError, match=r"\.gltf or \.glb"):
        camera_export.write_gltf(tmp_path / "c.obj", scene.vertices, scene.faces,
                                 result.camera)


@pytest.mark.skipif(shutil.which("node") is None
                    or not (ROOT / ".ci" / "node" / "node_modules" / "gltf-validator").is_dir(),
                    reason="the Khronos glTF validator is not installed (npm install "
                           "--prefix .ci/node; .ci/run does)")
@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_khronos_validator_finds_no_errors_in_the_export(tmp_path, suffix):
    out = tmp_path / f"cam{suffix}"
    _view(tmp_path, "--rays", 4, "--ground-plane", "--export-camera", out)
    done = subprocess.run(["node", str(ROOT / ".ci" / "node" / "validate.js"), str(out)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    issues = json.loads(done.stdout)["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]


# ---- the Mitsuba scene -----------------------------------------------------------------------

@pytest.mark.slow
def test_the_mitsuba_scene_states_the_conventions(tmp_path):
    mesh, report = _view(tmp_path, "--rays", 8, "--export-mitsuba", tmp_path / "export.xml",
                         "--ground-plane", "--up-axis", "z")
    root = ElementTree.parse(tmp_path / "export.xml").getroot()
    record = report["camera"]

    def value(element, name):
        return next(c.get("value") for c in element if c.get("name") == name)

    sensor = root.find("sensor")
    assert sensor.get("type") == "perspective"
    assert value(sensor, "fov_axis") == "y"
    assert float(value(sensor, "fov")) == record["fov_y_deg"]
    assert float(value(sensor, "near_clip")) == record["near"]
    assert float(value(sensor, "far_clip")) > record["far"]  # past the ground quad
    look = sensor.find("transform/lookat")
    origin = np.array(look.get("origin").split(","), dtype=float)
    target = np.array(look.get("target").split(","), dtype=float)
    np.testing.assert_allclose(origin, record["eye"], rtol=1e-15)
    np.testing.assert_allclose(target - origin, record["forward"], atol=1e-15)
    np.testing.assert_allclose(np.array(look.get("up").split(","), dtype=float), record["up"])
    film = sensor.find("film")
    assert (int(value(film, "width")), int(value(film, "height"))) == SIZE
    assert film.find("rfilter").get("type") == "box"
    assert root.find("default").get("value") == "8"  # spp = the view's rays per pixel
    integrator = root.find("integrator")
    assert integrator.get("type") == "direct"
    assert (value(integrator, "emitter_samples"), value(integrator, "bsdf_samples"),
            value(integrator, "hide_emitters")) == ("0", "1", "true")
    shapes = {s.get("id"): s for s in root.findall("shape")}
    assert value(shapes["aobake_mesh"], "face_normals") == "true"
    assert value(shapes["aobake_mesh"], "filename") == "export.ply"
    assert shapes["ground_plane"].get("type") == "rectangle"
    # the PLY beside it is the scene as baked
    from aobake.outputs.ply import parse_ply

    ply = parse_ply((tmp_path / "export.ply").read_bytes())
    scene = trimesh.load(mesh, process=False)
    np.testing.assert_array_equal(np.column_stack([ply.vertex[a] for a in "xyz"]),
                                  scene.vertices)
    np.testing.assert_array_equal(ply.faces, scene.faces)


@pytest.mark.slow
def test_a_finite_max_distance_is_written_with_a_warning(tmp_path, caplog):
    mesh = _scene(tmp_path)
    with caplog.at_level("WARNING"):
        result = run_cli("view", mesh, "--out", tmp_path / "v.exr", *LOOK, "--size", "8x6",
                         "--rays", 4, "--max-distance", "0.5", "--export-mitsuba",
                         tmp_path / "m.xml")
    assert result.exit_code == 0, result.output
    note = "max_distance 0.5: Mitsuba's direct integrator has no ray length"
    assert note in caplog.text
    root = ElementTree.parse(tmp_path / "m.xml")  # the note in a well-formed comment
    assert root.getroot().tag == "scene" and note in (tmp_path / "m.xml").read_text()


# ---- one transaction, checked before the work ------------------------------------------------

@pytest.mark.parametrize("flag, name, report, message", [
    ("--export-camera", "cam.obj", "r.json", "--export-camera writes .gltf or .glb"),
    ("--export-mitsuba", "scene.gltf", "r.json", "--export-mitsuba writes .xml"),
    ("--export-camera", "r.glb", "r.glb", "refusing to write --export-camera over --report"),
    ("--export-mitsuba", "r.xml", "r.xml", "refusing to write --export-mitsuba over --report"),
    ("--export-mitsuba", "scene.xml", "r.json", "over the input mesh"),  # its PLY: scene.ply
    ("--export-camera", "no/such/dir/cam.glb", "r.json", "does not exist"),
])
def test_bad_export_paths_are_refused_before_the_bake(tmp_path, flag, name, report, message):
    mesh = _scene(tmp_path)
    result = run_cli("view", mesh, "--out", tmp_path / "view.exr", "--size", "8x6",
                     "--rays", 4, "--report", tmp_path / report, flag, tmp_path / name)
    assert result.exit_code == 1, result.output
    assert message in result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.ply"]  # nothing written


@pytest.mark.slow
def test_the_export_may_not_overwrite_the_input(tmp_path):
    _view(tmp_path, "--rays", 4, "--export-camera", tmp_path / "cam.glb")
    result = run_cli("view", tmp_path / "cam.glb", "--camera", "first", "--out",
                     tmp_path / "v.exr", "--size", "8x6", "--rays", 4, "--export-camera",
                     tmp_path / "cam.glb")
    assert result.exit_code == 1 and "over the input mesh" in result.output, result.output


def test_a_selection_the_scene_cannot_carry_is_a_usage_error(tmp_path):
    mesh = _scene(tmp_path)
    result = run_cli("view", mesh, "--out", tmp_path / "v.exr", "--size", "8x6", "--rays", 4,
                     "--receive-only", "*", "--export-camera", tmp_path / "c.glb")
    assert result.exit_code == 2, result.output
    assert "--receive-only" in result.output
    with pytest.raises(UsageError):
        camera_export.plan(tmp_path / "c.glb", config={"alpha_cutout": True})


@pytest.mark.slow
def test_the_exports_and_the_view_appear_together_or_not_at_all(tmp_path, monkeypatch):
    mesh = _scene(tmp_path)
    args = ["view", mesh, "--out", tmp_path / "v.exr", "--size", "8x6", "--rays", 4,
            "--report", tmp_path / "r.json", "--export-camera", tmp_path / "c.glb",
            "--export-mitsuba", tmp_path / "m.xml"]
    assert run_cli(*args).exit_code == 0
    written = sorted(p.name for p in tmp_path.iterdir())
    assert written == ["c.glb", "m.ply", "m.xml", "r.json", "scene.ply", "v.camera.json",
                       "v.exr"]
    for path in tmp_path.iterdir():
        if path.name != "scene.ply":
            path.unlink()

    def broken(*args, **kwargs):
        raise OutputError("m.xml: no space left on device")

    monkeypatch.setattr(camera_export, "mitsuba_scene", broken)
    result = run_cli(*args)
    assert result.exit_code == 1 and "no space left" in result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.ply"]  # nothing else


# ---- the renderers ---------------------------------------------------------------------------

def _reference(tmp_path, pixel_filter="box"):
    """aobake's view of the test scene (the joint box estimator with --sampler random: 1024
    i.i.d. samples per pixel, whose spread has 1023 dof; its noise then below a render's,
    so that a Gaussian filter's blur stands out), the glTF and the Mitsuba scene beside
    it."""
    mesh, report = _view(tmp_path, "--pixel-filter", pixel_filter, "--sampler", "random",
                         "--rays", 1024,
                         "--export-camera", tmp_path / "view.glb",
                         "--export-mitsuba", tmp_path / "view.xml")
    return report


def _agreement(tmp_path, images, alphas=None, name="render"):
    """``aobake compare`` of the mean of ``images`` (k, H, W) against the view, with their
    standard error as --candidate-stderr: the recipe of docs/renderers.md."""
    images = np.asarray(images, dtype=np.float64)
    if alphas is not None:  # every pixel of the test view sees the scene (float32 sums)
        assert np.asarray(alphas).min() >= 1.0 - 1e-6
    mean = images.mean(axis=0)
    stderr = images.std(axis=0, ddof=1) / math.sqrt(len(images))
    write_exr(tmp_path / f"{name}_mean.exr", {"Y": mean})
    write_exr(tmp_path / f"{name}_stderr.exr", {"Y": stderr})
    result = run_cli("compare", tmp_path / "view.exr", tmp_path / f"{name}_mean.exr",
                     "--candidate-stderr", tmp_path / f"{name}_stderr.exr", "--json")
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def _assert_agrees(m, n_pixels):
    print({k: m[k] for k in ("n", "bias", "rmse", "noise_rms", "z_rms", "within_95")})
    assert m["error"] == "combined" and m["n"] == n_pixels, m
    # the mean difference over the pixels, against its own standard error
    bias_se = m["noise_rms"] / math.sqrt(n_pixels)
    assert abs(m["bias"]) <= 4 * bias_se, m
    assert 0.75 <= m["z_rms"] <= 1.3, m
    assert m["within_95"] >= 0.88, m


def _llvm_runs() -> str | None:
    """None where Mitsuba's llvm_ad_rgb variant renders, else why not.  Probed in a child:
    an unusable libLLVM aborts the process (LLVM 15: "Cannot select")."""
    probe = ("import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); "
             "s = mi.load_dict(mi.cornell_box()); mi.render(s, spp=1)")
    try:
        done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                              timeout=300)
    except subprocess.TimeoutExpired:
        return "the llvm_ad_rgb probe did not finish in 300 s"
    if done.returncode == 0:
        return None
    last = (done.stderr.strip().splitlines() or ["no message"])[-1][:200]
    return (f"llvm_ad_rgb does not run here (DRJIT_LIBLLVM_PATH="
            f"{os.environ.get('DRJIT_LIBLLVM_PATH', 'unset')}; apt install libllvm19): {last}")


@pytest.mark.slow
@pytest.mark.parametrize("variant", ["scalar_rgb", "llvm_ad_rgb"])
def test_mitsuba_renders_the_exported_scene_as_aobake_does(tmp_path, variant):
    mi = pytest.importorskip("mitsuba", reason="mitsuba is not installed (pip install "
                             "'aobake[mitsuba]')")
    if variant.startswith("llvm"):
        why = _llvm_runs()
        if why:
            pytest.skip(why)
    mi.set_variant(variant)
    _reference(tmp_path)
    scene = mi.load_file(str(tmp_path / "view.xml"), spp=64)
    renders = np.array([np.array(mi.render(scene, seed=k)) for k in range(RENDERS)])
    m = _agreement(tmp_path, renders[..., 0], renders[..., 3], "mitsuba")
    _assert_agrees(m, SIZE[0] * SIZE[1])


@pytest.mark.slow
def test_mitsuba_with_a_gaussian_filter_does_not_agree(tmp_path):
    """The test can fail: Mitsuba's default filter (a Gaussian) blurs the AO across pixels."""
    mi = pytest.importorskip("mitsuba", reason="mitsuba is not installed")
    mi.set_variant("scalar_rgb")
    _reference(tmp_path)
    xml = (tmp_path / "view.xml").read_text().replace('<rfilter type="box"/>',
                                                      '<rfilter type="gaussian"/>')
    (tmp_path / "gauss.xml").write_text(xml)
    scene = mi.load_file(str(tmp_path / "gauss.xml"), spp=64)
    renders = np.array([np.array(mi.render(scene, seed=k)) for k in range(RENDERS)])
    m = _agreement(tmp_path, renders[..., 0], renders[..., 3], "gauss")
    assert m["z_rms"] > 1.5, m


#: what Blender says when it has no GPU backend for EEVEE (no OpenGL/EGL context)
NO_GPU = ("egl", "opengl", "gpu", "context", "display")


def _blender(*args, timeout=900, gpu=False) -> dict:
    done = subprocess.run([BLENDER, str(BLENDER_SCRIPT), *map(str, args)],
                          capture_output=True, text=True, timeout=timeout)
    lines = done.stdout.strip().splitlines()
    result = json.loads(lines[-1]) if lines and lines[-1].startswith("{") else None
    if gpu and (result is None or not result["ok"]):
        said = (result or {}).get("error", "") + done.stderr[-2000:]
        if any(word in said.lower() for word in NO_GPU):
            pytest.skip(f"EEVEE cannot render here (no GPU context): {said.strip()[-300:]}")
    assert result is not None, done.stderr[-3000:]
    assert done.returncode == 0 and result["ok"], result
    return result


@pytest.mark.slow
@needs_blender
def test_blender_imports_the_camera_and_reproduces_the_view(tmp_path):
    mesh, report = _view(tmp_path, "--rays", 4, "--export-camera", tmp_path / "cam.glb")
    record = report["camera"]
    got = _blender("camera", tmp_path / "cam.glb")
    world = np.linalg.inv(record["world_to_view"])
    np.testing.assert_allclose(got["matrix_world"], GLTF_TO_BLENDER @ world, atol=1e-6)
    assert got["camera_type"] == "PERSP" and got["sensor_fit"] == "VERTICAL"
    assert got["angle_y"] == pytest.approx(math.radians(record["fov_y_deg"]), rel=1e-6)
    # (angle_x is the sensor width's, not the render's: with sensor_fit VERTICAL the
    # horizontal extent follows the resolution, which the projection below checks)
    assert got["resolution"] == list(SIZE)
    assert got["clip_start"] == pytest.approx(record["near"], rel=1e-6)
    assert got["flat"]  # no normals in the file: flat shading, the geometric normal
    # every imported vertex lands on the pixel aobake's camera puts it on
    points = np.array(got["world"]) @ GLTF_TO_BLENDER[:3, :3]  # back to glTF = aobake axes
    cam = cameras.look_at(record["eye"], record["target"], record["up"],
                          record["fov_y_deg"], SIZE)
    pixels, depth = cam.project(points)
    blender = np.array(got["pixels"])
    front = depth > 0  # (behind the eye aobake projects nothing; Blender extrapolates)
    assert front.sum() > 8
    np.testing.assert_allclose(blender[front, :2], pixels[front], atol=2e-3)
    np.testing.assert_allclose(blender[:, 2], depth, rtol=1e-5, atol=1e-5)


@pytest.mark.slow
@needs_blender
def test_the_obj_route_keeps_the_record_only_with_the_axes_kept(tmp_path):
    """An OBJ and <out>.camera.json in Blender: forward_axis='Y', up_axis='Z' leaves the
    coordinates alone and the record's inverse(world_to_view) is the camera's matrix_world;
    the importer's default (Y up -> Z up) turns the mesh and not the camera."""
    mesh = tmp_path / "scene.obj"
    trimesh.load(_scene(tmp_path), process=False).export(mesh)
    result = run_cli("view", mesh, "--out", tmp_path / "v.exr", *LOOK, "--size",
                     f"{SIZE[0]}x{SIZE[1]}", "--rays", 4)
    assert result.exit_code == 0, result.output
    record = json.loads((tmp_path / "v.camera.json").read_text())["camera"]
    cam = cameras.look_at(record["eye"], record["target"], record["up"],
                          record["fov_y_deg"], SIZE)
    moved = {}
    for axes in ("keep", "default"):
        got = _blender("camera-record", mesh, tmp_path / "v.camera.json", "--axes", axes)
        assert got["resolution"] == list(SIZE)
        np.testing.assert_allclose(got["matrix_world"], np.linalg.inv(record["world_to_view"]),
                                   atol=1e-6)
        world = np.array(got["world"])  # Blender's coordinates of the vertices
        if axes == "default":  # where they came from in the file (Y up -> Z up undone)
            world = world @ GLTF_TO_BLENDER[:3, :3]
        truth, depth = cam.project(world)
        front = depth > 0
        blender = np.array(got["pixels"])[front, :2]
        moved[axes] = np.abs(blender - truth[front]).max()
    assert moved["keep"] < 2e-3, moved
    assert moved["default"] > 1.0, moved  # the same vertices, elsewhere in the image


def _cycles(tmp_path, pixel_filter):
    report = _reference(tmp_path, pixel_filter)
    got = _blender("cycles", tmp_path / "view.glb", tmp_path / "cycles.exr", "--samples", 64,
                   "--seed", 1, "--filter", pixel_filter, "--renders", RENDERS)
    images, alphas = [], []
    for path in got["out"]:
        table = image.read(path)
        images.append(np.asarray(table.columns["ViewLayer.Ambient Occlusion.R"]))
        alphas.append(np.asarray(table.columns["ViewLayer.Combined.A"]))
    depth = np.asarray(image.read(got["out"][0]).columns["ViewLayer.Depth.Z"])
    return report, _agreement(tmp_path, images, alphas, "cycles"), depth


@pytest.mark.slow
@needs_blender
@pytest.mark.parametrize("pixel_filter", ["box", "center"])
def test_cycles_ao_pass_agrees_with_the_view(tmp_path, pixel_filter):
    """Box filter against --pixel-filter box; Blackman-Harris of width 0.01 against the
    pixel centres (a box would ignore its width).  At the centres, Cycles' depth pass is
    aobake's ``depth`` (along the view axis, not the ray)."""
    _, m, depth = _cycles(tmp_path, pixel_filter)
    _assert_agrees(m, SIZE[0] * SIZE[1])
    if pixel_filter == "center":
        view = read_values(tmp_path / "view.exr").columns
        np.testing.assert_allclose(depth.reshape(SIZE[::-1]), view["depth"], rtol=1e-3)
        assert np.abs(depth.reshape(SIZE[::-1]) - view["distance"]).max() > 0.01


@pytest.mark.slow
@needs_blender
def test_eevee_ao_pass_renders_the_view(tmp_path):
    """EEVEE's AO is a screen-space horizon scan, not ray traced: the recipe runs and covers
    the same pixels; its bias is measured (docs/renderers.md), not bounded by the noise."""
    _reference(tmp_path)
    got = _blender("eevee", tmp_path / "view.glb", tmp_path / "eevee.exr", "--samples", 4,
                   timeout=1800, gpu=True)
    table = image.read(got["out"])
    ao = np.asarray(table.columns["ViewLayer.Ambient Occlusion.R"]).reshape(-1)
    alpha = np.asarray(table.columns["ViewLayer.Combined.A"]).reshape(-1)
    assert alpha.min() >= 1.0 - 1e-6 and np.isfinite(ao).all()
    assert 0 <= ao.min() <= ao.max() <= 1 + 1e-6
    view = read_values(tmp_path / "view.exr").value.reshape(-1)
    correlation = np.corrcoef(ao, view)[0, 1]
    print({"bias": float(np.mean(ao - view)), "rmse": float(np.sqrt(np.mean((ao - view) ** 2))),
           "correlation": correlation, "seconds": got["seconds"]})
    assert correlation > 0.5  # the same picture, another estimator
