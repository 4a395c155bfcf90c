"""Scene loading: OBJ forms real archives publish, multi-object files, bad input."""

from dataclasses import fields as _fields

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from aobake import obj as objmod
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


@pytest.mark.slow
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


@pytest.mark.slow
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
@pytest.mark.slow
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


# --- The OBJ reader's two paths: the vectorised one gives the line-by-line one's ObjData ----------

def _paths(data: bytes, path="mem.obj"):
    """(fast ObjData | None, slow ObjData | InputError) for a file's bytes."""
    text, encoding = objmod._decode(path, data)
    fast = objmod._read_fast(path, data, text, encoding)
    try:
        slow = objmod._read_slow(path, text)
    except InputError as exc:
        slow = exc
    return fast, slow


def _assert_identical(a, b):
    """Every array equal in dtype, shape and bits (NaN payloads, signed zeros); lists equal."""
    for f in _fields(objmod.ObjData):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            assert isinstance(x, np.ndarray) and isinstance(y, np.ndarray), f.name
            assert (x.dtype, x.shape) == (y.dtype, y.shape), f.name
            assert x.flags.c_contiguous and y.flags.c_contiguous, f.name
            assert x.tobytes() == y.tobytes(), f.name
        else:
            assert x == y, f.name


def _fast_equals_slow(data: bytes):
    fast, slow = _paths(data)
    assert not isinstance(slow, InputError), slow
    assert fast is not None, "the fast path declined a file in its forms"
    _assert_identical(fast, slow)
    return fast


GRID = "".join(f"v {x} {y} {0.5 * x * y}\n" for y in range(3) for x in range(3))  # 9 vertices
UVS = "".join(f"vt {x / 2} {y / 2}\n" for y in range(3) for x in range(3))
NORMALS = "vn 0 0 1\nvn 0 1 0\nvn 1 0 0\n"

FAST_FORMS = {
    "plain": GRID + "f 1 2 5\nf 1 5 4\n",
    "v/vt": GRID + UVS + "f 1/1 2/2 5/5\nf 1/1 5/5 4/4\n",
    "v//vn": GRID + NORMALS + "f 1//1 2//2 5//3\nf 1//1 5//1 4//1\n",
    "v/vt/vn": GRID + UVS + NORMALS + "f 1/1/1 2/2/2 5/5/3\nf 1/9/1 5/5/1 4/4/2\n",
    "negative": GRID + UVS + NORMALS + "f -9/-9/-3 -8/-8/-2 -5/-5/-1\nf -9 -5 -6\n",
    # Negative indices count from the lines before the face, not from the end of the file.
    "interleaved": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 5 5 5\nv 6 5 5\nf -1 -2 -5\n"
                   "vn 0 0 1\nf 1//1 2//-1 3//1\nvn 1 0 0\nf 4//-1 5//-2 1//2\n",
    # Per-face and per-corner mixtures of forms: faces_uv None (one corner has no vt),
    # faces_normal -1 where a corner has no vn.
    "mixed forms": GRID + UVS + NORMALS
                   + "f 1/1 2/2 5/5\nf 1//1 5//2 4//3\nf 2/2/1 3 6//2\nf 4/4/ 5/5/ 8\n",
    "mixed within face": GRID + UVS + NORMALS + "f 1 2/2 5//1 4/4/3\n",
    "quads and n-gons": GRID + "f 1 2 5 4\nf 2 3 6 5\nf 4 5 6 9 8 7\nf 1 2 3\n",
    "unreferenced": GRID + "v 9 9 9\nf 1 2 5\n",  # v 4.., 10 unused but kept in file order
    "usemtl": "mtllib a.mtl\nmtllib b c.mtl\n" + GRID + "f 1 2 5\nusemtl red\nf 1 5 4\n"
              "usemtl blue # a comment\nf 2 3 6\nusemtl red\nf 2 6 5\ng part\nusemtl  two words \n"
              "f 4 5 8\no thing\ns 1\nf 5 6 9\n",
    "comments and blanks": "# header\n\n#\n" + GRID.replace("\n", "\n\n", 3)
                           + "   \n# between\nf 1 2 5\n\n\nf 1 5 4",  # no final line break
    "windows line endings": (GRID + UVS + "usemtl m\nf 1/1 2/2 5/5\nf 1/1 5/5 4/4\n")
                            .replace("\n", "\r\n"),
    "old mac line endings": (GRID + "f 1 2 5\n").replace("\n", "\r"),
    "form feed and vertical tab": "v 0 0 0\x0cv 1 0 0\x0bv 0 1 0\nf 1 2 3\x0cf 3 2 1\x0b",
    "tabs and spaces": GRID.replace(" ", "\t") + "f\t1\t 2  5 \t\nf  1 5    4 \n",
    "scientific": "v 1e0 -2.5E-3 +3e+2\nv .5 5. -0.0\nv 1E300 -1e-310 1_0\n"
                  "v 1e-320 123456789012345678901234567890 0.1\nf 1 2 3\nf 4 1 2\n",
    "colour columns": "".join(f"v {x} {x * x} 1 0.5 0.25 {x / 9}\n" for x in range(4))
                      + "f 1 2 3\nf 2 3 4\n",
    "w column": "v 0 0 0 1\nv 1 0 0 1\nv 0 1 0 0.5\nf 1 2 3\n",
    "vt u only": GRID + "vt 0.25\nvt 0.5\nvt 0.75\nf 1/1 2/2 5/3\n",
    "vt u v w": GRID + "vt 0.25 1 0\nvt 0.5 0.5 0\nvt 0.75 0 0\nf 1/1 2/2 5/3\n",
    "nan and inf": "v nan 0 0\nv inf -inf 0\nv -nan 1 1\nf 1 2 3\n",
    "lines and points": GRID + "l 1 2 3\np 4\nf 1 2 5\nl 5 6\n",
    "leading zeros": GRID + "f 001 0002 -0004\n",
    "module sample": OBJ,
    "latin-1 names": None,  # bytes, below
    "bom": "\ufeff# exported\n" + GRID + "f 1 2 5\n",
}


@pytest.mark.parametrize("name", sorted(FAST_FORMS))
def test_obj_fast_path_matches_slow_path(name):
    content = FAST_FORMS[name]
    if content is None:
        data = ("usemtl caf\xe9\n# r\xe9sum\xe9\n" + GRID + "f 1 2 5\n").encode("latin-1")
    else:
        data = content.encode("utf-8")
    _fast_equals_slow(data)


def test_obj_fast_path_reads_what_the_file_says():
    """Not only the same as the slow path: the right values (slow path bugs would pass above)."""
    data = _fast_equals_slow(FAST_FORMS["mixed forms"].encode())
    np.testing.assert_array_equal(data.faces, [[0, 1, 4], [0, 4, 3], [1, 2, 5], [3, 4, 7]])
    assert data.faces_uv is None  # face 2 has a corner without vt
    np.testing.assert_array_equal(data.faces_normal,
                                  [[-1, -1, -1], [0, 1, 2], [0, -1, 1], [-1, -1, -1]])
    data = _fast_equals_slow(FAST_FORMS["interleaved"].encode())
    np.testing.assert_array_equal(data.faces, [[0, 1, 2], [4, 3, 0], [0, 1, 2], [3, 4, 0]])
    np.testing.assert_array_equal(data.faces_normal, [[-1] * 3, [-1] * 3, [0, 0, 0], [1, 0, 1]])
    data = _fast_equals_slow(FAST_FORMS["usemtl"].encode())
    assert data.materials == ["red", "blue", "two words"]
    assert data.mtllibs == ["a.mtl", "b c.mtl"]
    np.testing.assert_array_equal(data.face_material, [-1, 0, 1, 0, 2, 2])
    data = _fast_equals_slow(FAST_FORMS["quads and n-gons"].encode())
    np.testing.assert_array_equal(data.faces[4:8], [[3, 4, 5], [3, 5, 8], [3, 8, 7], [3, 7, 6]])
    data = _fast_equals_slow(FAST_FORMS["lines and points"].encode())
    assert data.warnings == ["mem.obj: ignored 3 line/point elements (only faces are baked)"]


# Files the fast path declines; read_obj gives the slow path's result.
DECLINED = {
    "continuation": "v 0 0 \\\n 0\nv 1 0 0\nv 0 1 0\nf 1 2 \\\n3\n",
    "trailing comment": "v 0 0 0 # origin\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    "comment after face": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 # tri\n",
    "colour on some v lines": "v 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    "indented": "  v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    "fourth corner field": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/// 2/// 3///\n",
    "word after coordinates": "v 0 0 0 red\nv 1 0 0 red\nv 0 1 0 red\nf 1 2 3\n",
    "plus sign index": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf +1 2 3\n",
    "underscore index": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0_1 2 3\n",  # int() reads 1
    "unit separator": "v 0 0 0\nv 1\x1f0 0\nv 0 1 0\nf 1 2 3\n",
    "nbsp": "v 0 0 0\nv 1\xa00 0\nv 0 1 0\nf 1 2 3\n",
    "line separator": "v 0 0 0\nv 1 0 0\u2028v 0 1 0\nf 1 2 3\n",
}


@pytest.mark.parametrize("name", sorted(DECLINED))
def test_obj_files_the_fast_path_declines_read_as_the_slow_path_reads_them(tmp_path, name):
    path = tmp_path / "m.obj"
    path.write_bytes(DECLINED[name].encode())
    data, text, encoding = objmod._read_text(path)
    assert objmod._read_fast(path, data, text, encoding) is None
    _assert_identical(objmod.read_obj(path), objmod._read_slow(path, text))


@pytest.mark.parametrize("content, message", [
    ("v 0 0 0\nv 1 0 0\nf 1 2 3\n", "line 3: vertex index 3 out of range (2 defined so far)"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", "line 4: vertex index 0 is not valid"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -4 2 3\n", "line 4: vertex index -4 out of range"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/1 3/1\n", "line 4: texture index 1 out of range"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//2 3//1\n", "normal index 2 out of range"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "line 4: a face needs 3 or more corners"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\n", "line 5: vertex index 4 out of range"),
    ("v 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nf 1 2 4\r\n", "line 4: vertex index 4"),
    ("v 0 0 0\nv 1 0 0\nv 0 1\nf 1 2 3\n", "line 3: malformed 'v' statement"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 x\nf 1 2 3\n", "line 3: malformed 'v' statement"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -\n", "line 4: bad vertex index '-'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 1-2\n", "line 4: bad vertex index '1-2'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 /3\n", "line 4: bad vertex index ''"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n", "out of range"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nusemtl\n", "line 5: malformed 'usemtl' statement"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", "mesh has no faces"),
    ("vt 0 0\nf 1 2 3\n", "line 2: vertex index 1 out of range"),
    ("# nothing\n", "no vertices"),
])
def test_obj_errors_are_the_slow_paths(tmp_path, content, message):
    """The fast path never reads a file the slow path rejects; the message is the slow path's."""
    path = tmp_path / "bad.obj"
    path.write_text(content, newline="")
    data, text, encoding = objmod._read_text(path)
    assert objmod._read_fast(path, data, text, encoding) is None
    with pytest.raises(InputError, match=str(path)) as info:
        objmod.read_obj(path)
    assert message in str(info.value)


def test_obj_large_triangle_file_takes_the_fast_path(monkeypatch, tmp_path):
    """An ordinary exporter's file (the bunny's form) is read without the slow path."""
    rng = np.random.default_rng(5)
    vertices = rng.normal(size=(500, 3))
    faces = rng.integers(1, 501, size=(900, 3))
    text = "# Meshlab\n" + "".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in vertices) \
        + "".join(f"f {a} {b} {c}\n" for a, b, c in faces)
    path = tmp_path / "big.obj"
    path.write_text(text)
    monkeypatch.setattr(objmod, "_read_slow", lambda *a: pytest.fail("slow path ran"))
    data = objmod.read_obj(path)
    np.testing.assert_allclose(data.vertices, vertices, atol=5e-7)
    np.testing.assert_array_equal(data.faces, faces - 1)


# --- Property tests: generated files in the fast forms, then the same files with one line spoilt.

HYP = settings(max_examples=300, deadline=None, derandomize=True,
               suppress_health_check=[HealthCheck.too_slow])

_number = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(-1e6, 1e6).map(lambda x: f"{x:.6f}"),
    st.floats(allow_nan=False, allow_infinity=False).map(lambda x: f"{x:.4E}"),
    st.integers(-10**30, 10**30).map(str),
    st.sampled_from(["-0", "+1", ".5", "5.", "1e-320", "0.1", "-0.0", "1_000", "INF", "-NaN"]),
)


@st.composite
def _obj_files(draw):
    """An OBJ file in the fast path's forms: widths fixed per kind, every index in range."""
    widths = {"v": draw(st.sampled_from([3, 4, 6])), "vt": draw(st.integers(1, 3)), "vn": 3}
    sep = draw(st.sampled_from([" ", "\t", "  ", " \t"]))
    counts = {"v": 0, "vt": 0, "vn": 0}
    lines = []
    for kind in draw(st.lists(st.sampled_from(
            ["v", "v", "v", "vt", "vn", "f", "f", "f", "usemtl", "mtllib", "#", "", "g", "s", "l"]),
            min_size=1, max_size=40)):
        if kind in counts:
            numbers = draw(st.lists(_number, min_size=widths[kind], max_size=widths[kind]))
            lines.append(sep.join([kind, *numbers]))
            counts[kind] += 1
        elif kind == "f" and counts["v"]:
            corners = []
            form = draw(st.sampled_from(["v", "v/vt", "v//vn", "v/vt/vn", "any"]))
            for _ in range(draw(st.integers(3, 6))):
                fields = []
                for key in ("v", "vt", "vn"):
                    wanted = form == "any" and draw(st.booleans()) or key in form.split("/")
                    if key == "v" or (wanted and counts[key]):
                        count = counts[key]
                        index = draw(st.integers(1, count))
                        fields.append(str(index) if draw(st.booleans()) else str(index - count - 1))
                    else:
                        fields.append("")
                corners.append("/".join(fields).rstrip("/") if draw(st.booleans())
                               else "/".join(fields))
            lines.append(sep.join(["f", *corners]) + draw(st.sampled_from(["", " ", "\t"])))
        elif kind == "usemtl":
            lines.append("usemtl " + draw(st.sampled_from(["a", "b", "c d", "a # c"])))
        elif kind == "mtllib":
            lines.append("mtllib lib.mtl")
        elif kind == "#":
            lines.append("# " + draw(st.text(max_size=10).filter(lambda s: "\\" not in s
                                                                 and s.isprintable())))
        elif kind == "g":
            lines.append("g group" + draw(st.sampled_from(["", " x"])))
        elif kind == "s":
            lines.append("s " + draw(st.sampled_from(["1", "off"])))
        elif kind == "l" and counts["v"]:
            lines.append("l 1 1")
    if not counts["v"]:
        lines.insert(0, sep.join(["v"] + ["0"] * widths["v"]))
    if not any(line.startswith("f") for line in lines):
        lines.append("f 1 -1 1")
    end = draw(st.sampled_from(["\n", "\r\n", "\r"]))
    return end.join(lines) + draw(st.sampled_from(["", end]))


def _same_or_both_reject(data: bytes):
    try:
        fast, slow = _paths(data)
    except InputError:  # binary content: the decoding both paths share
        return
    if isinstance(slow, InputError):
        assert fast is None, f"fast path read a file the slow path rejects: {slow}"
    elif fast is not None:
        _assert_identical(fast, slow)


@pytest.mark.slow
@HYP
@given(text=_obj_files())
def test_obj_fast_path_property(text):
    _fast_equals_slow(text.encode("utf-8"))


_junk = st.one_of(
    st.text(alphabet="vtnf0123456789 -/.#\\\t\r\n\x00\x0b\x0c\x1c\x1f\xa0\x85eE+_xusemtl",
            max_size=20),
    st.sampled_from(["f 1 2", "f 0 1 2", "f 1/1/1/1 2 3", "f -99 1 2", "v 1 2", "v", "f",
                     " f 1 2 3", "usemtl", "vt", "vn 1 2", "f 1//x 2 3", "f 1/ /2 3",
                     "f 99999999999999999999 1 2", "f 1 2 3\\", "v 1 2 3 4 5 6 7"]),
)


@pytest.mark.slow
@HYP
@given(text=_obj_files(), where=st.integers(0, 10**6), junk=_junk, replace=st.booleans())
def test_obj_fast_path_property_spoilt_files(text, where, junk, replace):
    """One line replaced or inserted: either both paths reject the file, or the fast path
    declines, or both give the same ObjData."""
    lines = text.split("\n")
    where %= len(lines)
    lines[where:where + replace] = [junk]
    _same_or_both_reject("\n".join(lines).encode("utf-8", errors="surrogateescape"))


@pytest.mark.slow
@HYP
@given(data=st.binary(max_size=300))
def test_obj_fast_path_property_arbitrary_bytes(data):
    _same_or_both_reject(data)


def test_a_byte_order_mark_does_not_hide_the_first_line(tmp_path):
    from aobake.obj import read_obj

    path = tmp_path / "bom.obj"
    path.write_bytes(b"\xef\xbb\xbfv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    data = read_obj(path)
    assert data.vertices.shape == (3, 3) and data.faces.tolist() == [[0, 1, 2]]


def test_a_scene_built_directly_is_checked():
    """aobake.Scene(...) with faces of the wrong shape or out of range: an InputError at
    construction, not an IndexError in the bake."""
    import aobake

    v = np.zeros((4, 3))
    n = np.zeros((4, 3))
    with pytest.raises(aobake.InputError, match="faces must be"):
        aobake.Scene(v, np.array([[0, 1, 2, 3]]), n, np.zeros((1, 3)))
    with pytest.raises(aobake.InputError, match="out of range"):
        aobake.Scene(v, np.array([[0, 1, 9]]), n, np.zeros((1, 3)))
    with pytest.raises(aobake.InputError, match="face_normals"):
        aobake.Scene(v, np.array([[0, 1, 2]]), n, np.zeros((2, 3)))


def test_far_from_origin_coordinates_quantised_by_float64_are_warned_of():
    """A mesh translated by 1e15: float64 spaces coordinates 0.125 apart there, a visible
    fraction of unit triangles; at 1e6 the step (1e-10) is not."""
    import trimesh

    from aobake.scene import make_scene

    box = trimesh.creation.box()
    far = make_scene(box.vertices + 1e15, box.faces)
    assert any("quantised by float64" in w for w in far.warnings)
    near = make_scene(box.vertices + 1e6, box.faces)
    assert not any("quantised" in w for w in near.warnings)


def test_normalize_is_the_linalg_norm_formulation_bit_for_bit():
    """vectors.normalize's column-by-column length is np.linalg.norm's, bit for bit, also
    for zero, subnormal, huge (overflowing) and non-finite rows and any leading shape."""
    from aobake.vectors import normalize

    def reference(vectors):
        length = np.linalg.norm(vectors, axis=-1, keepdims=True)
        ok = np.isfinite(length) & (length > 0)
        return np.divide(vectors, length, out=np.zeros(np.shape(vectors)), where=ok), length

    rng = np.random.default_rng(8)
    special = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 1e308, 1e-308, 5e-324, 1e154, 3.0])
    with np.errstate(all="ignore"):
        for trial in range(100):
            a = rng.normal(size=(int(rng.integers(0, 300)), 3)) * 10.0 ** rng.integers(-300, 300)
            mask = rng.random(a.shape) < 0.2
            a[mask] = rng.choice(special, size=int(mask.sum()))
            for vectors in (a, a.reshape(-1, 1, 3), np.asfortranarray(a), a[::2]):
                got, want = normalize(vectors), reference(vectors)
                assert all(x.shape == y.shape and x.tobytes() == y.tobytes()
                           for x, y in zip(got, want))


# --- The compiled block parsers (aobake/_obj.c) against their numpy twins -----------------------

def _compiled():
    """The compiled module (the ``kernel`` fixture's, for tests that hypothesis drives)."""
    from aobake import _native

    if not _native.built():
        pytest.skip("aobake._kernels was not built (no C compiler at install)")
    return _native.kernels()


def _both_readers(data: bytes):
    """(compiled, numpy) _read_fast results for a file's bytes (None: declined)."""
    from aobake import _native

    text, encoding = objmod._decode("mem.obj", data)
    compiled = objmod._read_fast("mem.obj", data, text, encoding)
    with _native.numpy_only():
        plain = objmod._read_fast("mem.obj", data, text, encoding)
    return compiled, plain


def _same_either_way(data: bytes):
    try:
        compiled, plain = _both_readers(data)
    except InputError:  # binary content: the decoding both share
        return
    assert (compiled is None) == (plain is None)
    if compiled is not None:
        _assert_identical(compiled, plain)


@pytest.mark.parametrize("name", sorted(FAST_FORMS))
def test_obj_kernels_read_the_fast_forms_as_numpy_does(kernel, name):
    content = FAST_FORMS[name]
    _same_either_way(content.encode() if content is not None else b"v 0 0 0\nf 1 1 1\n")


@pytest.mark.slow
@HYP
@given(text=_obj_files(), where=st.integers(0, 10**6), junk=_junk, replace=st.booleans())
def test_obj_kernels_property_spoilt_files(text, where, junk, replace):
    _compiled()
    lines = text.split("\n")
    _same_either_way(text.encode())
    where %= len(lines)
    lines[where:where + replace] = [junk]
    _same_either_way("\n".join(lines).encode("utf-8", errors="surrogateescape"))


# Spellings at the edges of the exact path (19 significant digits, 2^53, 10^22) and past it
# (Python's own parser), signed zeros, subnormals, overflow; and what the kernel declines.
_EDGE_FLOATS = ["0", "-0", "+0.0", "-0.000", "1", "-1.", ".5", "5.", "0.1", "0.30000000000000004",
                "9007199254740992", "9007199254740993", "9007199254740993.0", "1e22", "1e23",
                "9007199254740991e22", "9007199254740993e-22", "1234567890123456789",
                "12345678901234567890", "0.00000000000000000000000123", "123456789012345678901234567890",
                "1e-320", "4.9406564584124654e-324", "2.4703282292062327e-324", "1e-400",
                "1.7976931348623157e308", "1e309", "-1e400", "2.2250738585072011e-308",
                "000000000000000000000000001.5", "1.5e0000000000000000000001", "1E+05", "1e-05",
                "3.141592653589793238462643383279", "-2.5E-3", "+3e+2"]


@pytest.mark.parametrize("token", _EDGE_FLOATS)
def test_obj_floats_kernel_is_python_float(kernel, token):
    block = f"v {token} 1 {token}\nv 0 {token} 2\n".encode()
    width, values = kernel.obj_floats(block, 2, b"v", 3)
    got = np.frombuffer(values, np.float64).reshape(2, width)
    want = np.array([[float(token), 1.0, float(token)], [0.0, float(token), 2.0]])
    assert got.tobytes() == want.tobytes()


@pytest.mark.parametrize("block, count", [
    (b"v 1 2 inf\n", 1), (b"v nan 1 2\n", 1), (b"v 1_0 1 2\n", 1), (b"v 1 2\n", 1),
    (b"v 1 2 3\nv 1 2\n", 2), (b"v 1 2 3 # c\n", 1), (b"v 1 2 3\n", 2), (b"v 1 2 3\nv 1 2 3\n", 1),
    (b"v . 1 2\n", 1), (b"v 1e 1 2\n", 1), (b"v 1e+ 1 2\n", 1), (b"v 1 2 3\xa0\n", 1),
    (b"vn 1 2 3\n", 1), (b"v 1 2 3", 1), (b"v 1 2 3\nv\n", 2), (b"v 0x10 1 2\n", 1),
])
def test_obj_floats_kernel_declines_what_it_does_not_read(kernel, block, count):
    assert kernel.obj_floats(block, count, b"v", 3) is None


@pytest.mark.slow
@settings(max_examples=2000, deadline=None, derandomize=True)
@given(st.lists(st.one_of(
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.floats(allow_nan=False, allow_infinity=False).map(lambda x: f"{x:.17e}"),
    st.floats(-1e3, 1e3).map(lambda x: f"{x:.{abs(hash(x)) % 25}f}"),
    st.tuples(st.text("0123456789", min_size=1, max_size=30), st.text("0123456789", max_size=30),
              st.integers(-340, 340)).map(lambda t: f"{t[0]}.{t[1]}e{t[2]}"),
), min_size=3, max_size=3))
def test_obj_floats_kernel_property(tokens):
    width, values = _compiled().obj_floats(("v " + " ".join(tokens) + "\n").encode(), 1, b"v", 3)
    assert np.frombuffer(values, np.float64).tobytes() == \
        np.array([float(t) for t in tokens]).tobytes()


@pytest.mark.parametrize("block", [
    b"f 1 2 3\n", b"f 1/2 2/3 3/4\n", b"f 1//3 2//3 3//1\n", b"f 1/2/3 -1/-2/-3 4/5/6 7/8/9\n",
    b"f 1/ 2// 3/4/\n", b"f\t1 \t2  3 \t\nf 4 5 6\r", b"f 000000000000000001 2 -00000000000000003\n",
    b"f 1 2\n", b"f 1 2\nf \n",
])
def test_obj_corners_kernel_matches_numpy(kernel, block):
    count = block.count(b"f")
    compiled = objmod._corners(block, count, kernel)
    assert kernel.obj_corners(block, count) is not None
    plain = objmod._corners(block, count)
    for a, b in zip(compiled, plain):
        assert (a.dtype, a.shape, a.tobytes()) == (b.dtype, b.shape, b.tobytes())


@pytest.mark.parametrize("block", [
    b"f 1 2 3 # c\n", b"f 1/2/3/4 2 3\n", b"f /2 1 2\n", b"f 1 2 -\n", b"f 1 2 1-2\n",
    b"f --1 2 3\n", b"f 1 2 0000000000000000001\n", b"f 1 2 3", b"f 1 2 3\nf 1 f 2\n",
    b" f 1 2 3\n", b"f 1 2 +3\n", b"f \n",
])
def test_obj_corners_kernel_declines_what_it_does_not_read(kernel, block):
    assert kernel.obj_corners(block, max(1, block.count(b"\n"))) is None


def test_obj_vertex_normals_are_np_add_at_sums():
    """scene._obj_normals sums each vertex's corner normals as np.add.at does (in corner
    order, from 0.0): the same bits, corners without a vn left out."""
    from aobake.scene import _obj_normals

    rng = np.random.default_rng(3)
    normals = rng.normal(size=(40, 3)) * np.exp(rng.normal(size=(40, 3)) * 5)
    faces = rng.integers(1, 10, size=(300, 3))
    has = rng.random((300, 3)) < 0.8
    text = GRID + "".join(f"vn {x!r} {y!r} {z!r}\n" for x, y, z in normals.tolist()) + "".join(
        "f " + " ".join(f"{v}//{rng.integers(1, 41)}" if h else str(v) for v, h in zip(f, hs))
        + "\n" for f, hs in zip(faces, has))
    data = _fast_equals_slow(text.encode())
    corners = data.faces_normal.ravel()
    want = np.zeros_like(data.vertices)
    np.add.at(want, data.faces.ravel()[corners >= 0], data.normals[corners[corners >= 0]])
    assert _obj_normals(data).tobytes() == want.tobytes()
