"""Per-vertex target: one sample point per distinct (position, normal) of the mesh."""

from __future__ import annotations

import numpy as np

from aobake import _native
from aobake.records import (BakeResult, BlockRows, BlockSizes, Finished, PointRange,
                            SamplePoints)
from aobake.vectors import count_defined

#: faces whose corner areas are summed at a time by :func:`vertex_sizes` (bounds its
#: temporary to 24 bytes per face of one block, not of the mesh)
SIZE_BLOCK = 1 << 16
#: the odd multiplier of the row hash (2^64 / golden ratio): any odd constant groups the
#: rows the same; this one spreads nearby bit patterns over the high bits
_MIX = np.uint64(0x9E3779B97F4A7C15)


def vertex_sizes(scene) -> np.ndarray:
    """(v,) float64 size of each vertex's triangles: sqrt(2 * mean area of the faces using it)
    (0 for an unreferenced vertex).

    Each vertex's areas are added in corner order (face 0 corners 0, 1, 2, face 1, ...), as
    one ``np.bincount`` over the corners adds them, a block of faces at a time
    (``np.add.at`` adds in sequence onto the running sums: the same bits) so the
    repeated areas never exist for the whole mesh (24 bytes a face), nor, for a lean scene
    (``Scene.lean``), the areas themselves (8 bytes a face: each block's are remade)."""
    faces = scene.faces
    n = len(scene.vertices)
    total = np.zeros(n)
    for start in range(0, len(faces), SIZE_BLOCK):
        block = slice(start, start + SIZE_BLOCK)
        np.add.at(total, faces[block].reshape(-1), np.repeat(scene.areas(block), 3))
    count = np.bincount(faces.reshape(-1), minlength=n)
    return np.sqrt(2.0 * total / np.maximum(count, 1))


def vertex_parts(scene):
    """(vertex_offsets, face_offsets) (k + 1,) int64 of the scene's vertex-disjoint parts
    (a set's baked instances, ``Scene.instances``: part j owns vertices
    [vertex_offsets[j], vertex_offsets[j + 1]) and faces [face_offsets[j], ...), and its
    faces use its vertices only), or None for a scene without them (loaded flat, or whose
    arrays a selection changed)."""
    instances = getattr(scene, "instances", None)
    vertex_offsets = getattr(instances, "vertex_offsets", None)
    face_offsets = getattr(instances, "face_offsets", None)
    if vertex_offsets is None or face_offsets is None or len(vertex_offsets) < 2:
        return None
    vertex_offsets = np.asarray(vertex_offsets, dtype=np.int64)
    face_offsets = np.asarray(face_offsets, dtype=np.int64)
    if (len(face_offsets) != len(vertex_offsets) or vertex_offsets[0] != 0 or face_offsets[0] != 0
            or vertex_offsets[-1] != len(scene.vertices) or face_offsets[-1] != len(scene.faces)):
        return None
    for k in range(len(vertex_offsets) - 1):  # every part's faces on its own vertices
        own = scene.faces[face_offsets[k]:face_offsets[k + 1]]
        if len(own) and (own.min() < vertex_offsets[k] or own.max() >= vertex_offsets[k + 1]):
            return None
    return vertex_offsets, face_offsets


def part_sizes(scene, parts, k: int) -> np.ndarray:
    """(v_k,) float64 :func:`vertex_sizes` of part ``k``'s vertices (``parts``:
    :func:`vertex_parts`), the same bits as those rows of the whole: a vertex's faces are its
    part's, and ``np.bincount`` adds each vertex's corner areas in corner order, as the
    whole's ``np.add.at`` does."""
    from aobake.scene import compiled_triangle_normals

    vertex_offsets, face_offsets = parts
    v0, v1 = int(vertex_offsets[k]), int(vertex_offsets[k + 1])
    faces = slice(int(face_offsets[k]), int(face_offsets[k + 1]))
    own = scene.faces[faces] - v0
    areas = None
    if scene.face_areas is None and scene.frame is not None:
        # ``Scene.areas`` of a lean scene (``scene.face_rows``), from the part's vertices put
        # in the frame once rather than each corner's: the same coordinates, the same bits,
        # ~8x faster than gathering every corner
        center, scale = scene.frame
        compiled = compiled_triangle_normals((scene.vertices[v0:v1] - center) * scale, own)
        if compiled is not None:
            areas = 0.5 * compiled[1] / (scale * scale)
    if areas is None:
        areas = scene.areas(faces)
    corners = own.reshape(-1)
    total = np.bincount(corners, weights=np.repeat(areas, 3), minlength=v1 - v0)
    count = np.bincount(corners, minlength=v1 - v0)
    return np.sqrt(2.0 * total / np.maximum(count, 1))


def _overlapping(lo: np.ndarray, hi: np.ndarray) -> list:
    """[[part, ...], ...] the groups of parts whose boxes ``lo``, ``hi`` (k, 3) overlap,
    touching included, directly or through others (a sweep along x, union-find)."""
    k = len(lo)
    root = list(range(k))

    def find(i):
        while root[i] != i:
            root[i] = root[root[i]]
            i = root[i]
        return i

    order = np.argsort(lo[:, 0], kind="stable").tolist()
    active: list = []
    for i in order:
        active = [j for j in active if hi[j, 0] >= lo[i, 0]]
        for j in active:
            if np.all(lo[i] <= hi[j]) and np.all(lo[j] <= hi[i]):
                root[find(i)] = find(j)
        active.append(i)
    groups: dict = {}
    for i in range(k):
        groups.setdefault(find(i), []).append(i)
    return list(groups.values())


def distinct_by_part(positions, normals, vertex_offsets, kernels=None) -> bool:
    """Every row (position, normal) of (v, 3) float64 ``positions`` and ``normals`` is
    distinct bit for bit (:func:`distinct_rows` would return (None, None)), found part by
    part: rows of parts whose boxes do not overlap differ in position, so only the rows of
    parts whose boxes overlap are searched together (memory: the largest such group's)."""
    return shared_by_part(positions, normals, vertex_offsets, kernels) is None


def shared_by_part(positions, normals, vertex_offsets, kernels=None):
    """The rows of (v, 3) float64 ``positions`` and ``normals`` that repeat an earlier row
    bit for bit, found part by part as :func:`distinct_by_part` does: (repeated (r,) int64
    increasing, owner (r,) int64 the first row of each one's value), or None where every
    row is distinct.  The same groups as :func:`distinct_rows` of the whole (its ``first``
    is every row not repeated), holding 16 bytes a repeated row, not a row."""
    bounds = [(int(vertex_offsets[j]), int(vertex_offsets[j + 1]))
              for j in range(len(vertex_offsets) - 1)]
    lo = np.array([positions[a:b].min(axis=0) if b > a else np.full(3, np.inf)
                   for a, b in bounds]).reshape(-1, 3)
    hi = np.array([positions[a:b].max(axis=0) if b > a else np.full(3, -np.inf)
                   for a, b in bounds]).reshape(-1, 3)
    repeated, owner = [], []
    for group in _overlapping(lo, hi):
        # the group's rows in file order (its parts ascending: ``_overlapping`` lists them
        # so), so each value's first row here is its first row in the whole
        index = np.concatenate([np.arange(*bounds[j]) for j in sorted(group)])
        first, inverse = distinct_rows(positions[index], normals[index], kernels)
        if first is None:
            continue
        again = np.flatnonzero(first[inverse] != np.arange(len(index)))
        repeated.append(index[again])
        owner.append(index[first[inverse[again]]])
    if not repeated:
        return None
    repeated, owner = np.concatenate(repeated), np.concatenate(owner)
    order = np.argsort(repeated, kind="stable")
    return repeated[order], owner[order]


class SharedRows:
    """The (v,) int64 ``inverse`` of a plan whose points are a set's distinct vertex rows
    (``state``: the point of each vertex), held as its repeated rows only: ``repeated``
    (r,) int64 increasing and ``owner_point`` (r,) int64 the point each repeats; every other
    vertex w is point w - (repeated rows before w).  :meth:`gather` makes the per-vertex
    arrays a block of vertices at a time; numpy reads the whole as the array."""

    dtype = np.dtype(np.int64)
    ndim = 1

    def __init__(self, n: int, repeated: np.ndarray, owner_point: np.ndarray):
        self.n, self.repeated, self.owner_point = int(n), repeated, owner_point
        self.shape = (self.n,)

    def __len__(self) -> int:
        return self.n

    def rows(self, start: int, stop: int) -> np.ndarray:
        """(stop - start,) int64 the points of vertices start..stop-1."""
        w = np.arange(start, stop, dtype=np.int64)
        out = w - np.searchsorted(self.repeated, w)
        a, b = np.searchsorted(self.repeated, [start, stop])
        out[self.repeated[a:b] - start] = self.owner_point[a:b]
        return out

    def gather(self, array: np.ndarray) -> np.ndarray:
        """(v, ...) ``array`` (p, ...) of the points read at each vertex's point:
        ``array[inverse]`` a block of vertices at a time."""
        out = np.empty((self.n,) + array.shape[1:], dtype=array.dtype)
        for start in range(0, self.n, SIZE_BLOCK):
            stop = min(self.n, start + SIZE_BLOCK)
            out[start:stop] = array[self.rows(start, stop)]
        return out

    def firsts(self, values: np.ndarray) -> BlockRows:
        """(p, ...) the points' rows of per-vertex ``values`` (v, ...) (each point's first
        vertex: the rows not repeated), read a block of vertices at a time, not held."""
        starts = np.arange(0, self.n + SIZE_BLOCK, SIZE_BLOCK).clip(max=self.n)
        starts = np.unique(starts)
        bounds = starts - np.searchsorted(self.repeated, starts)

        def make(j):
            a, b = int(starts[j]), int(starts[j + 1])
            keep = np.ones(b - a, dtype=bool)
            lo, hi = np.searchsorted(self.repeated, [a, b])
            keep[self.repeated[lo:hi] - a] = False
            return values[a:b][keep]

        return BlockRows(bounds, make, values.dtype, values.shape[1:])

    def land(self, estimates) -> tuple:
        """(values name -> (v, ...), rays (v,) int32 | None) of the points' ``estimates``
        gathered to every vertex, each of the estimates' per-point arrays given up as it is
        gathered (replaced by :meth:`firsts` of what it became: the same rows, read where
        the record and warnings read them), the largest first: what is held beyond the
        per-vertex arrays is at most the last, smallest one."""
        values = {}
        names = sorted(estimates.fields, key=lambda name: -estimates.fields[name].nbytes)
        for name in names:
            values[name] = self.gather(estimates.fields[name])
            estimates.fields[name] = self.firsts(values[name])
        rays = None
        if estimates.rays is not None:
            rays = self.gather(estimates.rays)
            estimates.rays = self.firsts(rays)
        return {name: values[name] for name in estimates.fields}, rays

    def __array__(self, dtype=None, copy=None):
        whole = self.rows(0, self.n)
        return whole if dtype is None else whole.astype(dtype)


def shared_plan(scene, parts, repeated, owner) -> SamplePoints:
    """The plan of a set's instances some of whose vertex rows repeat others (``repeated``,
    ``owner``: :func:`shared_by_part`): its points the rows not repeated, in file order (the
    whole search's ``first``), made an instance at a time (``records.BlockRows``: points,
    normals, ids, and sizes as ``records.BlockSizes``), its state a :class:`SharedRows`:
    nothing held for every vertex besides the outputs and 16 bytes a repeated row."""
    vertex_offsets = parts[0]
    n = len(scene.vertices)
    cut = np.searchsorted(repeated, vertex_offsets)  # repeated rows before each part
    point_bounds = vertex_offsets - cut

    def local(k):  # (p_k,) int64 the rows of part k not repeated, from its first vertex
        v0, v1 = int(vertex_offsets[k]), int(vertex_offsets[k + 1])
        keep = np.ones(v1 - v0, dtype=bool)
        keep[repeated[cut[k]:cut[k + 1]] - v0] = False
        return np.flatnonzero(keep)

    def rows(array):
        return BlockRows(point_bounds, lambda k: array[int(vertex_offsets[k]) + local(k)],
                         array.dtype, array.shape[1:])

    ids = BlockRows(point_bounds, lambda k: int(vertex_offsets[k]) + local(k), np.int64)
    sizes = BlockSizes(point_bounds, lambda k: part_sizes(scene, parts, k)[local(k)])
    owner_point = owner - np.searchsorted(repeated, owner)
    return SamplePoints(rows(scene.vertices), rows(scene.vertex_normals), ids, sizes=sizes,
                        state=SharedRows(n, repeated, owner_point))


def _row_hash(columns, n: int) -> np.ndarray:
    """(n,) uint32 a hash of the float64 bits of each row of ``columns`` (each (n,) float64):
    rows equal bit for bit hash equal (the converse is checked by the caller)."""
    h = np.zeros(n, dtype=np.uint64)
    for column in columns:
        np.bitwise_xor(h, np.asarray(column, dtype=np.float64).view(np.uint64), out=h)
        np.multiply(h, _MIX, out=h)
        np.bitwise_xor(h, h >> np.uint64(29), out=h)
    return (h >> np.uint64(32)).astype(np.uint32)


def distinct_rows(positions: np.ndarray, normals: np.ndarray, kernels=None):
    """The rows (position, normal) of (v, 3) float64 ``positions`` and ``normals`` that are
    distinct bit for bit, in file order.

    Returns (first (p,) int64 increasing: the first row of each distinct value,
    inverse (v,) int64: the index into ``first`` of each row's value), or (None, None)
    when every row is distinct (``first`` and ``inverse`` would both be 0..v-1).  The
    groups are ``np.unique``'s of the 48-byte rows (equal bytes; -0.0 is not 0.0) and each
    group's first row its ``return_index``; only the order of ``first`` differs (file
    order, not the rows' byte order).

    Memory: a 32-bit hash of each row and its sort (about 28 bytes a row while it runs),
    then the exact comparison of the rows whose hashes collide; ``np.unique`` of the rows
    held two copies of every 48-byte row.  kernels : the compiled module (its radix sort)
    or None (numpy's).
    """
    n = len(positions)
    if n < 2:
        return None, None
    columns = [positions[:, k] for k in range(3)] + [normals[:, k] for k in range(3)]
    key = _row_hash(columns, n)
    if kernels is not None:
        order, ordered = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.uint32)
        kernels.radix_argsort(key, 32, order, ordered)
    else:
        order = np.argsort(key, kind="stable")
        ordered = key[order]
    del key
    collide = np.zeros(n, dtype=bool)  # in sorted order: rows sharing their hash
    same = ordered[1:] == ordered[:-1]
    collide[1:] |= same
    collide[:-1] |= same
    del ordered, same
    candidates = np.sort(order[collide])  # file order
    del order, collide
    if not len(candidates):
        return None, None
    rows = np.ascontiguousarray(np.concatenate([positions[candidates], normals[candidates]],
                                               axis=1), dtype=np.float64)
    records = rows.view(np.dtype((np.void, rows.itemsize * rows.shape[1]))).ravel()
    _, head, group = np.unique(records, return_index=True, return_inverse=True)
    owner = candidates[head[group.reshape(-1)]]  # each candidate's group's first row
    repeated = candidates[owner != candidates]
    if not len(repeated):
        return None, None
    is_first = np.ones(n, dtype=bool)
    is_first[repeated] = False
    first = np.flatnonzero(is_first)
    inverse = np.cumsum(is_first, dtype=np.int64) - 1
    inverse[repeated] = inverse[owner[owner != candidates]]
    return first, inverse


def _identity(index) -> bool:
    """``index`` is 0..n-1 (compared a block at a time: no n-sized temporary)."""
    if isinstance(index, PointRange):
        return True
    step = SIZE_BLOCK
    return all(np.array_equal(index[i:i + step], np.arange(i, min(len(index), i + step)))
               for i in range(0, len(index), step))


class VertexTarget:
    """AO at the scene's vertices, in file order."""

    name = "vertices"

    def rays_per_point(self, config) -> int:
        return config.rays

    def sample(self, scene, config, occluders, threads, timings, warnings,
               phase=None) -> SamplePoints:
        # Vertices that share position and normal get the same point id, hence the same
        # samples and identical values (no noise seam where a file splits vertices at UV seams).
        if getattr(config, "keep_distances", False):
            # The kept distances' rows (the NPZ's ray_distances) are the points in the
            # rows' byte order, np.unique's: that layout is part of the file.
            keys = np.ascontiguousarray(np.concatenate([scene.vertices, scene.vertex_normals],
                                                       axis=1))
            rows = keys.view(np.dtype((np.void, keys.itemsize * keys.shape[1]))).ravel()
            _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
            return SamplePoints(scene.vertices[first], scene.vertex_normals[first],
                                first.astype(np.int64), sizes=vertex_sizes(scene)[first],
                                state=inverse.reshape(-1))
        parts = vertex_parts(scene)
        if parts is not None:
            shared = shared_by_part(scene.vertices, scene.vertex_normals, parts[0],
                                    _native.kernels())
            if shared is not None:  # instances placed alike, seams with one normal
                return shared_plan(scene, parts, *shared)
            # A set's instances, every vertex its own point: its ids and inverse one 0..v-1
            # (PointRange), its sizes made an instance at a time where the tracer reaches
            # them (BlockSizes): nothing held for every vertex besides the outputs.
            ids = PointRange(len(scene.vertices))
            sizes = BlockSizes(parts[0], lambda k: part_sizes(scene, parts, k))
            return SamplePoints(scene.vertices, scene.vertex_normals, ids, sizes=sizes,
                                state=ids)
        first, inverse = distinct_rows(scene.vertices, scene.vertex_normals, _native.kernels())
        sizes = vertex_sizes(scene)
        if first is None:
            # Every vertex is its own point: the scene's arrays, not copies (the tracer and
            # the executors only read them); ids and the inverse are one 0..v-1, not made
            # (PointRange: 8 bytes a point the trace does not hold).
            ids = PointRange(len(scene.vertices))
            return SamplePoints(scene.vertices, scene.vertex_normals, ids, sizes=sizes,
                                state=ids)
        return SamplePoints(scene.vertices[first], scene.vertex_normals[first], first,
                            sizes=sizes[first], state=inverse)

    def finish(self, scene, config, plan, estimates, timings, warnings) -> Finished:
        inverse = plan.state
        # every vertex its own point, in order: the estimates are the result as they are
        same = len(inverse) == len(plan.points) and _identity(inverse)
        traced = None if estimates.rays is None else int(np.sum(estimates.rays, dtype=np.int64))
        if isinstance(inverse, SharedRows):
            # a set whose rows repeat: each per-point array given up as it is gathered
            values, rays = inverse.land(estimates)
        else:
            values = {name: array if same else array[inverse]
                      for name, array in estimates.fields.items()}
            rays = None if estimates.rays is None else (
                estimates.rays if same else estimates.rays[inverse])
        unsampled = len(scene.vertex_normals) - count_defined(scene.vertex_normals)
        if unsampled:
            why = ("unreferenced, only on zero-area faces, or only on faces --exclude left "
                   "out" if config.exclude else "unreferenced or only on zero-area faces")
            warnings.append(f"{unsampled} vertices have no defined normal ({why}): not "
                            "sampled, no-information values")
        if estimates.rays is None:  # a method that casts no rays (an approximation, a file)
            result = BakeResult(scene.vertices, scene.faces, scene.vertex_normals, None, values)
            return Finished(result, values, None, len(scene.vertices))
        # (traced: the rays summed before copying to vertices that share samples, without
        # an int64 copy of them)
        result = BakeResult(scene.vertices, scene.faces, scene.vertex_normals, rays, values)
        return Finished(result, values, rays, len(scene.vertices), cast=traced)
