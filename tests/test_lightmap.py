"""Lightmaps: analytic values texel by texel, vertex/texel agreement, seams,
round trips through the CLI, reproducibility and bad input."""

import functools
import json

import numpy as np
import pytest
import trimesh

from aobake.api import bake, bake_texels
from analytic import dof_for, z_bound
from conftest import run_cli
from readers import read_accessor, read_glb, read_image


def uv_quad(center, half, flip=False):
    """A square in z = center[2] with UVs covering [0,1]^2 (u along x, v along y)."""
    c = np.asarray(center, float)
    v = np.array([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]]) + c
    f = np.array([[0, 1, 2], [0, 2, 3]])
    if flip:
        f = f[:, ::-1]
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    return v, f, uv


def obj_text(parts):
    """OBJ with per-part UVs: parts = [(v, f, uv or None)]."""
    lines, base_v, base_t = [], 0, 0
    for v, f, uv in parts:
        lines += [f"v {x} {y} {z}" for x, y, z in v]
        if uv is not None:
            lines += [f"vt {a} {b}" for a, b in uv]
            lines += ["f " + " ".join(f"{i + 1 + base_v}/{i + 1 + base_t}" for i in tri) for tri in f]
            base_t += len(uv)
        else:
            lines += ["f " + " ".join(f"{i + 1 + base_v}" for i in tri) for tri in f]
        base_v += len(v)
    return "\n".join(lines) + "\n"


@pytest.fixture
def ceiling_obj(tmp_path):
    """Floor quad (with UVs, the baked surface) under a large ceiling at h = 1."""
    floor = uv_quad([0, 0, 0], 0.5)
    ceiling_v = np.array([[-5, -5, 1.0], [5, -5, 1.0], [5, 5, 1.0], [-5, 5, 1.0]])
    # The ceiling faces down; give it UVs outside the floor's square? It must not be baked
    # into the floor's texels: put its UVs on a degenerate point outside [0,1] is invalid,
    # so give it its own corner of UV space by shrinking the floor's UVs to the left half.
    fv, ff, fuv = floor
    fuv = fuv * [0.5, 1.0]
    cuv = np.array([[0.6, 0.1], [0.9, 0.1], [0.9, 0.4], [0.6, 0.4]])
    path = tmp_path / "ceiling.obj"
    path.write_text(obj_text([(fv, ff, fuv), (ceiling_v, np.array([[0, 2, 1], [0, 3, 2]]), cuv)]))
    return path


@pytest.mark.parametrize("sampler", ["random", "sobol"])
def test_floor_under_ceiling_texel_by_texel(ceiling_obj, sampler):
    h, d = 1.0, 2.3
    exact = (h / d) ** 2
    res = bake_texels(ceiling_obj, resolution=32, padding=0, texel_samples=2, rays=256,
                      max_distance=d, sampler=sampler, unwrap="never")
    ao, se = res.channels["ao"], res.channels["ao_stderr"]
    # The floor occupies u in [0, 0.5]: columns 0..15 of a 32-wide image.
    floor = np.zeros_like(res.covered)
    floor[:, :16] = True
    assert np.all(res.covered[floor])
    values, errors = ao[floor], se[floor]
    rays_per_sample = res.report["parameters"]["rays_per_texel_sample"]
    if sampler == "random":
        # Each texel averages 2 independent samples: normal statistic (n large).
        k = z_bound(values.size, None)
        bad = np.abs(values - exact) > k * errors
        assert not bad.any(), (values[bad][:5], errors[bad][:5])
    else:
        # Mean over texels (see test_analytic): texel samples are independent, so the
        # mean of N texels has sd sqrt(sum se^2) / N.
        k = z_bound(1, dof_for(sampler, rays_per_sample))
        assert abs(values.mean() - exact) <= k * np.sqrt(np.sum(errors ** 2)) / errors.size
    assert res.report["texture"]["texels_shared"] == 0
    assert res.report["texture"]["atlas"] == "mesh UVs"
    assert res.report["texture"]["charts"] is None  # only a new atlas has a chart count


@pytest.mark.slow
def test_vertex_and_texel_bakes_agree(tmp_path):
    # A flat floor grid (planar UVs, the compared surface) under a floating sphere: AO
    # varies smoothly over the floor and flat faces carry no faceting bias, so the
    # texel at a vertex's UV and the vertex itself estimate the same value.
    n = 24
    xs = np.linspace(-1, 1, n + 1)
    gx, gy = np.meshgrid(xs, xs)
    fv = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    idx = np.arange(gx.size).reshape(n + 1, n + 1)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    ff = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    fuv = np.stack([(gx.ravel() + 1) / 4, (gy.ravel() + 1) / 2], axis=1)  # u in [0, 0.5]
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.4)
    sv = sphere.vertices + [0.2, 0.1, 0.6]
    suv = np.stack([0.75 + 0.2 * sphere.vertices[:, 0] / 0.4, 0.5 + 0.4 * sphere.vertices[:, 1] / 0.4], 1)
    obj = tmp_path / "floor.obj"
    obj.write_text(obj_text([(fv, ff, fuv), (sv, sphere.faces, suv)]))
    verts = bake(obj, rays=512, sampler="random")
    res = 256
    # unwrap="never": the sphere's projected UVs overlap (front and back), the floor's do not.
    tex = bake_texels(obj, resolution=res, padding=2, texel_samples=1, rays=512,
                      sampler="random", unwrap="never")
    floor = np.arange(len(fv))
    col = np.clip((fuv[:, 0] * res).astype(int), 0, res - 1)
    row = np.clip(((1 - fuv[:, 1]) * res).astype(int), 0, res - 1)
    ok = tex.covered[row, col]
    assert ok.mean() > 0.9
    a_t, s_t = tex.channels["ao"][row, col][ok], tex.channels["ao_stderr"][row, col][ok]
    a_v, s_v = verts.ao[floor][ok], verts.ao_stderr[floor][ok]
    diff = a_t - a_v
    se = np.hypot(s_t, s_v)
    assert np.all(se > 0)
    k = z_bound(len(diff), None)
    assert np.all(np.abs(diff) <= k * se), np.abs(diff / se).max()
    # No systematic offset: the mean difference within its stderr (points and texel
    # samples are independent: sd of the mean difference = sqrt(sum se^2) / N).
    assert abs(diff.mean()) <= z_bound(1, None) * np.sqrt(np.sum(se ** 2)) / se.size


def _bilinear(img, uv):
    h, w = img.shape
    x = uv[:, 0] * w - 0.5
    y = (1 - uv[:, 1]) * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    x0, x1 = np.clip(x0, 0, w - 1), np.clip(x0 + 1, 0, w - 1)
    y0, y1 = np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1)
    return ((1 - fx) * (1 - fy) * img[y0, x0] + fx * (1 - fy) * img[y0, x1]
            + (1 - fx) * fy * img[y1, x0] + fx * fy * img[y1, x1])


def _seam_midpoints(atlas):
    """UV midpoints of each seam edge on both sides: (uv_a (e, 2), uv_b (e, 2))."""
    pos_faces = atlas.source_vertex[atlas.faces]
    edges = {}
    for fi, (tri, ptri) in enumerate(zip(atlas.faces, pos_faces)):
        for a, b in ((0, 1), (1, 2), (2, 0)):
            key = tuple(sorted((ptri[a], ptri[b])))
            edges.setdefault(key, []).append((tri[a], tri[b], ptri[a]))
    ua, ub = [], []
    for key, sides in edges.items():
        if len(sides) != 2:
            continue
        (a0, a1, pa), (b0, b1, pb) = sides
        if pa != pb:
            b0, b1 = b1, b0
        mid_a = 0.5 * (atlas.uv[a0] + atlas.uv[a1])
        mid_b = 0.5 * (atlas.uv[b0] + atlas.uv[b1])
        if np.linalg.norm(mid_a - mid_b) > 1e-6:  # a seam: the edge is in two places
            ua.append(mid_a)
            ub.append(mid_b)
    return np.array(ua), np.array(ub)


@functools.lru_cache(maxsize=None)
def _seam_bakes():
    """A sphere under a plate (AO varies over it) on a fresh atlas, baked with padding 0 and 4
    (cached: both seam tests read the same bakes and the padded atlas's seams)."""
    sphere = trimesh.creation.uv_sphere(radius=1.0, count=[24, 24])
    plate = trimesh.creation.box(extents=[0.8, 0.8, 0.1])
    plate.apply_translation([0, 0, 1.3])  # some occlusion so AO varies over the sphere
    mesh = trimesh.util.concatenate([sphere, plate])
    results = {p: bake_texels(mesh, resolution=128, padding=p, texel_samples=4, rays=256,
                              sampler="random", unwrap="always") for p in (0, 4)}
    return results, _seam_midpoints(results[4].atlas)


@pytest.mark.slow
@pytest.mark.parametrize("padding", [4, 0], ids=["padded-seams-agree", "unpadded-gutter-shows"])
def test_seams_agree_after_padding_and_gutter_shows_without(padding):
    results, (ua, ub) = _seam_bakes()
    assert len(ua) > 20
    res = results[padding]
    ao, se = res.channels["ao"], res.channels["ao_stderr"]
    a, b = _bilinear(ao, ua), _bilinear(ao, ub)
    err = np.hypot(_bilinear(se, ua), _bilinear(se, ub))
    # A seam sample reads texels up to ~1.5 texels from the edge on each side:
    # the geometric gradient over that distance is far below the noise at 128^2.
    z = np.abs(a - b) / np.maximum(err, 1e-12)
    if padding:
        assert np.all(z <= z_bound(len(z), None)), z.max()
    else:
        # Without padding, bilinear lookups at chart edges read empty gutter texels.
        assert np.max(z) > z_bound(len(z), None)


@pytest.mark.slow
def test_reproducible_textures(ceiling_obj):
    opts = dict(resolution=24, padding=2, texel_samples=3, rays=32, max_distance=2.0,
                quantities=("ao", "obscurance", "bent-normal"), unwrap="never")
    runs = [bake_texels(ceiling_obj, threads=t, chunk_rays=c, **opts)
            for t, c in ((1, 65536), (2, 65536), (2, 50))]
    for other in runs[1:]:
        for name, image in runs[0].channels.items():
            assert np.array_equal(image, other.channels[name]), name


def test_exr_channels_and_header_round_trip(ceiling_obj, tmp_path):
    out = tmp_path / "ao.exr"
    res = run_cli(ceiling_obj, "--out", out, "--resolution", "16x8", "--rays", 16, "-q", "ao",
              "-q", "obscurance", "-q", "bent-normal", "--no-unwrap", "--quiet")
    assert res.exit_code == 0, res.output
    pixels, names, attrs = read_image(out)
    assert pixels.shape == (8, 16, len(names))
    expected = {"ao", "ao_stderr", "ao_ci_low", "ao_ci_high", "obscurance", "obscurance_stderr",
                "obscurance_ci_low", "obscurance_ci_high", "bent_normal.X", "bent_normal.Y",
                "bent_normal.Z", "bent_normal_stderr", "rays", "coverage"}
    assert set(names) == expected
    angle_se = pixels[..., names.index("bent_normal_stderr")]
    assert np.all(np.isfinite(angle_se)) and angle_se.min() >= 0 and angle_se.max() <= np.pi / 2
    meta = json.loads(attrs["aobake:metadata"])
    assert meta["config"]["rays"] == 16
    assert "1 = fully open" in meta["conventions"]["ao"]
    assert attrs["oiio:format"] == "float"
    assert not (tmp_path / "ao.obj").exists()  # own UVs: no new atlas to write
    ao = pixels[..., names.index("ao")]
    assert np.all((ao >= 0) & (ao <= 1))
    res = run_cli(ceiling_obj, "--out", tmp_path / "h.exr", "--resolution", 8, "--rays", 8,
              "--half", "--no-unwrap", "--quiet")
    assert res.exit_code == 0
    _, names, attrs = read_image(tmp_path / "h.exr")
    formats = dict(zip(names, attrs["oiio:channelformats"]))
    assert formats.pop("rays") == "float" and set(formats.values()) == {"half"}


@pytest.mark.parametrize("ext, depth", [(".png", 8), (".png", 16), (".tif", 16)])
def test_ldr_bit_depths_read_back_exactly(ceiling_obj, tmp_path, ext, depth):
    out = tmp_path / f"ao{ext}"
    rep = tmp_path / "r.json"
    res = run_cli(ceiling_obj, "--out", out, "--resolution", 16, "--rays", 16, "--bit-depth", depth,
              "--no-unwrap", "--quiet", "--report", rep)
    assert res.exit_code == 0, res.output
    exr = tmp_path / "ao.exr"
    run_cli(ceiling_obj, "--out", exr, "--resolution", 16, "--rays", 16, "--no-unwrap", "--quiet")
    pixels, names, _ = read_image(out)
    ref, ref_names, _ = read_image(exr)
    top = 2**depth - 1
    stored = np.rint(pixels * top)
    expect = np.rint(np.clip(ref[..., ref_names.index("ao")].astype(np.float64), 0, 1) * top)
    assert np.array_equal(stored[..., 0], expect) and np.array_equal(stored[..., 1], expect)
    cov = np.rint(np.clip(ref[..., ref_names.index("coverage")].astype(np.float64), 0, 1) * top)
    assert np.array_equal(stored[..., 3], cov)


@pytest.mark.slow
def test_glb_lightmap_reloads_with_occlusion_texture(tmp_path):
    torus = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3)
    src = tmp_path / "t.ply"
    torus.export(src)
    out = tmp_path / "ao.glb"
    res = run_cli(src, "--out", out, "--target", "texels", "--resolution", 64, "--rays", 8, "--quiet")
    assert res.exit_code == 0, res.output
    gltf, blob = read_glb(out)
    material = gltf["materials"][0]
    assert material["occlusionTexture"]["texCoord"] == 0
    prim = gltf["meshes"][0]["primitives"][0]
    uv = read_accessor(gltf, blob, prim["attributes"]["TEXCOORD_0"])
    assert uv.min() >= 0 and uv.max() <= 1
    loaded = trimesh.load(out)
    assert len(loaded.to_geometry().faces) == len(torus.faces)


@pytest.mark.slow
def test_new_atlas_writes_mesh_beside_output(tmp_path, box_ply):
    out = tmp_path / "ao.png"
    res = run_cli(box_ply, "--out", out, "--resolution", 128, "--rays", 8, "--quiet")
    assert res.exit_code == 0, res.output
    mesh_out = tmp_path / "ao.obj"
    assert mesh_out.exists()
    from aobake.obj import read_obj

    data = read_obj(mesh_out)
    assert data.faces_uv is not None and len(data.faces) == 12
    assert data.uv.min() >= 0 and data.uv.max() <= 1


@pytest.mark.parametrize("args, message, code", [
    (["--resolution", "0"], "at least 1x1", 2),  # malformed option: usage error
    (["--resolution", "100000"], "GiB", 1),  # well-formed, but too big for this machine
    (["--resolution", "12000x12000", "--texel-samples", "64"], "GiB", 1),
    (["--resolution", "abc"], "N or WxH", 2),
    (["--no-unwrap"], "no UVs and --no-unwrap", 1),
])
@pytest.mark.slow
def test_bad_texture_options(tmp_path, box_ply, args, message, code):
    out = tmp_path / "ao.exr"
    res = run_cli(box_ply, "--out", out, "--rays", 4, *args)
    assert res.exit_code == code, res.output
    assert message in res.output and "Traceback" not in res.output
    if code == 1:
        assert len(res.output.strip().splitlines()) == 1
    assert not out.exists() and not (tmp_path / "ao.obj").exists()


@pytest.mark.slow
def test_unwritable_output_path(tmp_path, box_ply):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        res = run_cli(box_ply, "--out", locked / "ao.exr", "--resolution", 8, "--rays", 4)
        import os

        if os.access(locked, os.W_OK):  # running as root: permissions do not bind
            pytest.skip("directory permissions are not enforced for this user")
        assert res.exit_code == 1 and "Traceback" not in res.output
        assert list(locked.iterdir()) == []
    finally:
        locked.chmod(0o700)
    res = run_cli(box_ply, "--out", tmp_path / "missing" / "ao.exr", "--resolution", 8, "--rays", 4)
    assert res.exit_code == 1 and "does not exist" in res.output


@pytest.mark.slow
def test_output_on_read_only_filesystem(box_ply):
    # /proc refuses new files even for root: the write itself fails, cleanly.
    res = run_cli(box_ply, "--out", "/proc/aobake-test.exr", "--resolution", 8, "--rays", 4)
    assert res.exit_code == 1, res.output
    assert "Traceback" not in res.output and len(res.output.strip().splitlines()) == 1


@pytest.mark.slow
def test_glb_keeps_base_colour_and_uvs_with_new_atlas(tmp_path):
    from PIL import Image

    Image.new("RGB", (4, 4), (200, 30, 30)).save(tmp_path / "albedo.png")
    (tmp_path / "m.mtl").write_text("newmtl red\nKd 0.8 0.1 0.1\nmap_Kd albedo.png\n")
    v, f, uv = uv_quad([0, 0, 0], 1.0)
    # Two quads sharing the same UV square: overlapping UVs force a new atlas.
    v2 = np.vstack([v, v + [0, 0, 0.5]])
    f2 = np.vstack([f, f + 4])
    uv2 = np.vstack([uv, uv])
    body = obj_text([(v2, f2, uv2)])
    (tmp_path / "m.obj").write_text("mtllib m.mtl\nusemtl red\n" + body)
    out = tmp_path / "ao.glb"
    rep = tmp_path / "r.json"
    res = run_cli(tmp_path / "m.obj", "--out", out, "--target", "texels", "--resolution", 64,
              "--padding", 2, "--rays", 8, "--report", rep)
    assert res.exit_code == 0, res.output
    report = json.loads(rep.read_text())
    assert report["texture"]["uv_check"]["overlapping_texels"] > 0  # the overlap is reported
    assert report["texture"]["atlas"] == "xatlas" and report["texture"]["charts"] >= 1
    assert any("cannot be baked" in w for w in report["warnings"])
    gltf, blob = read_glb(out)
    material = gltf["materials"][0]
    assert material["occlusionTexture"]["texCoord"] == 1
    pbr = material["pbrMetallicRoughness"]
    assert pbr["baseColorTexture"]["texCoord"] == 0
    np.testing.assert_allclose(pbr["baseColorFactor"], [0.8, 0.1, 0.1, 1.0])
    prim = gltf["meshes"][0]["primitives"][0]
    base = read_accessor(gltf, blob, prim["attributes"]["TEXCOORD_0"])
    # The input's own UVs, flipped to glTF's top-left origin: exactly the corners of [0,1]^2.
    assert set(np.round(base.ravel(), 6)) == {0.0, 1.0}
    atlas = read_accessor(gltf, blob, prim["attributes"]["TEXCOORD_1"])
    assert atlas.min() >= 0 and atlas.max() <= 1 and len(np.unique(atlas, axis=0)) > 4


@pytest.mark.slow
def test_public_api_exports_the_lightmap_baker():
    import aobake

    res = aobake.bake_texels(trimesh.creation.box(), resolution=64, rays=8, padding=1)
    assert isinstance(res, aobake.TexelResult)
    assert res.channels["ao"].shape == (64, 64) and res.atlas.new


def test_glb_keeps_every_material_of_a_multi_material_obj(tmp_path):
    """Each material of the input becomes a primitive with its own base colour and the shared
    AO occlusion texture; faces keep their material; faces before any usemtl get white."""
    from PIL import Image

    Image.new("RGB", (4, 4), (20, 200, 30)).save(tmp_path / "green.png")
    (tmp_path / "m.mtl").write_text("newmtl red\nKd 0.8 0.1 0.1\n"
                                    "newmtl green\nKd 1 1 1\nmap_Kd green.png\n")
    v, f, uv = uv_quad([0, 0, 0], 0.5)
    # Three quads side by side in their own UV thirds: valid own UVs, no new atlas.
    parts = []
    for i in range(3):
        parts.append((v + [1.2 * i, 0, 0], f, uv * [1 / 3, 1] + [i / 3, 0]))
    text = obj_text(parts).splitlines()
    # insert usemtl statements: quad 0 before any (white), quad 1 red, quad 2 green
    faces = [i for i, line in enumerate(text) if line.startswith("f ")]
    assert len(faces) == 6
    text.insert(faces[4], "usemtl green")
    text.insert(faces[2], "usemtl red")
    (tmp_path / "m.obj").write_text("mtllib m.mtl\n" + "\n".join(text) + "\n")
    out = tmp_path / "ao.glb"
    res = run_cli(tmp_path / "m.obj", "--out", out, "--target", "texels", "--resolution", 48,
              "--padding", 1, "--rays", 8, "--quiet")
    assert res.exit_code == 0, res.output
    gltf, blob = read_glb(out)
    primitives = gltf["meshes"][0]["primitives"]
    assert len(primitives) == 3 and len(gltf["materials"]) == 3
    occlusion = {m["occlusionTexture"]["index"] for m in gltf["materials"]}
    assert len(occlusion) == 1  # one AO atlas shared by every material
    by_name = {}
    for prim in primitives:
        material = gltf["materials"][prim["material"]]
        indices = read_accessor(gltf, blob, prim["indices"]).reshape(-1, 3)
        positions = read_accessor(gltf, blob, prim["attributes"]["POSITION"])
        by_name[material["name"]] = (material, positions[indices].mean(axis=(0, 1)), len(indices))
    assert set(by_name) == {"red", "green", "default"}
    red, green, white = by_name["red"], by_name["green"], by_name["default"]
    assert all(part[2] == 2 for part in (red, green, white))  # two triangles each
    # each material sits on its own quad (centres at x = 0, 1.2, 2.4)
    np.testing.assert_allclose([white[1][0], red[1][0], green[1][0]], [0, 1.2, 2.4], atol=1e-6)
    np.testing.assert_allclose(red[0]["pbrMetallicRoughness"]["baseColorFactor"], [0.8, 0.1, 0.1, 1])
    assert "baseColorTexture" not in red[0]["pbrMetallicRoughness"]
    assert green[0]["pbrMetallicRoughness"]["baseColorTexture"]["texCoord"] == 0
    assert white[0]["pbrMetallicRoughness"]["baseColorFactor"] == [1.0, 1.0, 1.0, 1.0]
    loaded = trimesh.load(out)  # a viewer-grade loader reads all three
    assert len(loaded.geometry) == 3


@pytest.mark.slow
def test_new_atlas_in_a_non_square_image(tmp_path, box_ply):
    out = tmp_path / "ao.exr"
    rep = tmp_path / "r.json"
    res = run_cli(box_ply, "--out", out, "--resolution", "64x32", "--padding", 1,
              "--rays", 4, "--report", rep)
    assert res.exit_code == 0, res.output
    pixels, names, _ = read_image(out)
    assert pixels.shape[:2] == (32, 64)
    coverage = pixels[..., names.index("coverage")]
    assert coverage[:, 32:].max() == 0 and coverage[:, :32].max() > 0  # the top-left 32 x 32
    report = json.loads(rep.read_text())
    assert any("top-left 32x32" in w for w in report["warnings"])


@pytest.mark.slow
def test_uvs_at_one_point_are_not_baked_into(tmp_path):
    """Own UVs that all sit at one point passed the check and gave an all-black map: now
    they count as unusable and a new atlas is made, with a warning that says why."""
    box = trimesh.creation.box()
    lines = [f"v {x} {y} {z}" for x, y, z in box.vertices] + ["vt 0.5 0.5"]
    lines += [f"f {a + 1}/1 {b + 1}/1 {c + 1}/1" for a, b, c in box.faces]
    path = tmp_path / "point_uv.obj"
    path.write_text("\n".join(lines) + "\n")
    res = bake_texels(path, rays=4, resolution=64, padding=1)
    assert res.report["texture"]["atlas"] == "xatlas" and res.covered.any()
    assert any("cover 0 texel centres" in w for w in res.report["warnings"])


@pytest.mark.slow
def test_charts_of_a_few_texels_warn_with_the_density(tmp_path):
    """150 separate triangles (one chart each) in a 96^2 map: about 8 texels per chart."""
    rng = np.random.default_rng(0)
    centres = rng.uniform(-2, 2, (150, 1, 3))
    corners = (centres + rng.normal(scale=0.2, size=(150, 3, 3))).reshape(-1, 3)
    mesh = trimesh.Trimesh(corners, np.arange(450).reshape(150, 3), process=False)
    path = tmp_path / "m.ply"
    mesh.export(path)
    res = bake_texels(path, rays=4, resolution=96, padding=2)
    (warning,) = [w for w in res.report["warnings"] if "raise --resolution" in w]
    assert "for 150 charts" in warning and "texels per scene unit" in warning
    density = res.report["texture"]["texel_density"]
    assert density == pytest.approx(np.sqrt(res.report["texture"]["texels_covered"] / mesh.area))


@pytest.mark.slow
def test_unwrap_failure_names_the_mesh(tmp_path):
    rng = np.random.default_rng(0)
    corners = (rng.uniform(-2, 2, (150, 1, 3)) + rng.normal(scale=0.2, size=(150, 3, 3))).reshape(-1, 3)
    path = tmp_path / "many.ply"
    trimesh.Trimesh(corners, np.arange(450).reshape(150, 3), process=False).export(path)
    res = run_cli(path, "--out", tmp_path / "ao.exr", "--resolution", 32, "--padding", 2,
                  "--rays", 4)
    assert res.exit_code == 1
    assert res.output.startswith(f"aobake: error: {path}: unwrapping") and "--resolution" in res.output


@pytest.mark.slow
def test_progress_reports_every_stage(tmp_path, box_ply):
    """Unwrapping and rasterising are reported as they start (xatlas ran 4-9 s with nothing
    shown), then the tracing progress."""
    seen, ticks = [], []

    def progress(done, total):
        ticks.append((done, total))

    progress.phase = seen.append
    bake_texels(box_ply, rays=4, resolution=64, padding=1, progress=progress)
    assert seen == ["loading", "unwrapping", "rasterising", "tracing"]
    assert ticks and ticks[-1][0] == ticks[-1][1]


@pytest.mark.slow
def test_texel_bent_normal_error_stays_no_information_where_a_sample_has_none(tmp_path):
    """An inside-out box (every ray blocked): each sample's angle error is the pi/2
    sentinel, and so is the texel's (it was pi/(2 sqrt(K)), as if averaging measured errors)."""
    box = trimesh.creation.box()
    box.invert()
    path = tmp_path / "inside.ply"
    box.export(path)
    res = bake_texels(path, rays=16, resolution=32, padding=0, texel_samples=4,
                      quantities=("ao", "bent_normal"))
    se = res.channels["bent_normal_stderr"][res.covered]
    np.testing.assert_allclose(se, np.pi / 2, rtol=1e-6)
