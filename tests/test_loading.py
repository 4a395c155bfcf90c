"""Scene loading: OBJ forms real archives publish, multi-object files, bad input."""

import numpy as np
import pytest
import trimesh

from aobake.errors import InputError
from aobake.scene import load_scene

OBJ = """\
# quads, an n-gon, negative indices, groups, UVs on one object, normals on another
mtllib nothing.mtl
o A
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
usemtl x
s 1
f -4/-4 -3/-3 -2/-2 -1/-1
g B
v 0 0 1
v 2 0 1
v 2 2 1
v 1 3 1
v 0 2 1
vn 0 0 1
f 5//1 6//1 7//1 8//1 9//1
l 1 2
"""


def test_obj_quads_ngons_negative_indices_groups(tmp_path):
    path = tmp_path / "forms.obj"
    path.write_text(OBJ)
    scene = load_scene(path)
    assert scene.vertices.shape == (9, 3)  # every v line, in file order
    np.testing.assert_array_equal(scene.vertices[4], [0, 0, 1])
    # 1 quad -> 2 triangles, 1 pentagon -> 3 triangles; indices point into the right object.
    assert scene.faces.shape == (5, 3)
    assert scene.faces[:2].max() == 3 and scene.faces[2:].min() == 4
    # Area checks against the file: unit square + pentagon (2x2 square + triangle of area 1).
    tri = scene.vertices[scene.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    assert area == pytest.approx(1 + 4 + 1)
    assert scene.normals_source == "file"
    np.testing.assert_allclose(scene.vertex_normals[4:], np.tile([0, 0, 1.0], (5, 1)))
    assert any("line/point" in w for w in scene.warnings)


def test_obj_without_normals_uses_angle_weighting(tmp_path):
    path = tmp_path / "plain.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    scene = load_scene(path)
    assert scene.normals_source == "angle"
    np.testing.assert_allclose(scene.vertex_normals, np.tile([0, 0, 1.0], (3, 1)))


def test_multi_object_glb_applies_node_transforms(tmp_path):
    a = trimesh.creation.box()
    b = trimesh.creation.box()
    sc = trimesh.Scene()
    sc.add_geometry(a, node_name="a")
    sc.add_geometry(b, node_name="b", transform=trimesh.transformations.translation_matrix([5, 0, 0]))
    path = tmp_path / "two.glb"
    sc.export(path)
    scene = load_scene(path)
    assert len(scene.faces) == 24
    assert scene.bounds[1][0] == pytest.approx(5.5)


@pytest.mark.parametrize("ext", [".ply", ".stl", ".off"])
def test_other_formats(tmp_path, ext):
    mesh = trimesh.creation.icosphere(subdivisions=1)
    path = tmp_path / f"m{ext}"
    mesh.export(path)
    scene = load_scene(path)
    assert len(scene.faces) == len(mesh.faces)
    assert len(scene.vertices) == len(mesh.vertices)  # STL welded back to shared vertices


@pytest.mark.parametrize("name, content, message", [
    ("missing.obj", None, "no such file"),
    ("mesh.xyz", "1 2 3", "unsupported mesh format"),
    ("empty.obj", "", "file is empty"),
    ("nofaces.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no faces"),
    ("nan.obj", "v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite"),
    ("inf.obj", "v inf 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite"),
    ("badindex.obj", "v 0 0 0\nv 1 0 0\nf 1 2 7\n", "out of range"),
    ("garbage.obj", "v 0 zero 0\n", "malformed"),
    ("corrupt.ply", "ply\nformat nonsense\n\x00\x01", "cannot read"),
    ("corrupt.glb", "glTF garbage", "cannot read"),
])
def test_bad_input_names_file_and_problem(tmp_path, name, content, message):
    path = tmp_path / name
    if content is not None:
        path.write_text(content)
    with pytest.raises(InputError) as info:
        load_scene(path)
    assert str(path) in str(info.value) and message in str(info.value)


def test_gltf_materials_are_kept_per_face(tmp_path):
    """Two nodes with different PBR materials: one material entry each, faces tagged."""
    from trimesh.visual import TextureVisuals
    from trimesh.visual.material import PBRMaterial

    parts = []
    for i, colour in enumerate(([255, 0, 0, 255], [0, 0, 255, 255])):
        box = trimesh.creation.box()
        box.apply_translation([3.0 * i, 0, 0])
        uv = np.random.default_rng(i).random((len(box.vertices), 2))
        box.visual = TextureVisuals(uv=uv, material=PBRMaterial(name=f"m{i}", baseColorFactor=colour))
        parts.append(box)
    path = tmp_path / "two.glb"
    trimesh.Scene(parts).export(path)
    scene = load_scene(path)
    assert len(scene.materials) == 2 and scene.face_material.shape == (len(scene.faces),)
    colours = {m["name"]: m["base_color_factor"] for m in scene.materials}
    assert colours == {"m0": [1.0, 0.0, 0.0, 1.0], "m1": [0.0, 0.0, 1.0, 1.0]}
    centres = scene.vertices[scene.faces].mean(axis=1)[:, 0]
    for k, material in enumerate(scene.materials):
        expected = 0.0 if material["name"] == "m0" else 3.0
        np.testing.assert_allclose(centres[scene.face_material == k], expected, atol=0.51)


def test_obj_faces_keep_their_usemtl(tmp_path):
    (tmp_path / "m.mtl").write_text("newmtl a\nKd 0.2 0.4 0.6\nnewmtl b\nKd 1 0 0\n")
    (tmp_path / "m.obj").write_text(
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "f 1/1 2/2 3/3\nusemtl b\nf 1/1 3/3 4/4\nusemtl a\nf 1/1 2/2 4/4\nusemtl b\nf 2/2 3/3 4/4\n")
    scene = load_scene(tmp_path / "m.obj")
    names = [m["name"] for m in scene.materials]
    assert names == ["b", "a", "default"]  # in order of first use; untagged faces: default
    np.testing.assert_array_equal(scene.face_material, [2, 0, 1, 0])
    assert scene.materials[1]["base_color_factor"] == [0.2, 0.4, 0.6, 1.0]
    assert scene.materials[2]["base_color_factor"] is None


@pytest.mark.parametrize("name, data", [
    ("latin.stl", b"solid caf\xe9\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
                  b"vertex 0 1 0\nendloop\nendfacet\nendsolid caf\xe9\n"),
    ("latin.off", b"OFF\n# caf\xe9\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
])
def test_text_meshes_with_latin1_names_read(tmp_path, name, data):
    """ASCII STL/OFF that are not UTF-8 need trimesh's charset detection (a declared
    dependency: without it every such file failed with ModuleNotFoundError)."""
    path = tmp_path / name
    path.write_bytes(data)
    assert len(load_scene(path).faces) == 1


@pytest.mark.parametrize("name, data", [
    ("bad.stl", b"solid x\nfacet garbage\n"),
    ("bad.off", b"OFF\n3 1\n0 0\n"),
    ("bad.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n0 0\n"),
])
def test_corrupt_text_meshes_are_input_errors_naming_the_file(tmp_path, name, data):
    from aobake.errors import InputError

    path = tmp_path / name
    path.write_bytes(data)
    with pytest.raises(InputError, match=name):
        load_scene(path)
