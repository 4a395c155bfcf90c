"""Readers registered beside their writers (issue 31): every format in
``aobake.outputs.registry.WRITERS`` reads back what its writer wrote through
``aobake.outputs.read``, aobake's GLB through the one glTF container module.

Tolerances: per-vertex values stored as float32 within float32 rounding of values in
[0, 1] (F32_ATOL); 8-bit images within half a step (0.5 / 255) plus float32 rounding.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import aobake
from aobake.errors import InputError
from aobake.outputs import gltf, read, write_vertices
from aobake.outputs.image import write_exr, write_ldr
from aobake.outputs.registry import WRITERS, reader_for
from aobake.outputs.table import Table

F32_ATOL = 1e-7  # float32 rounding of a value in [0, 1]: half an ulp is at most 6e-8
BYTE_ATOL = 0.5 / 255 + F32_ATOL

H, W = 4, 6


@pytest.fixture(scope="module")
def mesh():
    return trimesh.creation.icosphere(subdivisions=1)


def vertex_fields(n: int) -> dict:
    rng = np.random.default_rng(3)
    return {"ao": rng.random(n), "ao_stderr": 0.05 * rng.random(n)}


def write_any(path, writer, mesh) -> tuple[np.ndarray, np.ndarray | None]:
    """Write a small file of ``writer``'s format; (the ao it holds, its stderr or None)."""
    config = {"config": {"quantities": ["ao"]}}
    if writer.kind == "points":
        fields = vertex_fields(len(mesh.vertices))
        write_vertices(path, mesh.vertices, mesh.faces, fields, config)
        return fields["ao"], fields["ao_stderr"]
    if writer.suffix == ".glb":  # a lightmap GLB: the mesh with the map as its texture
        from aobake.outputs import glb, image

        uv = np.asarray(mesh.vertices[:, :2]) * 0.5 + 0.5
        png = image.png_bytes(np.full((H, W), 0.5), np.ones((H, W)))
        glb.write_textured(path, mesh.vertices, mesh.faces, None, uv, png, config)
        return None, None
    ao = np.linspace(0.0, 1.0, H * W).reshape(H, W)
    coverage = np.ones((H, W))
    if writer.suffix == ".exr":
        stderr = np.full((H, W), 0.01)
        write_exr(path, {"ao": ao, "ao_stderr": stderr, "coverage": coverage}, config)
        return ao, stderr
    write_ldr(path, ao, coverage, metadata=dict(config, map="ao"))
    return ao, None


@pytest.mark.parametrize("writer", WRITERS, ids=lambda w: f"{w.kind}{w.suffix}")
def test_every_format_written_is_read_back(tmp_path, writer, mesh):
    path = tmp_path / f"out{writer.suffix}"
    ao, stderr = write_any(path, writer, mesh)
    table = writer.read(path)
    assert isinstance(table, Table)
    assert table.metadata.get("config") == {"quantities": ["ao"]}
    if ao is None:  # the lightmap GLB: read as its mesh, which holds no per-vertex ao
        assert "TEXCOORD_0" in table.columns
        np.testing.assert_allclose(table.positions, mesh.vertices, atol=1e-6)
        with pytest.raises(InputError, match="a lightmap GLB's AO is a texture"):
            read(path, "ao")
        return
    values = read(path, "ao")
    atol = BYTE_ATOL if writer.suffix in (".png", ".tif", ".tiff") else F32_ATOL
    np.testing.assert_allclose(values.value, ao, rtol=0, atol=atol)
    if stderr is None:
        assert values.stderr is None
    else:
        np.testing.assert_allclose(values.stderr, stderr, rtol=0, atol=F32_ATOL)
    if writer.kind == "points":
        assert values.target == "vertices"
        np.testing.assert_allclose(values.positions, mesh.vertices, atol=1e-6)
        np.testing.assert_array_equal(values.faces, mesh.faces)
    else:
        assert values.target == "texels" and values.mask.all()


def test_the_reader_is_found_by_suffix_and_refused_for_other_files(tmp_path):
    assert reader_for(tmp_path / "A.NPZ") is WRITERS[0].read
    with pytest.raises(InputError, match=r"unsupported format '\.obj'"):
        reader_for(tmp_path / "mesh.obj")
    with pytest.raises(InputError, match=r"unsupported format '\.obj'"):
        read(tmp_path / "mesh.obj")


def test_compare_reads_through_the_outputs_reader():
    import aobake.compare

    assert aobake.compare.read is aobake.outputs.read


def test_aobake_glb_reads_back_through_the_container(tmp_path, mesh):
    """The writer and the reader share the container: a vertex GLB's attributes, its
    metadata in asset.extras, and its layout by the strict reading."""
    path = tmp_path / "ao.glb"
    fields = vertex_fields(len(mesh.vertices))
    write_vertices(path, mesh.vertices, mesh.faces, fields, {"config": {"rays": 4}})
    parsed, binary = gltf.parse_glb(path.read_bytes(), strict=True)
    assert parsed["asset"]["extras"] == {"config": {"rays": 4}}
    attributes = parsed["meshes"][0]["primitives"][0]["attributes"]
    np.testing.assert_allclose(gltf.accessor_array(parsed, binary, attributes["_AO"],
                                                   strict=True), fields["ao"], atol=F32_ATOL)
    assert aobake.outputs.read(path, "ao").metadata == {"config": {"rays": 4}}
