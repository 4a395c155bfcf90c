"""``aobake._embree`` (occlusion in packets, on embreex's libembree4) answers every query as
embreex does: the same booleans, distances and primitives, in both traversal modes, for
any number of rays and any split into calls; it refuses malformed buffers."""

import numpy as np
import pytest
import trimesh

import aobake
from aobake import _native
from aobake.backends import native
from aobake.backends.embree import EmbreeBackend
from aobake.scene import face_normals


@pytest.fixture
def compiled():
    """The compiled binding; skips where it was not built (.ci/run asserts CI built it)."""
    found = native.binding()
    if found is None:
        pytest.skip("aobake._embree was not built or embreex's libembree4 was not found")
    return found


def _scene(seed):
    rng = np.random.default_rng(seed)
    parts = []
    for _ in range(8):
        m = trimesh.creation.icosphere(subdivisions=2, radius=rng.uniform(0.1, 0.4))
        m.apply_translation(rng.uniform(-1, 1, 3))
        parts.append(m)
    box = trimesh.creation.box(extents=(2.5, 2.5, 2.5))  # closed: rays from inside all hit
    parts.append(box)
    mesh = trimesh.util.concatenate(parts)
    return mesh.vertices, mesh.faces.astype(np.int64)


def _rays(seed, n):
    """Points with 8-ray fans (as a tracer lays them out) plus n % 8 loose rays; unit
    directions; tmax per ray from 0 (a zero-length segment) to beyond the scene."""
    rng = np.random.default_rng(seed + 1)
    o = np.repeat(rng.uniform(-1.2, 1.2, (n // 8 + 1, 3)), 8, axis=0)[:n]
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    tmax = rng.choice([0.0, 0.05, 0.3, 1.0, np.float32(1e37)], size=n).astype(np.float32)
    return o.astype(np.float32), d.astype(np.float32), tmax


@pytest.mark.parametrize("robust", [True, False])
@pytest.mark.parametrize("seed,n", [(0, 20000), (1, 8 * 997 + 5), (2, 3)])
def test_compiled_answers_as_embreex(compiled, seed, n, robust):
    v, f = _scene(seed)
    fn = face_normals(v, f)
    fast = EmbreeBackend(v, f, fn, step=1e-5, robust=robust)
    with _native.embreex_only():
        slow = EmbreeBackend(v, f, fn, step=1e-5, robust=robust)
    assert fast.binding.startswith("aobake._embree") and slow.binding == "embreex"
    o, d, tmax = _rays(seed, n)
    hit = fast.occluded(o, d, tmax)
    assert hit.dtype == bool and np.array_equal(hit, slow.occluded(o, d, tmax))
    assert 0 < hit.mean() < 1  # both answers occur
    assert np.array_equal(fast.distance(o, d, tmax), slow.distance(o, d, tmax))
    t_fast, p_fast = fast.intersect(o, d, tmax)
    t_slow, p_slow = slow.intersect(o, d, tmax)
    assert np.array_equal(p_fast, p_slow)
    assert np.array_equal(t_fast[p_fast >= 0], t_slow[p_slow >= 0])
    # front-face queries are built on intersect: the same too
    assert np.array_equal(fast.front_occluded(o, d, tmax), slow.front_occluded(o, d, tmax))
    # every packet width this CPU answers gives the same answers
    module, widest = compiled
    for width in (1, 4, 8, 16):
        if width <= widest:
            out = np.empty(n, dtype=bool)
            module.occluded(fast._handle, o, d, tmax, out, width)
            assert np.array_equal(out, hit), width
    # a ray's answer does not depend on the rays packed beside it: any split, the same
    parts = [fast.occluded(o[s:s + 13], d[s:s + 13], tmax[s:s + 13]) for s in range(0, n, 13)]
    assert np.array_equal(np.concatenate(parts), hit)


def test_bake_records_the_binding_and_matches_embreex(compiled, tmp_path):
    mesh = trimesh.creation.annulus(r_min=0.3, r_max=1.0, height=0.6, sections=24)
    path = tmp_path / "ring.obj"
    mesh.export(path)
    for quantities in (["ao", "bent_normal"], ["obscurance"]):
        fast = aobake.bake(str(path), rays=64, seed=3, quantities=quantities)
        with _native.embreex_only():
            slow = aobake.bake(str(path), rays=64, seed=3, quantities=quantities)
        assert fast.report["parameters"]["embree_binding"].startswith("aobake._embree")
        assert slow.report["parameters"]["embree_binding"] == "embreex"
        fields = fast.fields()
        assert set(fields) == set(slow.fields()) and len(fields) >= 2
        for name, value in fields.items():
            assert np.array_equal(value, slow.fields()[name], equal_nan=True), name


def test_malformed_buffers_are_refused(compiled):
    module, _ = compiled
    v = np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1]], dtype=np.float32)
    scene = module.scene(v, 3, np.array([[0, 1, 2]], dtype=np.uint32), 1, True)
    o = np.zeros((4, 3), np.float32)
    d = np.tile(np.float32([0, 0, 1]), (4, 1))
    out = np.empty(4, dtype=bool)
    for width in (1, 4, 8, 16):
        if width <= compiled[1]:
            out[:] = False
            module.occluded(scene, o, d, np.full(4, 2, np.float32), out, width)
            assert out.all()
    with pytest.raises(ValueError, match="width"):
        module.occluded(scene, o, d, np.full(4, 2, np.float32), out, 3)
    with pytest.raises(ValueError, match="directions"):
        module.occluded(scene, o, d[:3], np.full(4, 2, np.float32), out, 1)
    with pytest.raises(ValueError, match="tfar"):
        module.occluded(scene, o, d, np.full(4, 2, np.float64), out, 1)
    with pytest.raises(ValueError, match="faces"):
        module.scene(v, 3, np.array([0, 1], dtype=np.uint32), 1, True)
    with pytest.raises(ValueError, match="index 3"):  # a corner past the vertices
        module.scene(v, 3, np.array([[0, 1, 3]], dtype=np.uint32), 1, True)
    with pytest.raises(ValueError, match="PyCapsule"):
        module.occluded(object(), o, d, np.full(4, 2, np.float32), out, 1)


def test_without_the_compiled_binding_embreex_traces(monkeypatch, tmp_path):
    """Where aobake._embree was not built or refused the library (another Embree major
    version), binding() is None and the bake traces through embreex, saying so."""
    monkeypatch.setattr(native, "_opened", (None, "refused for the test"))
    assert native.binding() is None
    mesh = trimesh.creation.box()
    path = tmp_path / "box.obj"
    mesh.export(path)
    result = aobake.bake(str(path), rays=16, seed=1)
    assert result.report["parameters"]["embree_binding"] == "embreex"
    monkeypatch.undo()
    if native.binding() is not None:  # and the compiled binding gives the same bits
        again = aobake.bake(str(path), rays=16, seed=1)
        assert again.report["parameters"]["embree_binding"].startswith("aobake._embree")
        assert np.array_equal(again.ao, result.ao)


def test_a_refused_library_falls_back_with_its_reason(compiled, monkeypatch, caplog):
    """_open: a library the module refuses (here: its open() raising as for an Embree of
    another major version) leaves embreex tracing, and the reason is logged."""
    import logging

    module, _ = compiled

    def refuse(path):
        raise OSError(f"{path} is Embree 50000, not 4.x")

    monkeypatch.setattr(native, "_opened", None)
    monkeypatch.setattr(module, "open", refuse)
    with caplog.at_level(logging.INFO, logger="aobake.backends.native"):
        assert native.binding() is None
    assert "not 4.x" in caplog.text


def test_packet_widths_give_the_same_bake_and_the_report_names_the_width(compiled, tmp_path,
                                                                         monkeypatch):
    """The packet width is a speed choice only: 16 lanes and 8 (and 4, and one ray at a
    time) give the same bits in every output of a whole bake, with bent normals (whose
    directions are averaged over the unoccluded rays) and a max distance; the report's
    parameters.embree_binding names the width and what chose it."""
    _, widest = compiled
    mesh = trimesh.creation.annulus(r_min=0.3, r_max=1.0, height=0.6, sections=24)
    path = tmp_path / "ring.obj"
    mesh.export(path)
    bakes = {}
    for width in (16, 8, 4, 1):
        if width > widest:
            continue
        monkeypatch.setenv(native.WIDTH_VARIABLE, str(width))
        bakes[width] = aobake.bake(str(path), rays=96, seed=5, max_distance=0.8,
                                   quantities=["ao", "bent_normal"])
        binding = bakes[width].report["parameters"]["embree_binding"]
        assert f"packets of {width}: {native.WIDTH_VARIABLE}" in binding, binding
    assert 8 in bakes and 16 in bakes
    first = bakes[8].fields()
    for width, result in bakes.items():
        fields = result.fields()
        assert set(fields) == set(first)
        for name, value in fields.items():
            assert np.array_equal(value, first[name], equal_nan=True), (width, name)
    # unset: Embree's native width on this CPU (16 with AVX-512, 8 with AVX2, 4 with SSE)
    monkeypatch.delenv(native.WIDTH_VARIABLE)
    chosen = native.native_width()
    assert chosen in (4, 8, 16) and native.packet_width(widest) == (chosen, "native")
    result = aobake.bake(str(path), rays=96, seed=5, max_distance=0.8,
                         quantities=["ao", "bent_normal"])
    assert (f"packets of {chosen}: Embree's native width"
            in result.report["parameters"]["embree_binding"])
    assert np.array_equal(result.ao, bakes[8].ao)


@pytest.mark.parametrize("text", ["3", "32", "eight", "-8"])
def test_a_bad_packet_width_is_refused(compiled, monkeypatch, text):
    from aobake.errors import InputError

    monkeypatch.setenv(native.WIDTH_VARIABLE, text)
    with pytest.raises(InputError, match=native.WIDTH_VARIABLE):
        native.packet_width(compiled[1])
    monkeypatch.setenv(native.WIDTH_VARIABLE, "16")
    if compiled[1] < 16:  # wider than this Embree answers
        with pytest.raises(InputError, match="at most"):
            native.packet_width(compiled[1])
