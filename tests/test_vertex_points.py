"""The per-vertex target's points without copies (issue 34 point 3): the distinct (position,
normal) rows found by a hash and a sort are np.unique's groups, each with its first row as
id; a mesh whose rows are all distinct is sampled from the scene's own arrays; the sizes are
the one-bincount sums bit for bit; and a bake is the same whichever way the points came."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import trimesh

import aobake
from aobake import _native
from aobake.scene import load_scene
from aobake.settings import BakeConfig
from aobake.targets import vertices as target_module
from aobake.targets.vertices import VertexTarget, distinct_rows, vertex_sizes

KERNELS = [None] + ([_native.kernels()] if _native.kernels() is not None else [])


def _unique(positions, normals):
    """np.unique's (first, inverse) of the 48-byte rows: the formulation replaced."""
    keys = np.ascontiguousarray(np.concatenate([positions, normals], axis=1))
    rows = keys.view(np.dtype((np.void, keys.itemsize * keys.shape[1]))).ravel()
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    return first, inverse.reshape(-1)


def _same_groups(positions, normals, kernels):
    """distinct_rows gives np.unique's groups and first rows (file order for np.unique's
    byte order)."""
    first, inverse = distinct_rows(positions, normals, kernels)
    n = len(positions)
    if first is None:
        first = inverse = np.arange(n)
    expected_first, expected_inverse = _unique(positions, normals)
    np.testing.assert_array_equal(first, np.sort(expected_first))
    np.testing.assert_array_equal(first[inverse], expected_first[expected_inverse])
    assert np.all(np.diff(first) > 0)


def _rows(seed=0, n=3000, repeats=400):
    rng = np.random.default_rng(seed)
    positions = rng.normal(size=(n, 3))
    normals = rng.normal(size=(n, 3))
    pick = rng.integers(0, n, repeats)
    positions = np.concatenate([positions, positions[pick]])
    normals = np.concatenate([normals, normals[pick]])
    # a repeated position with another normal is another point; -0.0 is not 0.0 (bytes)
    normals[-1] = -normals[-1]
    positions[5, 0] = 0.0
    positions = np.concatenate([positions, positions[5:6] * [-1.0, 1.0, 1.0]])
    normals = np.concatenate([normals, normals[5:6]])
    order = rng.permutation(len(positions))
    return positions[order], normals[order]


@pytest.mark.parametrize("kernels", KERNELS)
def test_distinct_rows_are_np_unique_groups(kernels):
    positions, normals = _rows()
    _same_groups(positions, normals, kernels)
    first, _ = distinct_rows(positions, normals, kernels)
    assert first is not None and len(first) < len(positions)


@pytest.mark.parametrize("kernels", KERNELS)
def test_distinct_rows_without_repeats_is_the_identity(kernels):
    positions, normals = _rows(repeats=0)
    normals[-1] = -normals[-1]  # undo the flipped repeat: every row distinct
    assert distinct_rows(positions, normals, kernels) == (None, None)
    _same_groups(positions, normals, kernels)


@pytest.mark.parametrize("hash_of", [lambda n: np.zeros(n, np.uint32),
                                     lambda n: (np.arange(n) % 7).astype(np.uint32)])
def test_colliding_hashes_are_compared_row_by_row(monkeypatch, hash_of):
    """Rows whose hashes collide are told apart by their bytes (every hash equal: np.unique
    of them all)."""
    monkeypatch.setattr(target_module, "_row_hash", lambda columns, n: hash_of(n))
    for repeats in (400, 0):
        positions, normals = _rows(seed=1, repeats=repeats)
        _same_groups(positions, normals, _native.kernels())


def test_vertex_sizes_are_one_bincount_bit_for_bit(monkeypatch):
    """Summed a block of faces at a time (blocks of 7 faces here: vertices whose faces span
    blocks), the sums are one bincount's over every corner, bit for bit."""
    mesh = trimesh.creation.icosphere(3)
    mesh.vertices *= 1.0 + 0.3 * np.sin(7 * mesh.vertices[:, :1])
    scene = load_scene(mesh)
    areas, n = scene.areas(), len(scene.vertices)
    total = np.bincount(scene.faces.ravel(), weights=np.repeat(areas, 3), minlength=n)
    count = np.bincount(scene.faces.ravel(), minlength=n)
    expected = np.sqrt(2.0 * total / np.maximum(count, 1))
    for block in (7, 1 << 16):
        monkeypatch.setattr(target_module, "SIZE_BLOCK", block)
        assert vertex_sizes(scene).tobytes() == expected.tobytes()


def _split_mesh():
    """A torus over a floor whose first faces use copies of their vertices (a seam), and
    the vertex each copy copies."""
    knot = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3)
    floor = trimesh.creation.box(extents=[4, 0.1, 4])
    floor.apply_translation([0, -0.4, 0])
    mesh = trimesh.util.concatenate([knot, floor])
    v, f, n = mesh.vertices, mesh.faces, mesh.vertex_normals
    copies = f[:40].ravel()
    faces = f.copy()
    faces[:40] = len(v) + np.arange(copies.size).reshape(-1, 3)
    return trimesh.Trimesh(np.vstack([v, v[copies]]), faces,
                           vertex_normals=np.vstack([n, n[copies]]), process=False), copies


def test_points_are_the_scene_arrays_when_every_vertex_is_distinct():
    scene = load_scene(trimesh.creation.icosphere(2))
    plan = VertexTarget().sample(scene, BakeConfig(), None, 1, {}, [])
    assert plan.points is scene.vertices and plan.normals is scene.vertex_normals
    assert plan.state is plan.ids
    np.testing.assert_array_equal(plan.ids, np.arange(len(scene.vertices)))


def test_points_and_values_are_those_of_np_unique():
    """The plan holds np.unique's points (another order), and the bake's values at every
    vertex are those of the plan np.unique's order gives (the --keep-distances path)."""
    mesh, copied = _split_mesh()
    scene = load_scene(mesh, "file")
    config = BakeConfig(rays=16)
    lean = VertexTarget().sample(scene, config, None, 1, {}, [])
    kept = VertexTarget().sample(scene, replace(config, keep_distances=True), None, 1, {}, [])
    assert len(lean.points) == len(kept.points) < len(scene.vertices)
    by_id = np.argsort(kept.ids)
    for name in ("points", "normals", "ids", "sizes"):
        np.testing.assert_array_equal(getattr(lean, name), getattr(kept, name)[by_id])
    np.testing.assert_array_equal(lean.ids[lean.state], kept.ids[kept.state])
    result = aobake.bake(scene, rays=16, threads=2)
    ordered = aobake.bake(scene, rays=16, threads=1, chunk_points=37)
    for name, array in result.fields().items():
        assert array.tobytes() == ordered.fields()[name].tobytes(), name
    # a copy has its vertex's point: the same value, bit for bit
    copies = np.arange(len(copied)) + len(scene.vertices) - len(copied)
    np.testing.assert_array_equal(result.ao[copies], result.ao[copied])
