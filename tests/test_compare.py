"""``aobake compare``: metrics against candidates with a known error, vertex matching,
other tools' files, heatmaps, and one clear error per bad input.

Tolerances come from float32 storage: a value below 2 is stored within half an ulp of 1
(``F32 / 2``), and an error is the difference of two stored values, so within ``F32``.
"""

import json
import math
import subprocess
import sys

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

import aobake
from aobake.compare import POSITION_TOLERANCE, compare, main, match_vertices, position_tolerance
from aobake.outputs import metadata, write_vertices
from aobake.outputs.image import write_exr, write_ldr
from readers import read_image, read_ply

F32 = float(np.finfo(np.float32).eps)  # ulp at 1: twice the rounding of one stored value < 2


def run(*args):
    """``aobake compare`` through CliRunner (stdout and stderr kept apart)."""
    return CliRunner().invoke(main, [str(a) for a in args])


def ramp(n, amplitude):
    """d_i = amplitude i / (n - 1): rmse amplitude sqrt((2n - 1) / (6 (n - 1))), bias amplitude / 2."""
    return amplitude * np.arange(n) / (n - 1)


@pytest.fixture(scope="module")
def vertex_bake(tmp_path_factory):
    """A sphere through a floor (170 distinct positions), baked with 32 rays; its NPZ/PLY/GLB."""
    tmp = tmp_path_factory.mktemp("vertex")
    mesh = trimesh.util.concatenate([trimesh.creation.icosphere(subdivisions=2),
                                     trimesh.creation.box(extents=[4, 0.2, 4])])
    result = aobake.bake(mesh, rays=32, quantities=("ao", "obscurance"))
    for suffix in ("npz", "ply", "glb"):
        aobake.write(result, tmp / f"ref.{suffix}")
    return result, tmp


@pytest.fixture(scope="module")
def texel_bake(tmp_path_factory):
    """A cube on a plate as a 48x48 lightmap with 16 rays per texel; its EXR and PNG."""
    tmp = tmp_path_factory.mktemp("texel")
    mesh = trimesh.util.concatenate([
        trimesh.creation.box(extents=[2, 0.2, 2]),
        trimesh.creation.box(extents=[0.5, 0.5, 0.5]).apply_translation([0, 0.35, 0])])
    result = aobake.bake_texels(mesh, rays=16, resolution=48, padding=1)
    aobake.write(result, tmp / "ref.exr", mesh_out=tmp / "atlas.obj")
    aobake.write(result, tmp / "ref.png", mesh_out=tmp / "atlas2.obj")
    return result, tmp


def stored(result, name):
    """A field as the files hold it (float32), in float64."""
    return result.values[name].astype(np.float32).astype(np.float64)


def write_candidate(path, result, fields=None, order=None):
    """Write ``result``'s vertices with ``fields`` replacing its own, optionally in ``order``
    (candidate vertex j = reference vertex order[j]), with aobake's metadata."""
    fields = dict(result.fields(), **(fields or {}))
    positions, faces = result.positions, result.faces
    if order is not None:
        positions, faces, *values = permuted(order, positions, faces, *fields.values())
        fields = dict(zip(fields, values))
    write_vertices(path, positions, faces, fields, metadata(result))
    return path


def permuted(order, positions, faces, *arrays):
    """The same mesh with candidate vertex j = vertex order[j]."""
    inverse = np.empty_like(order)
    inverse[order] = np.arange(len(order))
    return (positions[order], inverse[faces], *(a[order] for a in arrays))


# ---------------------------------------------------------------------------------------------
# metrics against known errors


@pytest.mark.parametrize("suffix", ["npz", "ply", "glb"])
def test_identical_files_agree(vertex_bake, suffix):
    result, tmp = vertex_bake
    m = compare(tmp / "ref.npz", tmp / f"ref.{suffix}")
    se = stored(result, "ao_stderr")
    assert m["n"] == len(result.positions) and m["matched_by"] == "order"
    assert m["rmse"] == m["bias"] == m["max_error"] == m["excess_rmse"] == 0.0
    assert m["psnr"] is None  # infinite: strict JSON has no Infinity
    assert m["reference_noise_rms"] == pytest.approx(math.sqrt(np.mean(se**2)), rel=1e-12)
    assert m["rmse_in_reference_se"] == 0.0


@pytest.mark.parametrize("suffix", ["npz", "ply", "glb"])
@pytest.mark.parametrize("c", [0.01, -0.03])
def test_constant_offset_is_the_bias(vertex_bake, tmp_path, suffix, c):
    result, tmp = vertex_bake
    cand = write_candidate(tmp_path / f"cand.{suffix}", result, {"ao": result.ao + c})
    m = compare(tmp / "ref.npz", cand)
    assert abs(m["bias"] - c) <= F32
    assert abs(m["rmse"] - abs(c)) <= F32
    assert abs(m["max_error"] - abs(c)) <= F32
    assert m["psnr"] == pytest.approx(-20 * math.log10(m["rmse"]), rel=1e-12)
    noise = math.sqrt(np.mean(stored(result, "ao_stderr") ** 2))
    assert m["reference_noise_rms"] == pytest.approx(noise, rel=1e-12)
    assert m["rmse_in_reference_se"] == pytest.approx(m["rmse"] / noise, rel=1e-12)
    assert m["rmse_without_reference_noise"] == pytest.approx(
        math.sqrt(max(0.0, m["rmse"] ** 2 - noise**2)), rel=1e-12, abs=1e-15)
    # the candidate carries the reference's stderr too: the combined error, sqrt(2) noise
    assert m["error"] == "combined" and m["noise_rms"] == pytest.approx(math.sqrt(2) * noise,
                                                                        rel=1e-12)
    assert m["excess_rmse"] == pytest.approx(math.sqrt(max(0.0, m["rmse"] ** 2 - 2 * noise**2)),
                                             rel=1e-12, abs=1e-15)
    se = stored(result, "ao_stderr")
    assert m["z_rms"] == pytest.approx(math.sqrt(np.mean(c**2 / (2 * se**2))), rel=1e-5)


def test_ramp_has_its_analytic_rmse(vertex_bake, tmp_path):
    result, tmp = vertex_bake
    n, a = len(result.positions), 0.05
    cand = write_candidate(tmp_path / "cand.ply", result, {"ao": result.ao + ramp(n, a)})
    m = compare(tmp / "ref.ply", cand)
    assert abs(m["rmse"] - a * math.sqrt((2 * n - 1) / (6 * (n - 1)))) <= F32
    assert abs(m["bias"] - a / 2) <= F32
    assert abs(m["max_error"] - a) <= F32
    assert abs(m["mean_abs_error"] - a / 2) <= F32


def test_obscurance_is_compared_with_its_own_stderr(vertex_bake, tmp_path):
    result, tmp = vertex_bake
    cand = write_candidate(tmp_path / "cand.npz", result, {"obscurance": result.obscurance - 0.02})
    m = compare(tmp / "ref.glb", cand, quantity="obscurance")
    assert abs(m["bias"] + 0.02) <= F32
    se = stored(result, "obscurance_stderr")
    assert m["reference_noise_rms"] == pytest.approx(math.sqrt(np.mean(se**2)), rel=1e-12)


# ---------------------------------------------------------------------------------------------
# vertex order


@pytest.mark.parametrize("suffix", ["ply", "glb", "npz"])
def test_permuted_vertices_give_the_same_metrics(vertex_bake, tmp_path, suffix):
    result, tmp = vertex_bake
    n = len(result.positions)
    fields = {"ao": result.ao + ramp(n, 0.05)}
    plain = compare(tmp / "ref.npz", write_candidate(tmp_path / f"a.{suffix}", result, fields))
    order = np.random.default_rng(1).permutation(n)
    permuted = compare(tmp / "ref.npz",
                       write_candidate(tmp_path / f"b.{suffix}", result, fields, order))
    assert plain["matched_by"] == "order" and permuted["matched_by"] == "position"
    for key in ("rmse", "bias", "max_error", "mean_abs_error", "psnr", "excess_rmse"):
        assert permuted[key] == pytest.approx(plain[key], rel=1e-12), key
    assert permuted["position_tolerance"] == position_tolerance(result.positions)


def split_box():
    """A unit cube with its own 4 vertices per side (3 coincident vertices per corner, told
    apart by their normals or their faces) beside a double-sided square (2 coincident
    vertices per corner on the same faces' centroids, told apart by the winding).
    (32, 3) positions, (16, 3) faces, (32, 3) normals."""
    box = trimesh.creation.box()
    box.unmerge_vertices()
    normals = np.repeat(box.face_normals, 3, axis=0)
    _, first, inverse = np.unique(np.round(np.hstack([box.vertices, normals]), 9), axis=0,
                                  return_index=True, return_inverse=True)
    positions, faces, normals = box.vertices[first], inverse.reshape(-1)[box.faces], normals[first]
    square = np.array([[2, 0, 0], [3, 0, 0], [3, 1, 0], [2, 1, 0]], dtype=float)
    front = np.array([[0, 1, 2], [0, 2, 3]]) + len(positions)
    back = front[:, ::-1] + 4
    return (np.vstack([positions, square, square]), np.vstack([faces, front, back]),
            np.vstack([normals, np.tile([0, 0, 1.0], (4, 1)), np.tile([0, 0, -1.0], (4, 1))]))


def test_coincident_vertices_are_told_apart(tmp_path):
    positions, faces, normals = split_box()
    n = len(positions)
    order = np.random.default_rng(2).permutation(n)
    tol = position_tolerance(positions)
    got, how, ambiguous = match_vertices(positions, positions[order], tol,
                                         (normals, normals[order].astype(np.float32)))
    assert how == "position" and ambiguous == 0
    assert np.array_equal(order[got], np.arange(n))  # candidate vertex got[i] is reference i
    # through the files, with faces and no normals: the heatmap's error at every reference
    # vertex is the ramp value of that vertex
    values = 1.0 - ramp(n, 0.5)
    write_vertices(tmp_path / "ref.npz", positions, faces, {"normals": normals, "ao": values}, None)
    p, f, cand = permuted(order, positions, faces, values + ramp(n, 0.1))
    write_vertices(tmp_path / "cand.ply", p, f, {"ao": cand}, None)
    m = compare(tmp_path / "ref.npz", tmp_path / "cand.ply", heatmap=tmp_path / "heat.ply")
    vertex, _, _ = read_ply(tmp_path / "heat.ply")
    assert np.abs(vertex["error"] - ramp(n, 0.1)).max() <= F32
    assert m["reference_noise_rms"] is None and m["excess_rmse"] is None and not m["warnings"]
    # positions alone cannot tell them apart: said, not hidden
    np.savez(tmp_path / "points.npz", positions=p, ao=cand)
    m = compare(tmp_path / "ref.npz", tmp_path / "points.npz")
    assert len(m["warnings"]) == 1 and f"{n} vertices coincide" in m["warnings"][0]


def test_positions_within_the_tolerance_match():
    rng = np.random.default_rng(3)
    reference = rng.normal(size=(500, 3)) * 1e3 + 5e4  # far from the origin
    tol = position_tolerance(reference)
    assert tol == POSITION_TOLERANCE * np.abs(reference).max()
    order = rng.permutation(500)
    jittered = reference[order] + rng.uniform(-tol, tol, size=(500, 3)) * 0.99
    got, how, _ = match_vertices(reference, jittered, tol)
    assert how == "position" and np.array_equal(order[got], np.arange(500))
    with pytest.raises(ValueError, match="not within"):
        match_vertices(reference, reference[order] + 3 * tol, tol)


# ---------------------------------------------------------------------------------------------
# other tools' files


def test_foreign_ascii_ply_in_the_occlusion_convention(vertex_bake, tmp_path):
    """A libigl-style file: text positions in another order, 1 - AO in a property of its own name."""
    result, tmp = vertex_bake
    order = np.random.default_rng(4).permutation(len(result.positions))
    positions, occlusion = result.positions[order], 1.0 - result.ao[order]
    lines = ["ply", "format ascii 1.0", f"element vertex {len(positions)}", "property float x",
             "property float y", "property float z", "property double occlusion",
             "element face 0", "property list uchar int vertex_indices", "end_header"]
    lines += [f"{x:.9g} {y:.9g} {z:.9g} {o:.17g}" for (x, y, z), o in zip(positions, occlusion)]
    (tmp_path / "igl.ply").write_text("\n".join(lines) + "\n")
    res = run(tmp / "ref.ply", tmp_path / "igl.ply", "--candidate-key", "occlusion",
              "--candidate-convention", "occlusion", "--json")
    assert res.exit_code == 0, res.output
    m = json.loads(res.stdout)
    assert m["matched_by"] == "position" and m["n"] == len(positions)
    assert m["rmse"] <= F32 and m["candidate_key"] == "occlusion"
    # without the convention the error is the whole 1 - 2 AO
    res = run(tmp / "ref.ply", tmp_path / "igl.ply", "--candidate-key", "occlusion", "--json")
    assert json.loads(res.stdout)["rmse"] > 0.1


def test_foreign_binary_ply_from_trimesh(vertex_bake, tmp_path):
    result, tmp = vertex_bake
    order = np.random.default_rng(5).permutation(len(result.positions))
    positions, faces, ao = permuted(order, result.positions, result.faces, result.ao)
    mesh = trimesh.Trimesh(positions, faces, process=False)
    mesh.vertex_attributes["shade"] = ao.astype(np.float32)
    (tmp_path / "tm.ply").write_bytes(trimesh.exchange.ply.export_ply(mesh, vertex_normal=False))
    m = compare(tmp / "ref.glb", tmp_path / "tm.ply", candidate_key="shade")
    assert m["matched_by"] == "position" and m["rmse"] == 0.0


def test_foreign_npz_without_positions_is_compared_in_order(vertex_bake, tmp_path):
    result, tmp = vertex_bake
    np.savez(tmp_path / "other.npz", occ=1.0 - result.ao)
    m = compare(tmp / "ref.npz", tmp_path / "other.npz", candidate_key="occ",
                candidate_convention="occlusion")
    assert m["matched_by"] == "order" and m["rmse"] <= F32
    res = run(tmp / "ref.npz", tmp_path / "other.npz")
    assert res.exit_code == 1
    assert "no array 'ao' (it has occ); name the candidate's with --candidate-key" in res.stderr


def test_occlusion_convention_refused_for_an_aobake_file(vertex_bake):
    _, tmp = vertex_bake
    res = run(tmp / "ref.npz", tmp / "ref.ply", "--candidate-convention", "occlusion")
    assert res.exit_code == 1 and "is an aobake output" in res.stderr


def test_different_weightings_are_different_quantities(vertex_bake, tmp_path):
    result, tmp = vertex_bake
    mesh = trimesh.Trimesh(result.positions, result.faces, process=False)
    aobake.write(aobake.bake(mesh, rays=8, weighting="uniform"), tmp_path / "uniform.ply")
    res = run(tmp / "ref.npz", tmp_path / "uniform.ply")
    assert res.exit_code == 1
    assert res.stderr.startswith(f"aobake: error: {tmp_path / 'uniform.ply'}: holds uniform-weighted")
    assert "different quantities" in res.stderr


def test_other_settings_that_change_the_number_are_warned_about(vertex_bake, tmp_path):
    result, tmp = vertex_bake
    mesh = trimesh.Trimesh(result.positions, result.faces, process=False)
    aobake.write(aobake.bake(mesh, rays=8, max_distance="10%"), tmp_path / "near.npz")
    m = compare(tmp / "ref.npz", tmp_path / "near.npz")
    assert len(m["warnings"]) == 1 and "max_distance differs" in m["warnings"][0]


# ---------------------------------------------------------------------------------------------
# lightmaps


@pytest.mark.slow
def test_texel_offset_over_covered_texels_only(texel_bake, tmp_path):
    result, tmp = texel_bake
    covered = result.channels["coverage"] > 0
    channels = dict(result.channels)
    channels["ao"] = np.where(covered, result.channels["ao"] + 0.01, 7.0)  # uncovered: nonsense
    write_exr(tmp_path / "cand.exr", channels, metadata(result))
    m = compare(tmp / "ref.exr", tmp_path / "cand.exr")
    assert m["n"] == covered.sum() and m["matched_by"] == "texel"
    assert abs(m["bias"] - 0.01) <= F32 and abs(m["max_error"] - 0.01) <= F32
    se = result.channels["ao_stderr"][covered].astype(np.float64)
    assert m["reference_noise_rms"] == pytest.approx(math.sqrt(np.mean(se**2)), rel=1e-12)


@pytest.mark.slow
def test_foreign_single_channel_image_uses_the_reference_mask(texel_bake, tmp_path):
    result, tmp = texel_bake
    covered = result.channels["coverage"] > 0
    write_exr(tmp_path / "other.exr", {"Y": np.where(covered, result.channels["ao"] - 0.02, -5.0)})
    m = compare(tmp / "ref.exr", tmp_path / "other.exr")
    assert m["n"] == covered.sum() and m["candidate_key"] == "Y"
    assert abs(m["bias"] + 0.02) <= F32


def test_png_is_within_its_quantisation(texel_bake):
    result, tmp = texel_bake
    covered = result.channels["coverage"] > 0
    m = compare(tmp / "ref.exr", tmp / "ref.png")
    assert m["n"] + m["n_uncovered_in_candidate"] == covered.sum()
    assert m["max_error"] <= 0.5 / 255 + F32  # 8 bits round to the nearest of 255 steps
    assert m["candidate_key"] == "R"


def test_png_candidate_with_its_own_coverage(texel_bake, tmp_path):
    result, tmp = texel_bake
    ao, coverage = result.channels["ao"].astype(np.float64), result.channels["coverage"]
    # an affine change kept inside [0, 1] (AO is 0 under the cube): e = 0.01 - 0.02 ao
    write_ldr(tmp_path / "cand.png", 0.98 * ao + 0.01, coverage, bit_depth=16,
              metadata=dict(metadata(result), map="ao"))
    m = compare(tmp / "ref.exr", tmp_path / "cand.png")
    assert m["n"] + m["n_uncovered_in_candidate"] == np.count_nonzero(coverage)
    used = np.rint(coverage * 65535) > 0  # alpha is the coverage in 16 bits
    step = 0.5 / 65535  # 16 bits round to the nearest of 65535 steps
    assert abs(m["bias"] - np.mean(0.01 - 0.02 * ao[used])) <= step + F32


def test_texel_heatmap(texel_bake, tmp_path):
    result, tmp = texel_bake
    covered = result.channels["coverage"] > 0
    channels = dict(result.channels, ao=result.channels["ao"] + 0.03)
    write_exr(tmp_path / "cand.exr", channels, metadata(result))
    res = run(tmp / "ref.exr", tmp_path / "cand.exr", "--heatmap", tmp_path / "heat.png")
    assert res.exit_code == 0, res.output
    assert "heatmap" in res.stdout
    pixels, names, _ = read_image(tmp_path / "heat.png")
    assert names == ["R", "G", "B", "A"] and pixels.shape == (*covered.shape, 4)
    assert np.array_equal(pixels[..., 3] > 0, covered)
    red = np.rint(pixels[covered][:, :3] * 255)  # error = max error everywhere: the red end
    assert (np.abs(red - [180, 4, 38]) <= 1).all()


def test_vertex_heatmap(vertex_bake, tmp_path):
    result, tmp = vertex_bake
    n = len(result.positions)
    d = ramp(n, 0.05) - 0.025  # -0.025 .. +0.025
    cand = write_candidate(tmp_path / "cand.npz", result, {"ao": result.ao + d})
    m = compare(tmp / "ref.ply", cand, heatmap=tmp_path / "heat.ply")
    vertex, faces, meta = read_ply(tmp_path / "heat.ply")
    assert np.abs(vertex["error"] - d).max() <= F32 and np.array_equal(faces, result.faces)
    assert meta["heatmap"]["scale"] == m["heatmap_scale"] == m["max_error"]
    rgb = np.column_stack([vertex["red"], vertex["green"], vertex["blue"]])
    assert tuple(rgb[-1]) == (180, 4, 38) and tuple(rgb[0]) == (59, 76, 192)
    assert (rgb[n // 2] >= 250).all()  # |error| < 1% of the scale: white
    positive = vertex["error"] > 0
    assert (rgb[positive, 0] > rgb[positive, 2]).all() and (rgb[~positive, 0] < rgb[~positive, 2]).all()


# ---------------------------------------------------------------------------------------------
# the command line and its errors


def test_json_is_one_strict_object(vertex_bake):
    _, tmp = vertex_bake

    def refuse(constant):
        raise AssertionError(f"non-strict JSON constant {constant}")

    res = run(tmp / "ref.npz", tmp / "ref.glb", "--json")
    assert res.exit_code == 0, res.output
    m = json.loads(res.stdout, parse_constant=refuse)
    for key in ("rmse", "bias", "max_error", "psnr", "n", "rmse_in_reference_se",
                "reference_noise_rms", "excess_rmse"):
        assert key in m
    assert m["psnr"] is None and res.stderr == ""


def test_table_and_quiet_library(vertex_bake, capsys):
    _, tmp = vertex_bake
    compare(tmp / "ref.npz", tmp / "ref.ply")
    assert capsys.readouterr() == ("", "")
    res = run(tmp / "ref.npz", tmp / "ref.ply")
    assert res.exit_code == 0 and "rmse" in res.stdout and "excess rmse" in res.stdout


def bad_inputs(vertex_bake, texel_bake, tmp_path):
    """name -> (reference, candidate, text in the message, file the message names)."""
    result, vtmp = vertex_bake
    _, ttmp = texel_bake
    ref = vtmp / "ref.npz"
    (tmp_path / "junk.npz").write_bytes(b"not a zip archive")
    (tmp_path / "junk.ply").write_bytes(b"hello\n")
    whole = (vtmp / "ref.ply").read_bytes()
    (tmp_path / "short.ply").write_bytes(whole[:whole.index(b"end_header") + 100])
    (tmp_path / "junk.glb").write_bytes(b"glTF" + bytes(40))
    (tmp_path / "junk.exr").write_bytes(b"\x76\x2f\x31\x01" + bytes(20))
    (tmp_path / "dir.ply").mkdir()
    aobake.write(aobake.bake(trimesh.creation.icosphere(subdivisions=1), rays=4),
                 tmp_path / "other_mesh.ply")
    moved = result.positions + 0.1
    write_vertices(tmp_path / "moved.ply", moved, result.faces, result.fields(), metadata(result))
    write_vertices(tmp_path / "no_ao.npz", result.positions, result.faces,
                   {"rays": result.rays}, None)
    write_exr(tmp_path / "small.exr", {"ao": np.ones((16, 16))})
    return {
        "missing": (ref, tmp_path / "absent.ply", "no such file", tmp_path / "absent.ply"),
        "missing reference": (tmp_path / "absent.npz", ref, "no such file",
                              tmp_path / "absent.npz"),
        "not a zip": (ref, tmp_path / "junk.npz", "cannot read as NPZ", tmp_path / "junk.npz"),
        "not a ply": (ref, tmp_path / "junk.ply", "cannot read as PLY", tmp_path / "junk.ply"),
        "truncated ply": (ref, tmp_path / "short.ply", "truncated", tmp_path / "short.ply"),
        "not a glb": (ref, tmp_path / "junk.glb", "cannot read as GLB", tmp_path / "junk.glb"),
        "not an exr": (ttmp / "ref.exr", tmp_path / "junk.exr", "cannot read as EXR",
                       tmp_path / "junk.exr"),
        "directory": (ref, tmp_path / "dir.ply", "is a directory", tmp_path / "dir.ply"),
        "other mesh": (ref, tmp_path / "other_mesh.ply", "has 42 vertices",
                       tmp_path / "other_mesh.ply"),
        "moved mesh": (ref, tmp_path / "moved.ply", "not within", tmp_path / "moved.ply"),
        "missing key": (ref, tmp_path / "no_ao.npz", "no array 'ao'", tmp_path / "no_ao.npz"),
        "image size": (ttmp / "ref.exr", tmp_path / "small.exr", "is 16x16 texels",
                       tmp_path / "small.exr"),
        "vertices vs texels": (ref, ttmp / "ref.exr", "holds a lightmap", ttmp / "ref.exr"),
        "format": (ref, tmp_path / "mesh.obj", "unsupported format", tmp_path / "mesh.obj"),
        "heatmap suffix": (ref, vtmp / "ref.ply", "is written as .ply", tmp_path / "heat.png"),
    }


BAD = ["missing", "missing reference", "not a zip", "not a ply", "truncated ply", "not a glb",
       "not an exr", "directory", "other mesh", "moved mesh", "missing key", "image size",
       "vertices vs texels", "format", "heatmap suffix"]


@pytest.mark.slow
@pytest.mark.parametrize("case", BAD)
def test_bad_input_is_one_line_and_exit_1(vertex_bake, texel_bake, tmp_path, case):
    reference, candidate, text, named = bad_inputs(vertex_bake, texel_bake, tmp_path)[case]
    extra = ["--heatmap", tmp_path / "heat.png"] if case == "heatmap suffix" else []
    res = run(reference, candidate, *extra)
    assert res.exit_code == 1, res.output
    assert isinstance(res.exception, SystemExit)  # no traceback
    assert res.stderr.startswith(f"aobake: error: {named}: "), res.stderr
    assert text in res.stderr and res.stderr.count("\n") == 1
    assert res.stdout == ""
    assert not (tmp_path / "heat.png").exists()


@pytest.mark.parametrize("args", [[], ["only_one.npz"], ["a.npz", "b.npz", "-q", "bent_normal"],
                                  ["a.npz", "b.npz", "--candidate-convention", "ao2"]])
def test_usage_errors_exit_2(args):
    res = run(*args)
    assert res.exit_code == 2


@pytest.mark.slow
def test_python_m_aobake_compare():
    res = subprocess.run([sys.executable, "-m", "aobake.compare", "--help"], capture_output=True,
                         text=True, check=False)
    assert res.returncode == 0 and "REFERENCE CANDIDATE" in res.stdout
    assert "--candidate-convention" in res.stdout


def test_aobake_compare_through_the_main_command(vertex_bake):
    from aobake import cli

    if "compare" not in getattr(cli, "SUBCOMMANDS", {}):
        pytest.skip("aobake/cli.py does not dispatch 'aobake compare' yet")
    _, tmp = vertex_bake
    res = CliRunner().invoke(cli.main, ["compare", str(tmp / "ref.npz"), str(tmp / "ref.ply"),
                                        "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["rmse"] == 0.0
