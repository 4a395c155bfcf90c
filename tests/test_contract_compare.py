"""``aobake compare`` held to the error contract (docs/reliability.md): one line
``aobake: error: FILE: problem`` and exit 1 naming the file at fault, readers that allocate
no more than the file holds, finite metrics, no library's own output, the signal contract,
matching whose work grows linearly whatever the duplicates, and other tools' files as they
are really written (trimesh: grey vertex colours, unreferenced vertices dropped).

Every file is made here, under tmp_path.
"""

import io
import json
import math
import os
import re
import signal
import struct
import subprocess
import sys
import time
import tracemalloc
import warnings
import zipfile

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

import aobake
from aobake.compare import compare, main, match_vertices, metrics, position_tolerance
from aobake.outputs.image import check_png, quiet_stderr
from aobake.outputs import write_vertices
from aobake.outputs.atomic import atomic_path
from aobake.outputs.image import write_ldr

F32 = float(np.finfo(np.float32).eps)


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def one_line_error(res, named):
    """The contract: exit 1, no traceback, exactly one line naming ``named``, nothing on stdout."""
    assert res.exit_code == 1, res.output
    assert isinstance(res.exception, SystemExit), res.exception  # no traceback
    assert res.stderr.startswith(f"aobake: error: {named}: "), res.stderr
    assert res.stderr.count("\n") == 1, res.stderr
    assert res.stdout == ""


@pytest.fixture(scope="module")
def bake(tmp_path_factory):
    """A sphere through a floor, baked with 8 rays: its NPZ, PLY and GLB."""
    tmp = tmp_path_factory.mktemp("contract")
    mesh = trimesh.util.concatenate([trimesh.creation.icosphere(subdivisions=1),
                                     trimesh.creation.box(extents=[4, 0.2, 4])])
    result = aobake.bake(mesh, rays=8)
    for suffix in ("npz", "ply", "glb"):
        aobake.write(result, tmp / f"ref.{suffix}")
    return result, tmp


def glb_parts(data: bytes):
    (json_length,) = struct.unpack_from("<I", data, 12)
    gltf = json.loads(data[20:20 + json_length])
    return gltf, data[20 + json_length:]


def glb_bytes(json_text: bytes, rest: bytes) -> bytes:
    json_text += b" " * (-len(json_text) % 4)
    body = struct.pack("<II", len(json_text), 0x4E4F534A) + json_text + rest
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def npz_claiming(shape) -> bytes:
    """An NPZ whose ``ao`` member's header claims ``shape`` float32 and holds 16 bytes."""
    member = io.BytesIO()
    np.lib.format.write_array_header_1_0(member, {"descr": "<f4", "fortran_order": False,
                                                  "shape": shape})
    member.write(bytes(16))
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as archive:
        archive.writestr("ao.npy", member.getvalue())
    return out.getvalue()


# ---------------------------------------------------------------------------------------------
# 1. malformed files: bounded readers, one line naming the file


def malformed(bake, tmp_path):
    """name -> (file name, bytes, text in the message)."""
    _, tmp = bake
    npz, ply, glb = ((tmp / f"ref.{s}").read_bytes() for s in ("npz", "ply", "glb"))
    gltf, rest = glb_parts(glb)

    def edited(change):
        copy = json.loads(json.dumps(gltf))
        change(copy)
        return glb_bytes(json.dumps(copy).encode(), rest)

    def zero_accessors(g):  # no bufferView: all zeros, a trillion of them
        for a in g["accessors"]:
            a.pop("bufferView", None)
            a["count"] = 10 ** 12

    def zero_stride(g):  # every element on the same bytes, a trillion of them
        for v in g["bufferViews"]:
            v["byteStride"] = 0
        for a in g["accessors"]:
            a["count"] = 10 ** 12

    comment = re.search(rb"comment aobake-metadata [^\n]*\n", ply)
    deep = ply[:comment.start()] + b"comment aobake-metadata " + b"[" * 100000 + \
        b"]" * 100000 + b"\n" + ply[comment.end():]
    header_end = ply.index(b"end_header")
    huge_count = re.sub(rb"element vertex \d+", b"element vertex 1000000000000",
                        ply[:header_end]) + ply[header_end:]
    return {
        "truncated npz": ("t.npz", npz[:len(npz) // 2], "cannot read as NPZ"),
        "not a zip": ("z.npz", b"PK\x03\x04" + bytes(60), "cannot read as NPZ"),
        "npz claiming terabytes": ("h.npz", npz_claiming((10 ** 12,)), "claims"),
        "deep ply metadata": ("d.ply", deep, "nests 100000 levels"),
        "ply claiming terabytes": ("c.ply", huge_count, "claims 1000000000000"),
        "glb zero accessors": ("a.glb", edited(zero_accessors), "claims 1000000000000"),
        "glb zero stride": ("s.glb", edited(zero_stride), "byteStride 0"),
        "deep glb json": ("j.glb", glb_bytes(b"[" * 100000 + b"]" * 100000, rest), "nests"),
    }


CASES = ["truncated npz", "not a zip", "npz claiming terabytes", "deep ply metadata",
         "ply claiming terabytes", "glb zero accessors", "glb zero stride", "deep glb json"]


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES)
def test_malformed_candidate_is_one_line_without_allocating_its_claims(bake, tmp_path, case):
    name, data, text = malformed(bake, tmp_path)[case]
    (tmp_path / name).write_bytes(data)
    tracemalloc.start()
    try:
        res = run(bake[1] / "ref.npz", tmp_path / name)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    one_line_error(res, tmp_path / name)
    assert text in res.stderr
    assert peak < 64 << 20  # nothing near what the file claims was made


#: what a mutation puts where a number was (GLB JSON)
_EXTREMES = [0, -1, 3, 4294967295, 2 ** 40, 2 ** 64, 1e300, 3.5, "x", [], {}, None]


def _json_mutation(data: bytes, rng) -> bytes:
    """A GLB with one number of its JSON (a count, an offset, a stride, an index ...)
    replaced by an extreme value, the container kept consistent."""
    gltf, rest = glb_parts(data)
    spots = []

    def walk(node):
        for key, value in (node.items() if isinstance(node, dict) else enumerate(node)):
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                spots.append((node, key))
            elif isinstance(value, (dict, list)):
                walk(value)

    walk(gltf)
    node, key = spots[int(rng.integers(0, len(spots)))]
    node[key] = _EXTREMES[int(rng.integers(0, len(_EXTREMES)))]
    return glb_bytes(json.dumps(gltf).encode(), rest)


def _mutations(data: bytes, rng, count: int, glb: bool = False):
    """``count`` broken copies of ``data``: truncated, bytes overwritten, and (GLB) a JSON
    number swapped for an extreme value."""
    for i in range(count):
        kind = i % 3
        if kind == 0:
            yield data[:int(rng.integers(0, len(data)))]
        elif kind == 1 or not glb:
            copy = bytearray(data)
            for at in rng.integers(0, len(data), size=int(rng.integers(1, 8))):
                copy[at] = int(rng.integers(0, 256))
            yield bytes(copy)
        else:
            yield _json_mutation(data, rng)


@pytest.mark.slow
@pytest.mark.parametrize("suffix", ["npz", "ply", "glb", "png"])
def test_broken_files_give_input_errors_only(bake, tmp_path, suffix):
    """The next malformation of the same kind: mutated copies of each format, as the
    candidate and as the reference, read either correctly or as an InputError naming the
    file, never another exception or a warning."""
    _, tmp = bake
    if suffix == "png":
        data, other = _png(tmp_path), tmp_path / "ref.png"
    else:
        data, other = (tmp / f"ref.{suffix}").read_bytes(), tmp / "ref.npz"
    rng = np.random.default_rng(21)
    path = tmp_path / f"broken.{suffix}"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for broken in _mutations(data, rng, 40, glb=suffix == "glb"):
            path.write_bytes(broken)
            for pair in ((other, path), (path, other)):
                try:
                    compare(*pair)
                except aobake.InputError as exc:  # a file's message, or a pair's naming both
                    assert str(exc).startswith(f"{path}: ") or str(path) in str(exc), exc


# ---------------------------------------------------------------------------------------------
# 2. coincident vertices: linear work


def _coincident(n, duplicates, rng):
    positions = rng.normal(size=(n, 3))
    positions[:duplicates] = positions[0]
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return positions, normals


def _match_cost(positions, normals, order):
    tol = position_tolerance(positions)
    tracemalloc.start()
    start = time.perf_counter()
    try:
        got, how, ambiguous = match_vertices(positions, positions[order], tol,
                                             (normals, normals[order].astype(np.float32)))
        seconds = time.perf_counter() - start
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert how == "position" and ambiguous == 0
    assert np.array_equal(order[got], np.arange(len(positions)))
    return seconds, peak


@pytest.mark.slow
def test_coincident_vertices_cost_what_distinct_ones_do():
    """4,000 vertices at one position in a 12,000-vertex pair: a pairwise comparison would
    make (4000, 4000, 3) floats (384 MB) and take seconds; the work stays within a few times
    that of 12,000 distinct vertices, in time and memory, and every vertex finds its copy
    (told apart by float32 copies of its normal)."""
    rng = np.random.default_rng(0)
    n = 12000
    order = rng.permutation(n)
    distinct = _match_cost(*_coincident(n, 0, rng), order)
    _match_cost(*_coincident(n, 4000, rng), order)  # warm-up (imports, caches)
    coincident = _match_cost(*_coincident(n, 4000, rng), order)
    assert coincident[1] <= 4 * distinct[1] + (8 << 20), (coincident, distinct)
    assert coincident[1] < 64 << 20
    assert coincident[0] <= 10 * distinct[0] + 1.0, (coincident, distinct)
    # twice the vertices, twice the duplicates: about twice the memory, not four times
    twice = _match_cost(*_coincident(2 * n, 8000, rng), rng.permutation(2 * n))
    assert twice[1] <= 3 * coincident[1], (twice, coincident)


def test_thousands_of_coincident_vertices_through_files(tmp_path):
    """Coincident vertices without normals or faces to tell them apart: paired in file
    order, said in a warning, fast."""
    rng = np.random.default_rng(1)
    positions, _ = _coincident(12000, 4000, rng)
    values = rng.uniform(size=12000)
    write_vertices(tmp_path / "ref.npz", positions, np.zeros((0, 3), np.int64),
                   {"ao": values}, None)
    order = rng.permutation(12000)
    np.savez(tmp_path / "cand.npz", positions=positions[order], ao=values[order] + 0.01)
    start = time.perf_counter()
    m = compare(tmp_path / "ref.npz", tmp_path / "cand.npz")
    assert time.perf_counter() - start < 5.0
    assert m["matched_by"] == "position" and m["n"] == 12000
    assert "4000 vertices coincide" in m["warnings"][0]
    # each coincident candidate vertex got some reference vertex of the same position: the
    # distinct ones are exact
    assert m["max_error"] <= 1.0 + 0.01


# ---------------------------------------------------------------------------------------------
# 3. extreme values: finite metrics or a reason naming the file


@pytest.mark.filterwarnings("error")
def test_extreme_values_give_finite_metrics_or_a_reason(bake, tmp_path):
    result, tmp = bake

    def candidate(name, **changes):  # float64 values (aobake's own files hold float32)
        arrays = dict(positions=result.positions, faces=result.faces, ao=result.ao,
                      ao_stderr=result.ao_stderr)
        np.savez(tmp_path / name, **dict(arrays, **changes))
        return tmp_path / name

    n = len(result.positions)
    big = candidate("big.npz", ao=np.full(n, 1e200))
    res = run(tmp / "ref.npz", big, "--json")
    assert res.exit_code == 0 and res.stderr == "", res.output
    m = json.loads(res.stdout)
    assert m["rmse"] == pytest.approx(1e200, rel=1e-6) and m["psnr"] == pytest.approx(-4000.0)
    assert m["excess_rmse"] == pytest.approx(m["rmse"], rel=1e-6)
    assert all(math.isfinite(v) for v in m.values() if isinstance(v, float))
    # a reference stderr of 1e200: strict JSON, finite numbers
    noisy = candidate("noisy.npz", ao_stderr=np.full(n, 1e200))
    res = run(noisy, tmp / "ref.npz", "--json")
    assert res.exit_code == 0, res.output
    m = json.loads(res.stdout)
    assert m["reference_noise_rms"] == pytest.approx(1e200) and m["excess_rmse"] == 0.0
    # a difference beyond float64: refused, naming the file with the largest values
    huge = candidate("huge.npz", ao=np.full(n, -1.75e308))
    top = candidate("top.npz", ao=np.full(n, 1.5e308))
    one_line_error(run(huge, top), huge)
    one_line_error(run(top, huge), huge)
    # a ratio beyond float64: the reference's stderr is what cannot be divided by
    tiny = candidate("tiny.npz", ao_stderr=np.full(n, 1e-300))
    one_line_error(run(tiny, big), tiny)
    # non-finite stderr among the compared values: refused, naming that file
    inf_se = tmp_path / "inf_se.npz"
    np.savez(inf_se, positions=result.positions, faces=result.faces, ao=result.ao,
             ao_stderr=np.full(n, np.inf))
    res = run(inf_se, tmp / "ref.npz")
    one_line_error(res, inf_se)
    assert "ao_stderr" in res.stderr
    # the library function alone
    out = metrics(np.zeros(3), np.array([1e308, -1e308, 1e308]), np.full(3, 1e300))
    assert all(math.isfinite(out[k]) for k in ("rmse", "bias", "mean_abs_error", "psnr",
                                               "excess_rmse", "rmse_in_reference_se"))


# ---------------------------------------------------------------------------------------------
# 4. a library writing to stderr


def _png(tmp_path):
    values = np.linspace(0, 1, 32 * 32).reshape(32, 32)
    write_ldr(tmp_path / "ref.png", values, np.ones((32, 32)), bit_depth=8,
              metadata={"map": "ao", "config": {}})
    return (tmp_path / "ref.png").read_bytes()


@pytest.mark.slow
def test_truncated_png_is_one_line_from_aobake(tmp_path):
    """libpng prints its own ``libpng error:`` line on the process's stderr: through a real
    process, the only line is aobake's."""
    data = _png(tmp_path)
    (tmp_path / "cut.png").write_bytes(data[:len(data) * 2 // 3])
    res = subprocess.run([sys.executable, "-m", "aobake.compare", str(tmp_path / "ref.png"),
                          str(tmp_path / "cut.png")], capture_output=True, text=True, check=False)
    assert res.returncode == 1
    assert res.stderr.startswith(f"aobake: error: {tmp_path / 'cut.png'}: "), res.stderr
    assert res.stderr.count("\n") == 1 and "libpng" not in res.stderr, res.stderr


def test_png_structure_is_checked_before_libpng(tmp_path):
    data = _png(tmp_path)
    check_png(data)  # aobake's own PNG passes
    iend = data.rindex(b"IEND") - 4
    idat = data.index(b"IDAT") - 4
    (length,) = struct.unpack_from(">I", data, idat)
    short = bytearray(data)
    short[idat + 8 + length // 2] ^= 0xFF  # data changed: its CRC fails
    cases = {"cut": data[:iend], "crc": bytes(short),
             "signature": b"\x89PNG\r\n\x1a\x00" + data[8:]}
    for name, broken in cases.items():
        with pytest.raises(ValueError):
            check_png(broken)
        (tmp_path / f"{name}.png").write_bytes(broken)
        with pytest.raises(aobake.InputError, match=re.escape(str(tmp_path / f"{name}.png"))):
            compare(tmp_path / "ref.png", tmp_path / f"{name}.png")


def test_quiet_stderr_keeps_a_c_library_off_the_terminal(capfd):
    with quiet_stderr() as said:
        os.write(2, b"libpng error: something\n")
    assert said == ["libpng error: something"]
    os.write(2, b"after\n")
    assert capfd.readouterr().err == "after\n"


# ---------------------------------------------------------------------------------------------
# 5. the message names the file at fault


@pytest.mark.parametrize("which", ["reference", "candidate"])
@pytest.mark.parametrize("what", ["positions", "normals", "ao_stderr"])
def test_the_message_names_the_file_at_fault(bake, tmp_path, which, what):
    result, tmp = bake
    arrays = {"positions": result.positions.copy(), "faces": result.faces,
              "normals": result.normals.copy(), "ao": result.ao.copy(),
              "ao_stderr": result.ao_stderr.copy()}
    arrays[what][3] = np.nan
    np.savez(tmp_path / "bad.npz", **arrays)
    other = tmp / "ref.ply"
    bad = tmp_path / "bad.npz"
    res = run(bad, other) if which == "reference" else run(other, bad)
    one_line_error(res, bad)


# ---------------------------------------------------------------------------------------------
# 6. signals


@pytest.mark.parametrize("signum, code, text", [
    (signal.SIGINT, 130, "aobake: error: interrupted (SIGINT): no output written\n"),
    (signal.SIGTERM, 143, "aobake: error: terminated (SIGTERM): no output written\n")])
def test_compare_follows_the_signal_contract(bake, tmp_path, monkeypatch, signum, code, text):
    """A signal while the heatmap is being written: the main command's exit status and one
    line, and no file left (neither the heatmap nor its temporary)."""
    _, tmp = bake

    def half_written(path, *args):
        with atomic_path(path) as part:
            part.write_bytes(b"ply\n")
            os.kill(os.getpid(), signum)
            time.sleep(5)  # the signal arrives here

    monkeypatch.setattr("aobake.compare.heatmap._write_ply", half_written)
    start = time.perf_counter()
    res = run(tmp / "ref.npz", tmp / "ref.glb", "--heatmap", tmp_path / "heat.ply")
    assert time.perf_counter() - start < 4
    assert res.exit_code == code, res.output
    assert res.stderr == text and "Aborted" not in res.output
    assert os.listdir(tmp_path) == []


# ---------------------------------------------------------------------------------------------
# 9. another tool's file, as trimesh writes it


@pytest.fixture
def peer(bake, tmp_path):
    """A mesh with vertices no face uses (two before the sphere and floor, one after), its
    aobake reference, and the mesh as trimesh loads it (the unreferenced ones dropped)."""
    result, _ = bake
    stray = np.array([[9.0, 9, 9], [9.5, 9, 9]])
    vertices = np.vstack([stray, result.positions, [[10.0, 9, 9]]])
    mesh = trimesh.Trimesh(vertices, result.faces + 2, process=False)
    mesh.export(tmp_path / "mesh.obj")
    reference = aobake.bake(tmp_path / "mesh.obj", rays=8, seed=3)
    aobake.write(reference, tmp_path / "ref.ply")
    loaded = trimesh.load(tmp_path / "mesh.obj")  # the most common Python path
    assert len(loaded.vertices) == len(vertices) - 3
    return reference, loaded


def _reference_values_at(reference, vertices):
    """The reference's values at ``vertices`` (found by position, as a peer's would be)."""
    index = {tuple(np.round(p, 6)): i for i, p in enumerate(reference.positions)}
    return reference.ao[[index[tuple(np.round(p, 6))] for p in vertices]]


@pytest.mark.parametrize("suffix", ["ply", "glb"])
def test_trimesh_grey_colours_without_unreferenced_vertices(peer, tmp_path, suffix):
    """libigl's AO of a mesh loaded by trimesh, saved with grey vertex colours (simulated: the
    reference's values + 0.02, as 8-bit grey): accepted, with notes saying what was read and
    which reference vertices have no partner."""
    reference, loaded = peer
    ao = np.clip(_reference_values_at(reference, loaded.vertices) + 0.02, 0, 1)
    grey = np.rint(ao * 255).astype(np.uint8)
    loaded.visual.vertex_colors = np.column_stack([grey, grey, grey, np.full_like(grey, 255)])
    loaded.export(tmp_path / f"peer.{suffix}")
    res = run(tmp_path / "ref.ply", tmp_path / f"peer.{suffix}", "--json")
    assert res.exit_code == 0, res.output
    m = json.loads(res.stdout)
    assert m["n"] == len(loaded.vertices) and m["n_uncovered_in_candidate"] == 3
    assert m["matched_by"] == "position"
    assert m["candidate_key"] == ("red" if suffix == "ply" else "COLOR_0")
    assert any("grey vertex colours" in text for text in m["notes"])
    assert any("no partner for 3 of the reference's" in text and "none of them used by a face"
               in text for text in m["notes"])
    used = np.rint(np.clip(_reference_values_at(reference, loaded.vertices) + 0.02, 0, 1)
                   * 255) / 255 - _reference_values_at(reference, loaded.vertices)
    assert abs(m["bias"] - used.mean()) <= 1e-6
    res = run(tmp_path / "ref.ply", tmp_path / f"peer.{suffix}")  # the table says it too
    assert "note:" in res.stdout and "grey vertex colours" in res.stdout


def test_a_missing_used_vertex_is_refused(peer, tmp_path):
    reference, loaded = peer
    keep = np.ones(len(loaded.vertices), bool)
    keep[5] = False  # a vertex a face uses
    faces = loaded.faces[keep[loaded.faces].all(axis=1)]
    remap = np.cumsum(keep) - 1
    ao = _reference_values_at(reference, loaded.vertices)[keep]
    write_vertices(tmp_path / "cut.ply", loaded.vertices[keep], remap[faces], {"ao": ao}, None)
    res = run(tmp_path / "ref.ply", tmp_path / "cut.ply")
    one_line_error(res, tmp_path / "cut.ply")
    assert "lacks 1 of the vertices the reference's faces use" in res.stderr


def test_colours_that_are_not_grey_are_not_taken(peer, tmp_path):
    _, loaded = peer
    loaded.visual.vertex_colors = np.tile([200, 10, 10, 255], (len(loaded.vertices), 1))
    loaded.export(tmp_path / "red.ply")
    res = run(tmp_path / "ref.ply", tmp_path / "red.ply")
    one_line_error(res, tmp_path / "red.ply")
    assert "not grey" in res.stderr and "--candidate-key" in res.stderr
