"""What occludes what (``aobake.groups``): faces selected by OBJ object / group / material
and glTF node / mesh / material names, with glob patterns.

* patterns match as documented (globs, ``kind:`` prefixes, ``*`` only named faces), and a
  pattern that matches nothing is refused with the names the file has;
* an excluded object changes nothing: the bake equals the bake of the file without it, bit
  for bit;
* a receive-only object casts nothing: the others' values equal those of the file without
  it, bit for bit, and it is baked;
* an occluder-only object is not baked (0 rays; its texels not covered) and occludes as
  before: the others' values equal the plain bake's, bit for bit;
* the report lists what each name did; a setup that leaves every point at 0 warns;
* high-to-low: cage rays pass through an occluder-only card, which still darkens the
  source; an excluded card changes nothing.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import aobake
from aobake import groups
from aobake.api import bake_grouped
from aobake.errors import InputError
from aobake.scene import load_scene
from aobake.targets import TexelTarget, VertexTarget
from aobake.targets.projected import ProjectedVertexTarget

THREADS = 2


def floor():
    """A 4 x 4 floor at z = 0 in 8 x 8 squares (vertices under the ball too)."""
    x, y = np.meshgrid(np.linspace(-2, 2, 9), np.linspace(-2, 2, 9))
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(81)], axis=1)
    i = (np.arange(8)[:, None] * 9 + np.arange(8)[None, :]).ravel()
    faces = np.concatenate([np.stack([i, i + 1, i + 10], 1), np.stack([i, i + 10, i + 9], 1)])
    return trimesh.Trimesh(vertices, faces, process=False)


def ball():
    return trimesh.creation.icosphere(subdivisions=1, radius=0.5).apply_translation([0, 0, 0.6])


def wall():
    return trimesh.creation.box([0.2, 4, 2]).apply_translation([2.5, 0, 1])


def write_obj(path, parts):
    """OBJ with one ``o`` (and ``g`` and ``usemtl``) per part: parts are (name, mesh,
    group, material) in file order."""
    lines, offset = [], 0
    for name, mesh, group, material in parts:
        lines.append(f"o {name}")
        lines.append(f"g {group}")
        lines.append(f"usemtl {material}")
        lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in mesh.vertices.tolist()]
        lines += [f"f {a + 1 + offset} {b + 1 + offset} {c + 1 + offset}"
                  for a, b, c in mesh.faces.tolist()]
        offset += len(mesh.vertices)
    path.write_text("\n".join(lines) + "\n")
    return path


PARTS = {"floor": ("floor", floor, "ground", "concrete"),
         "ball": ("ball", ball, "props", "rubber"),
         "wall": ("wall", wall, "props", "brick")}


def scene_file(tmp_path, names, stem="scene"):
    parts = [(PARTS[n][0], PARTS[n][1](), PARTS[n][2], PARTS[n][3]) for n in names]
    return write_obj(tmp_path / f"{stem}.obj", parts)


def vertex_bake(mesh, **selection):
    return bake_grouped(mesh, VertexTarget(), rays=64, seed=3, threads=THREADS,
                               **selection)


# --------------------------------------------------------------------------- patterns


def test_patterns_match_as_documented(tmp_path):
    scene = load_scene(scene_file(tmp_path, ["floor", "ball", "wall"]))
    count = {name: len(PARTS[name][1]().faces) for name in PARTS}

    def faces(pattern):
        return int(groups.match(scene, pattern).sum())
    assert faces("ball") == count["ball"]
    assert faces("b*") == count["ball"] + count["wall"]  # ball, and the wall's material brick
    assert faces("object:b*") == count["ball"]
    assert faces("material:b*") == count["wall"]
    assert faces("props") == count["ball"] + count["wall"]  # the group
    assert faces("[fw]*") == count["floor"] + count["wall"]
    assert faces("?all") == count["ball"] + count["wall"]
    assert faces("BALL") == 0  # case-sensitive
    assert faces("*") == len(scene.faces)
    with pytest.raises(InputError, match=r"--exclude 'chair' matches no face's name .*"
                                         r"object 'floor', 'ball', 'wall'"):
        groups.apply(scene, groups.Selection(exclude=("chair",)))
    with pytest.raises(InputError, match="both receive-only and occluder-only"):
        groups.apply(scene, groups.Selection(receive_only=("props",),
                                             occluder_only=("ball",)))
    with pytest.raises(InputError, match="leaves no face"):
        groups.apply(scene, groups.Selection(exclude=("*",)))
    with pytest.raises(InputError, match="nothing to bake"):
        groups.apply(scene, groups.Selection(occluder_only=("*",)))
    with pytest.raises(InputError, match="nothing occludes"):
        groups.apply(scene, groups.Selection(receive_only=("*",)))


def test_unnamed_faces_are_not_matched_and_gltf_nodes_are(tmp_path):
    path = tmp_path / "plain.obj"
    floor().export(path)
    with pytest.raises(InputError, match="names no object"):
        groups.apply(load_scene(path), groups.Selection(exclude=("*",)))
    glb = trimesh.Scene()
    glb.add_geometry(floor(), node_name="floor_node", geom_name="floor_mesh")
    glb.add_geometry(ball(), node_name="ball_node", geom_name="ball_mesh")
    glb.export(tmp_path / "s.glb")
    scene = load_scene(tmp_path / "s.glb")
    assert groups.match(scene, "node:ball_*").sum() == len(ball().faces)
    assert groups.match(scene, "mesh:floor_mesh").sum() == len(floor().faces)


# --------------------------------------------------------------------------- roles


def test_an_excluded_object_changes_nothing(tmp_path):
    with_wall = scene_file(tmp_path, ["floor", "ball", "wall"], "with")
    without = scene_file(tmp_path, ["floor", "ball"], "without")
    a = vertex_bake(with_wall, exclude=("wall",))
    b = vertex_bake(without)
    n = len(b.positions)
    assert np.array_equal(a.ao[:n], b.ao) and np.array_equal(a.rays[:n], b.rays)
    assert not a.rays[n:].any()  # the wall's vertices: not baked
    faces = a.report["groups"]["faces"]
    assert faces["excluded"] == len(wall().faces) and faces["baked"] == len(b.faces)


def test_a_receive_only_object_casts_nothing(tmp_path):
    path = scene_file(tmp_path, ["floor", "wall", "ball"])
    alone = scene_file(tmp_path, ["floor", "wall"], "alone")
    a = vertex_bake(path, receive_only=("object:ball",))
    b = vertex_bake(alone)
    plain = vertex_bake(path)
    n = len(b.positions)
    assert np.array_equal(a.ao[:n], b.ao)  # the floor and the wall see no ball
    assert (a.rays[n:] > 0).all()  # the ball is baked
    under = np.linalg.norm(b.positions[:81, :2], axis=1) < 0.6
    assert a.ao[:81][under].min() > plain.ao[:81][under].max()  # the ball shaded them
    assert a.report["parameters"]["occluding_faces"] == len(b.faces)
    entry = next(e for e in a.report["groups"]["names"] if e["name"] == "ball")
    assert entry["receive_only"] == entry["faces"] == len(ball().faces)


@pytest.mark.slow
def test_an_occluder_only_object_is_not_baked(tmp_path):
    path = scene_file(tmp_path, ["floor", "ball", "wall"])
    a = vertex_bake(path, occluder_only=("ball",))
    plain = vertex_bake(path)
    start = len(floor().vertices)
    stop = start + len(ball().vertices)
    assert not a.rays[start:stop].any()  # not baked
    keep = np.r_[0:start, stop:len(plain.ao)]
    assert np.array_equal(a.ao[keep], plain.ao[keep])  # and it occludes as before
    # (seams off: the seam solve is global, its solution moves within its tolerance when
    # the ball's texels leave it)
    options = dict(rays=16, resolution=64, seams="off", threads=THREADS)
    texels = bake_grouped(path, TexelTarget(), occluder_only=("ball",), **options)
    full = aobake.bake_texels(path, **options)
    assert texels.covered.sum() < full.covered.sum()
    assert not (texels.covered & ~full.covered).any()
    common = texels.covered
    assert np.array_equal(texels.channels["ao"][common], full.channels["ao"][common])


def test_every_point_at_zero_warns(tmp_path):
    box = trimesh.creation.box([3, 3, 3]).apply_translation([0, 0, 0.6])
    path = write_obj(tmp_path / "boxed.obj", [("ball", ball(), "a", "m"),
                                              ("box", box, "b", "m")])
    res = vertex_bake(path, occluder_only=("box",))
    assert any("is 0 at every one" in w for w in res.report["warnings"])
    res = vertex_bake(path, exclude=("box",))
    assert not any("is 0 at every one" in w for w in res.report["warnings"])


# --------------------------------------------------------------------------- high-to-low


def test_cage_rays_pass_through_an_occluder_only_card(tmp_path):
    from test_studio import bumpy_sphere, low_sphere

    high, low = bumpy_sphere(), low_sphere()
    # a card 0.2 outside the bumps' tops on +z, inside the cage's reach of 0.35 x 2
    card = trimesh.Trimesh([[-0.4, -0.4, 1.3], [0.4, -0.4, 1.3], [0.4, 0.4, 1.3],
                            [-0.4, 0.4, 1.3]], [[0, 1, 2], [0, 2, 3]], process=False)
    source = trimesh.Trimesh(high.vertices, high.faces, process=False)
    path = write_obj(tmp_path / "source.obj", [("high", source, "a", "m"),
                                               ("card", card, "b", "m")])
    alone = write_obj(tmp_path / "alone.obj", [("high", source, "a", "m")])

    def bake(mesh, **selection):
        target = ProjectedVertexTarget(low, cage_offset=0.35)
        return bake_grouped(mesh, target, rays=64, threads=THREADS, **selection)
    base = bake(alone)
    landed = bake(path)  # the card catches the rays under it
    through = bake(path, occluder_only=("card",))
    excluded = bake(path, exclude=("card",))
    under = np.linalg.norm(landed.projection.points - base.projection.points, axis=1) > 1e-9
    assert under.any()
    assert np.array_equal(through.projection.points, base.projection.points)
    assert np.array_equal(excluded.ao, base.ao)
    assert through.ao[under].mean() < base.ao[under].mean()  # the card shades them
