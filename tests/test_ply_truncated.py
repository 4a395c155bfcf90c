"""A PLY cut short is an input error wherever aobake reads values from it (issue 35):
``--method file --ao-from`` and ``compare`` read it through ``aobake.compare.read``, which
used to drop a face element that ran past the end of the file and read the vertices alone."""

from __future__ import annotations

import subprocess
import sys

import pytest
import trimesh

import aobake
from aobake.compare import read
from conftest import run_cli


@pytest.fixture
def baked(tmp_path):
    mesh = tmp_path / "sphere.ply"
    trimesh.creation.icosphere(1).export(mesh)
    out = tmp_path / "ao.ply"
    aobake.write(aobake.bake(mesh, rays=8), out)
    return mesh, out


def _cut(path, keep: int):
    data = path.read_bytes()
    cut = path.with_name("cut.ply")
    cut.write_bytes(data[:len(data) - keep])
    return cut


@pytest.mark.parametrize("keep", [1, 7, 100])
@pytest.mark.slow
def test_reading_a_binary_ply_cut_in_its_faces_is_an_input_error(baked, keep):
    cut = _cut(baked[1], keep)
    with pytest.raises(aobake.InputError, match=r"cut\.ply: .*truncated: element 'face'"):
        read(cut, "ao", role="reference")


def test_an_ascii_ply_cut_in_its_faces_is_an_input_error(tmp_path):
    text = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            "property float z\nproperty float ao\nelement face 2\n"
            "property list uchar int vertex_indices\nend_header\n"
            "0 0 0 1\n1 0 0 0.5\n0 1 0 0.25\n3 0 1 2\n3 0 2")
    path = tmp_path / "cut.ply"
    path.write_text(text)
    with pytest.raises(aobake.InputError, match="truncated: element 'face'"):
        read(path, "ao", role="reference")
    path.write_text(text + " 1\n")  # whole again: read as before
    assert read(path, "ao", role="reference").value.tolist() == [1.0, 0.5, 0.25]


def test_a_ply_of_quads_is_still_read_for_its_vertex_values(tmp_path):
    # not triangles: the faces are not read (they cannot be), the values are: not truncated
    path = tmp_path / "quads.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\n"
                    "property float y\nproperty float z\nproperty float ao\nelement face 1\n"
                    "property list uchar int vertex_indices\nend_header\n"
                    "0 0 0 1\n1 0 0 1\n1 1 0 1\n0 1 0 1\n4 0 1 2 3\n")
    assert read(path, "ao", role="reference").value.tolist() == [1.0] * 4


@pytest.mark.slow
def test_library_view_from_a_truncated_ply_is_an_input_error(baked):
    mesh, out = baked
    cut = _cut(out, 7)
    with pytest.raises(aobake.InputError, match="cut.ply"):
        aobake.bake_view(mesh, method="file", ao_from=str(cut), size=(16, 12))


@pytest.mark.slow
def test_cli_view_from_a_truncated_ply_exits_1(baked, tmp_path):
    mesh, out = baked
    cut = _cut(out, 7)
    look = tmp_path / "look.png"
    result = subprocess.run([sys.executable, "-m", "aobake", "view", str(mesh), "--method",
                             "file", "--ao-from", str(cut), "--size", "16x12", "--out",
                             str(look)], capture_output=True, text=True)
    assert result.returncode == 1, result.stderr
    assert result.stderr.strip().splitlines() == [
        line for line in result.stderr.strip().splitlines() if line.startswith("aobake: error: ")]
    assert str(cut) in result.stderr and "truncated" in result.stderr
    assert not look.exists()


def test_cli_compare_of_a_truncated_ply_exits_1(baked):
    mesh, out = baked
    cut = _cut(out, 7)
    result = run_cli("compare", out, cut)
    assert result.exit_code == 1, result.output
    assert "truncated" in result.output
