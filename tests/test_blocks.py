"""A set's instances traced a block at a time (issue 34 point 3): exact order statistics
read a block at a time (``aobake.select``), sizes made per instance (``records.BlockSizes``,
``targets.vertices.part_sizes``), the distinct-row search per group of overlapping
instances, and the bake they make: the same bits as the whole-array path."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import trimesh

from aobake import select
from aobake.records import BlockSizes


def _samples(rng, n, kind):
    if kind == 0:
        return rng.random(n)
    if kind == 1:  # many ties
        return rng.integers(0, 5, n).astype(float) * 0.1
    if kind == 2:  # both signs, many octaves
        return np.exp(rng.normal(0, 3, n)) * rng.choice([-1.0, 1.0], n)
    return np.full(n, 0.3)


@pytest.mark.parametrize("limit", [1, 3, select.GATHER_LIMIT])
def test_order_statistics_are_numpys_bits_in_any_blocks(limit, monkeypatch):
    """np.median and np.percentile of the values, bit for bit, from any cut into blocks, also
    where a bin holds more than ``limit`` values (the histogram refined to the key's last
    bits: ties, a constant array)."""
    monkeypatch.setattr(select, "GATHER_LIMIT", limit)
    rng = np.random.default_rng(34)
    for trial in range(400):
        n = int(rng.integers(1, 400)) if trial < 360 else int(rng.integers(1, 20000))
        x = _samples(rng, n, trial % 4)
        blocks = select.of_array(x, block=int(rng.integers(1, 500)))
        assert select.median(blocks) == float(np.median(x)), (n, trial)
        for q in (0, 50, 95, 99.9, 100):
            assert select.percentile(blocks, q) == float(np.percentile(x, q)), (n, q, trial)
    sorted_x = np.sort(x)
    values, count = select.order_statistics(blocks, lambda n: [0, n // 3, n - 1])
    assert count == len(x) and values == [sorted_x[0], sorted_x[len(x) // 3], sorted_x[-1]]


def test_order_statistics_of_nothing_and_of_nan():
    assert select.median(select.of_array(np.zeros(0))) is None
    assert select.percentile(select.of_array(np.zeros(0)), 95) is None
    x = np.array([1.0, np.nan, 2.0])
    assert np.isnan(select.median(select.of_array(x)))
    assert np.isnan(select.percentile(select.of_array(x), 95))
    mask = np.array([True, False, True])
    assert select.median(select.of_array(x, mask)) == 1.5


def test_block_sizes_stand_for_the_array_they_do_not_hold():
    """Every way the bake reads a plan's (n,) sizes gives that array's values; made only for
    the blocks a read reaches; pickled as the array."""
    whole = np.random.default_rng(1).random(50)
    bounds = np.array([0, 7, 7, 30, 50])
    made = []

    def make(k):
        made.append(k)
        return whole[bounds[k]:bounds[k + 1]].copy()

    sizes = BlockSizes(bounds, make)
    order = np.random.default_rng(7).permutation(50)
    mask = np.arange(50) % 3 == 0
    for key in (slice(None), slice(5, 17), slice(8, 9), slice(40, None, 3), order, order[:9],
                mask, np.array([-1, 0, 49]), slice(7, 7)):
        assert np.array_equal(sizes[key], whole[key]), key
    made.clear()
    assert np.array_equal(sizes[31:40], whole[31:40]) and made == [3]
    assert np.array_equal(np.asarray(sizes), whole) and len(sizes) == 50
    assert np.array_equal(pickle.loads(pickle.dumps(sizes)), whole)
    with pytest.raises(IndexError):
        sizes[np.array([50])]


def _set(tmp_path, overlap=False):
    """A set of five spheres sharing one mesh: turned, scaled, mirrored; with ``overlap`` two
    of them placed alike (their vertices coincide: shared samples)."""
    from gltf_scenes import write_instanced

    sphere = trimesh.creation.icosphere(2)
    nodes = [{"name": "a", "mesh": 0, "translation": [0.0, 0.0, 0.0]},
             {"name": "b", "mesh": 0, "translation": [1.5, 0.2, 0.0],
              "rotation": [0.0, 0.3826834, 0.0, 0.9238795]},
             {"name": "c", "mesh": 0, "translation": [0.0, 1.2, 0.9], "scale": [1.3, 0.7, 1.0]},
             {"name": "d", "mesh": 0, "translation": [3.0, 0.0, 0.0], "scale": [-1.0, 1.0, 1.0]},
             {"name": "e", "mesh": 0, "translation": [0.0, 0.0, 0.0] if overlap
              else [6.0, 0.0, 0.0]}]
    return write_instanced(tmp_path / "set.glb", [{"name": "sphere", "vertices": sphere.vertices,
                                                   "faces": sphere.faces}], nodes)


def _whole_array_path(monkeypatch):
    """The bake as before blocks: the plan's sizes one array (vertex_sizes of the whole)."""
    from aobake.targets import vertices

    monkeypatch.setattr(vertices, "vertex_parts", lambda scene: None)


def _same(a, b):
    for name in a.values:
        assert np.array_equal(a.values[name], b.values[name]), name
    assert np.array_equal(a.rays, b.rays)
    for key in ("ray_offset", "ray_offset_range"):
        assert a.report["parameters"][key] == b.report["parameters"][key], key
    assert a.report["error"] == b.report["error"]
    assert a.report["rays_cast"] == b.report["rays_cast"]


@pytest.mark.slow
def test_a_set_traced_a_block_at_a_time_gives_the_whole_arrays_bits(tmp_path, monkeypatch):
    """Sizes per instance, each instance's own trace order, the offsets made again for the
    report: the values, rays and report of the whole-array path, at any thread count and
    chunk size, and where an explicit split cuts the plan into items."""
    import aobake
    from aobake.targets import vertices

    path = str(_set(tmp_path))
    options = dict(rays=8, quantities=("ao", "bent_normal"), seed=3)
    from aobake.scene import load_scene

    scene = load_scene(path)
    assert vertices.vertex_parts(scene) is not None  # the blocks' path runs
    blocked = [aobake.bake(path, threads=t, chunk_rays=c, **options)
               for t, c in ((1, 131072), (2, 96), (2, 8))]
    split = aobake.bake(path, threads=2, chunk_points=700, **options)
    _whole_array_path(monkeypatch)
    whole = aobake.bake(path, threads=2, **options)
    for result in blocked + [split]:
        _same(result, whole)


@pytest.mark.slow
def test_instances_placed_alike_share_samples_as_before(tmp_path, monkeypatch):
    """Two instances placed alike put vertices at the same position with the same normal:
    the search over their overlapping boxes finds them, and the bake shares their samples
    as the whole set's search does (the same bits)."""
    import aobake
    from aobake.scene import load_scene
    from aobake.targets import vertices

    path = str(_set(tmp_path, overlap=True))
    scene = load_scene(path)
    parts = vertices.vertex_parts(scene)
    assert not vertices.distinct_by_part(scene.vertices, scene.vertex_normals, parts[0])
    first, _ = vertices.distinct_rows(scene.vertices, scene.vertex_normals)
    assert first is not None
    result = aobake.bake(path, rays=8, seed=5)
    a, e = (slice(*map(int, parts[0][k:k + 2])) for k in (0, 4))
    assert np.array_equal(result.ao[a], result.ao[e])
    _whole_array_path(monkeypatch)
    _same(result, aobake.bake(path, rays=8, seed=5))


def test_part_sizes_are_the_whole_sets_rows(tmp_path):
    """Each instance's vertex sizes are those rows of the whole set's vertex_sizes, bit for
    bit, and every group of instances whose boxes do not overlap is searched alone."""
    from aobake.scene import load_scene
    from aobake.targets import vertices

    scene = load_scene(str(_set(tmp_path)))
    parts = vertices.vertex_parts(scene)
    assert len(parts[0]) == 6
    mine = np.concatenate([vertices.part_sizes(scene, parts, k) for k in range(5)])
    assert np.array_equal(mine, vertices.vertex_sizes(scene))
    assert vertices.distinct_by_part(scene.vertices, scene.vertex_normals, parts[0])
    lo = np.array([[0, 0, 0], [2, 0, 0], [1, 1, 1], [5, 5, 5]], dtype=float)
    hi = lo + 1.0  # 0 touches 2, 2 touches 1: one group; 3 alone
    assert sorted(map(sorted, vertices._overlapping(lo, hi))) == [[0, 1, 2], [3]]


def test_merged_fills_the_result_as_parts_land_and_checks_the_tiling():
    """``records.Merged``: parts landing in any order give ``records.merge``'s arrays; a fold
    takes its extra instead of an (n,) array; a gap or an overlap is refused."""
    from aobake.records import Estimates, Merged, merge

    rng = np.random.default_rng(2)
    n, cuts = 40, [0, 7, 7, 19, 33, 40]
    whole = Estimates({"ao": rng.random(n), "bent_normal": rng.random((n, 3))},
                      rng.integers(0, 9, n).astype(np.int32), {"ray_offset": rng.random(n)}, 7)

    def part(a, b):
        return Estimates({k: v[a:b] for k, v in whole.fields.items()}, whole.rays[a:b],
                         {k: v[a:b] for k, v in whole.extras.items()}, 7)

    class Sum:
        def __init__(self):
            self.total = 0.0

        def add(self, start, stop, p):
            self.total += float(p.extras["ray_offset"].sum())

        def result(self):
            return self.total

    pieces = list(zip(cuts[:-1], cuts[1:]))
    merged, folded = Merged(n), Merged(n, {"ray_offset": Sum()})
    for a, b in pieces[::-1]:
        merged.add(a, b, part(a, b))
        folded.add(a, b, part(a, b))
    want = merge([(np.arange(a, b), part(a, b)) for a, b in pieces], n)
    for got in (merged.result(), folded.result()):
        for name in want.fields:
            assert np.array_equal(got.fields[name], want.fields[name]), name
        assert np.array_equal(got.rays, want.rays) and got.dof == 7
    assert np.array_equal(merged.result().extras["ray_offset"], want.extras["ray_offset"])
    assert folded.result().extras["ray_offset"] == pytest.approx(whole.extras["ray_offset"].sum())
    for bad in ([(0, 19), (19, 39)], [(0, 20), (19, 40)], [(0, 19), (20, 40)]):
        m = Merged(n)
        for a, b in bad:
            m.add(a, b, part(a, b))
        with pytest.raises(ValueError, match="exactly once"):
            m.result()


def test_split_items_are_cut_when_read(tmp_path):
    """``executors.base.items`` cuts an item's rows when it is read: a plan whose sizes are
    made a block at a time makes only the blocks an item reaches."""
    from aobake.executors.base import Job, items
    from aobake.records import PointRange, SamplePoints

    n = 50
    whole = np.random.default_rng(3).random(n)
    bounds = np.array([0, 10, 25, 50])
    made = []

    def make(k):
        made.append(k)
        return whole[bounds[k]:bounds[k + 1]].copy()

    plan = SamplePoints(np.zeros((n, 3)), np.ones((n, 3)), PointRange(n),
                        sizes=BlockSizes(bounds, make))
    work = items(Job(None, None, "rays", 8, True, "k"), plan, 20)
    assert len(work) == 3 and made == []
    item = work[1]
    assert (item.start, item.stop) == (20, 40) and made == [1, 2]
    assert np.array_equal(item.sizes, whole[20:40])
    assert np.array_equal(item.ids, np.arange(20, 40))
    assert [(i.start, i.stop) for i in work] == [(0, 20), (20, 40), (40, 50)]


@pytest.mark.slow
@pytest.mark.parametrize("executor", ["processes", "dask"])
def test_a_set_split_over_workers_gives_the_whole_arrays_bits(tmp_path, monkeypatch, executor):
    """A set's instances on the split executors (items cut as submitted, their rows landing
    in the result as they end, the ray offsets folded: ``offsets.OffsetFold``): the values,
    rays and report of the whole-array path, for the executor's own split and an explicit
    one; and --tolerance's likewise."""
    import aobake

    if executor == "dask":
        pytest.importorskip("distributed")
    path = str(_set(tmp_path))
    options = dict(rays=8, quantities=("ao", "bent_normal"), seed=3)
    split = [aobake.bake(path, threads=2, executor=executor, workers=2, chunk_points=c,
                         **options) for c in (None, 700)]
    tolerance = dict(rays=8, seed=4, tolerance=0.1, max_rays=64)
    adaptive = aobake.bake(path, threads=2, executor=executor, workers=2, chunk_points=900,
                           **tolerance)
    _whole_array_path(monkeypatch)
    whole = aobake.bake(path, threads=2, **options)
    for result in split:
        _same(result, whole)
    _same(adaptive, aobake.bake(path, threads=2, **tolerance))
    assert adaptive.report["tolerance"] == aobake.bake(path, **tolerance).report["tolerance"]


@pytest.mark.slow
def test_tolerance_a_block_at_a_time_gives_the_whole_arrays_bits(tmp_path, monkeypatch):
    """--tolerance on a set: an instance's stages at a time (``adaptive.estimate_blocks``,
    the final counts folded into ``adaptive.Tally``) give the values, rays and report of the
    whole-array path, at 1 and 2 threads and any chunk size."""
    import aobake
    from aobake import adaptive

    path = str(_set(tmp_path))
    options = dict(rays=8, seed=6, tolerance=0.15, max_rays=256,
                   quantities=("ao", "obscurance"))
    calls = []
    blocks = adaptive.estimate_blocks
    monkeypatch.setattr(adaptive, "estimate_blocks",
                        lambda *a, **k: calls.append(1) or blocks(*a, **k))
    blocked = [aobake.bake(path, threads=t, chunk_rays=c, **options)
               for t, c in ((1, 131072), (2, 40))]
    assert len(calls) == 2
    _whole_array_path(monkeypatch)
    whole = aobake.bake(path, threads=2, **options)
    assert whole.report["tolerance"]["points_met"] > 0
    assert whole.report["tolerance"]["final_rays"]["max"] > whole.report["tolerance"][
        "final_rays"]["min"]
    for result in blocked:
        _same(result, whole)
        assert result.report["tolerance"] == whole.report["tolerance"]


def test_tally_spread_is_numpys_min_median_max():
    """``adaptive._spread`` from a histogram of counts: np.min's, np.median's and np.max's
    values of the counts' array (shifted), for odd and even counts and ties."""
    from aobake import adaptive

    rng = np.random.default_rng(8)
    for trial in range(200):
        counts = rng.choice([8, 16, 24, 32, 64, 1000], int(rng.integers(1, 60)))
        kinds, many = np.unique(counts, return_counts=True)
        got = adaptive._spread(dict(zip(kinds.tolist(), many.tolist())), -8)
        shifted = counts.astype(np.int64) - 8
        assert got == {"min": int(shifted.min()), "median": float(np.median(shifted)),
                       "max": int(shifted.max())}, trial
    assert adaptive._spread({}) == {"min": 0, "median": 0.0, "max": 0}


@pytest.mark.slow
def test_a_set_sharing_rows_is_planned_an_instance_at_a_time(tmp_path, monkeypatch):
    """Two instances placed alike share rows: the plan's points are the whole search's
    ``first`` rows made an instance at a time (``records.BlockRows``) and its state the
    whole search's inverse held as the repeated rows (``vertices.SharedRows``); the bake
    gives the whole-array path's values, rays and report at 1 and 2 threads, any chunk,
    split into items, on processes, and with --tolerance."""
    import aobake
    from aobake.records import BlockRows
    from aobake.scene import load_scene
    from aobake.settings import BakeConfig
    from aobake.targets import vertices

    path = str(_set(tmp_path, overlap=True))
    scene = load_scene(path)
    plan = vertices.VertexTarget().sample(scene, BakeConfig(rays=8), None, 1, {}, [])
    first, inverse = vertices.distinct_rows(scene.vertices, scene.vertex_normals)
    assert isinstance(plan.points, BlockRows) and isinstance(plan.state, vertices.SharedRows)
    assert np.array_equal(np.asarray(plan.ids), first)
    assert np.array_equal(np.asarray(plan.points), scene.vertices[first])
    assert np.array_equal(plan.normals[5:400], scene.vertex_normals[first][5:400])
    assert np.array_equal(np.asarray(plan.sizes), vertices.vertex_sizes(scene)[first])
    assert np.array_equal(np.asarray(plan.state), inverse)
    values = np.random.default_rng(0).random((len(first), 3))
    assert np.array_equal(plan.state.gather(values), values[inverse])
    assert np.array_equal(np.asarray(plan.state.firsts(values[inverse])), values)
    assert np.array_equal(plan.state.firsts(values[inverse])[100:70000:7], values[100:70000:7])

    options = dict(rays=8, quantities=("ao", "bent_normal"), seed=3)
    tolerance = dict(rays=8, seed=6, tolerance=0.15, max_rays=256)
    got = [aobake.bake(path, threads=t, chunk_rays=c, **options)
           for t, c in ((1, 131072), (2, 40))]
    got.append(aobake.bake(path, threads=2, chunk_points=500, **options))
    got.append(aobake.bake(path, threads=2, executor="processes", workers=2, **options))
    adaptive = aobake.bake(path, threads=2, **tolerance)
    _whole_array_path(monkeypatch)
    whole = aobake.bake(path, threads=2, **options)
    for result in got:
        _same(result, whole)
    whole_adaptive = aobake.bake(path, threads=2, **tolerance)
    _same(adaptive, whole_adaptive)
    assert adaptive.report["tolerance"] == whole_adaptive.report["tolerance"]


@pytest.mark.slow
@pytest.mark.parametrize("overlap", [False, True])
def test_streamed_rays_a_block_at_a_time_give_the_whole_arrays_bits(tmp_path, monkeypatch,
                                                                    overlap):
    """More rays a point than one piece (streamed, ``PIECE_RAYS`` made 64 here): a set's
    instances streamed a block at a time (``Tracer._stream_blocks``) give the whole-array
    path's values, rays and report, at 1 and 2 threads and split into items, also where
    rows are shared."""
    import aobake
    from aobake.samplers import base
    from aobake.trace import Tracer

    monkeypatch.setattr(base, "PIECE_RAYS", 64)
    path = str(_set(tmp_path, overlap=overlap))
    options = dict(rays=256, quantities=("ao", "bent_normal"), seed=2)
    calls = []
    blocks = Tracer._stream_blocks
    monkeypatch.setattr(Tracer, "_stream_blocks",
                        lambda *a, **k: calls.append(1) or blocks(*a, **k))
    got = [aobake.bake(path, threads=t, **options) for t in (1, 2)]
    got.append(aobake.bake(path, threads=2, chunk_points=600, **options))
    assert len(calls) == 2
    _whole_array_path(monkeypatch)
    whole = aobake.bake(path, threads=2, **options)
    for result in got:
        _same(result, whole)


@pytest.mark.slow
def test_roles_by_name_on_a_set_sharing_rows_give_the_whole_arrays_bits(tmp_path, monkeypatch):
    """--exclude, --occluder-only (which zeroes the plan's normals: ``BlockRows.copy``) and
    --receive-only by node name on a set whose rows repeat: the whole-array path's bits."""
    import aobake

    path = str(_set(tmp_path, overlap=True))
    roles = (dict(exclude=("c",)), dict(occluder_only=("b",)), dict(receive_only=("d",)))
    got = [aobake.bake(path, rays=8, seed=1, **role) for role in roles]
    _whole_array_path(monkeypatch)
    for role, result in zip(roles, got):
        _same(result, aobake.bake(path, rays=8, seed=1, **role))
