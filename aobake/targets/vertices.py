"""Per-vertex target: one sample point per distinct (position, normal) of the mesh."""

from __future__ import annotations

import numpy as np

from aobake.results import BakeResult
from aobake.targets.base import Finished, SamplePoints
from aobake.vectors import defined


def vertex_sizes(scene) -> np.ndarray:
    """(v,) float64 size of each vertex's triangles: sqrt(2 * mean area of the faces using it)
    (0 for an unreferenced vertex)."""
    areas = scene.areas()
    n = len(scene.vertices)
    total = np.bincount(scene.faces.ravel(), weights=np.repeat(areas, 3), minlength=n)
    count = np.bincount(scene.faces.ravel(), minlength=n)
    return np.sqrt(2.0 * total / np.maximum(count, 1))


def _dense_rank(values: np.ndarray) -> np.ndarray:
    """(n,) int64 rank of each of ``values`` (n,) among their distinct values, ascending."""
    order = np.argsort(values)  # any sort: equal values get one rank
    ranked = values[order]
    new = np.empty(len(values), dtype=np.int64)
    new[:1] = 0
    np.not_equal(ranked[1:], ranked[:-1], out=new[1:])
    rank = np.empty(len(values), dtype=np.int64)
    rank[order] = np.cumsum(new)
    return rank


def _differ(words: np.ndarray, order: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """(p,) bool: row ``order[k]`` of ``words`` differs from row ``order[k + 1]``, k in pairs."""
    return np.any(words[order[pairs]] != words[order[pairs + 1]], axis=1)


def distinct_rows(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first (k,) int64, inverse (n,) int64) of the rows of ``keys`` (n, w) float64 as byte
    strings: exactly ``np.unique`` over the rows viewed as (n,) void records with
    ``return_index`` and ``return_inverse`` (rows ordered as their bytes compare, like
    memcmp; ``first`` the smallest index of each distinct row; -0.0 and 0.0, and NaNs of
    different bits, distinct), 3x faster.

    Two 8-byte words read big-endian order as memcmp orders their bytes, so the rows
    are sorted by the dense ranks of the first two words (packed with the row index into
    one int64: a plain sort is the stable argsort), and only neighbours that tie on both
    are compared whole; the runs of those that still differ (equal first 16 bytes, a
    position shared by two normals) are sorted by their bytes as np.unique would.
    """
    keys = np.ascontiguousarray(keys, dtype=np.float64)
    n, width = keys.shape
    if n == 0 or width < 2:
        rows = keys.view(np.dtype((np.void, keys.itemsize * width))).ravel()
        _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
        return first, inverse.reshape(-1)
    words = keys.view(np.uint64)  # equal words, equal bytes
    lead = keys[:, :2].view(">u8").astype(np.uint64)
    key = _dense_rank(lead[:, 0]) * n + _dense_rank(lead[:, 1])
    if n < 2_097_152:  # key * n + index < 2^63
        packed = key * n + np.arange(n, dtype=np.int64)
        packed.sort()
        order = packed % n
    else:
        order = np.argsort(key, kind="stable")
    key = key[order]
    tie = key[1:] == key[:-1]
    new = np.empty(n, dtype=bool)  # the first row of each distinct row, in sorted order
    new[:1] = True
    np.logical_not(tie, out=new[1:])
    pairs = np.flatnonzero(tie)
    if len(pairs):
        unequal = _differ(words, order, pairs)
        if unequal.any():
            records = keys.view(np.dtype((np.void, 8 * width))).ravel()
            run = np.cumsum(new) - 1
            slots = np.flatnonzero(np.isin(run, run[pairs[unequal]]))
            sub = order[slots]  # index order within each run: a stable sort keeps it
            order[slots] = sub[np.argsort(records[sub], kind="stable")]
            unequal = _differ(words, order, pairs)
        new[pairs + 1] = unequal
    inverse = np.empty(n, dtype=np.int64)
    inverse[order] = np.cumsum(new) - 1
    return order[new], inverse


class VertexTarget:
    """AO at the scene's vertices, in file order."""

    name = "vertices"

    def rays_per_point(self, config) -> int:
        return config.rays

    def sample(self, scene, config, occluders, threads, timings, warnings,
               phase=None) -> SamplePoints:
        # Vertices that share position and normal get the same point id, hence the same
        # samples and identical values (no noise seam where a file splits vertices at UV seams).
        # Points in the order of their 48-byte (position, normal) records, as np.unique.
        first, inverse = distinct_rows(np.concatenate([scene.vertices, scene.vertex_normals],
                                                      axis=1))
        return SamplePoints(scene.vertices[first], scene.vertex_normals[first],
                            first.astype(np.int64), sizes=vertex_sizes(scene)[first],
                            state=inverse.reshape(-1))

    def finish(self, scene, config, plan, estimates, timings, warnings) -> Finished:
        inverse = plan.state
        values = {name: array[inverse] for name, array in estimates.fields.items()}
        unsampled = int(np.count_nonzero(~defined(scene.vertex_normals)))
        if unsampled:
            warnings.append(f"{unsampled} vertices have no defined normal (unreferenced or only on "
                            "zero-area faces): not sampled, no-information values")
        if estimates.rays is None:  # a method that casts no rays (an approximation, a file)
            result = BakeResult(scene.vertices, scene.faces, scene.vertex_normals, None, values)
            return Finished(result, values, None, len(scene.vertices))
        # rays traced before copying to vertices that share samples
        traced = int(estimates.rays.astype(np.int64).sum())
        rays = estimates.rays[inverse]
        result = BakeResult(scene.vertices, scene.faces, scene.vertex_normals, rays, values)
        return Finished(result, values, rays, len(scene.vertices), cast=traced)
