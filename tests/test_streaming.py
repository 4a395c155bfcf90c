"""A point's rays stream in pieces: memory is bounded whatever the ray count, and the
streamed statistics equal the whole-point ones (AO bit for bit: exact counts)."""

import tracemalloc

import numpy as np
import pytest
import trimesh

import aobake
from aobake import _native
from aobake.samplers import base as samplers_base

QUANTITIES = ("ao", "obscurance", "bent_normal")


def _scene():
    """A unit box and query points on the plane of its bottom face, facing up: part of each
    hemisphere is blocked by the box (AO strictly between 0 and 1), hits at many distances."""
    box = trimesh.creation.box()
    x = np.linspace(0.55, 1.5, 6)
    points = np.stack([x, np.full_like(x, 0.2), np.full_like(x, -0.5)], axis=1)
    normals = np.tile([0.0, 0.0, 1.0], (len(x), 1))
    return box, points, normals


def _bake(rays, sampler, **options):
    box, points, normals = _scene()
    return aobake.bake_points(box, points, normals, rays=rays, sampler=sampler,
                              quantities=QUANTITIES, max_distance="inf", tau=2.0, **options)


def _fields(result):
    names = [f.name for q in result.report["config"]["quantities"]
             for f in aobake.quantities.QUANTITIES[q].fields]
    return {name: np.asarray(getattr(result, name)) for name in names}


@pytest.fixture
def small_pieces(monkeypatch):
    """Pieces of 256 rays, so a bake of 2048 rays per point streams in 8 pieces."""
    monkeypatch.setattr(samplers_base, "PIECE_RAYS", 256)


def test_streamed_statistics_equal_the_whole_point(sampler, monkeypatch):
    whole = _fields(_bake(2048, sampler, threads=1))
    monkeypatch.setattr(samplers_base, "PIECE_RAYS", 256)
    streamed_result = _bake(2048, sampler, threads=1)
    streamed = _fields(streamed_result)
    assert aobake.samplers.sample_set(sampler, 2048).piece < 2048  # it did stream
    for name in ("ao", "ao_stderr", "ao_ci_low", "ao_ci_high"):  # exact escape counts
        np.testing.assert_array_equal(streamed[name], whole[name], err_msg=name)
    # Float sums in another order (Chan's update): equal to rounding, ~1e-16 relative.
    for name in set(whole) - {"ao", "ao_stderr", "ao_ci_low", "ao_ci_high"}:
        np.testing.assert_allclose(streamed[name], whole[name], rtol=1e-12, atol=1e-14,
                                   err_msg=name)
    assert 0 < whole["ao"].min() and whole["ao"].max() < 1  # a partly blocked hemisphere


@pytest.mark.slow
@pytest.mark.parametrize("replicates", [2, 3, 6, 8])
def test_streamed_equals_whole_for_any_replicates(sampler, replicates, monkeypatch):
    """--replicates R not a power of two: the pieces stay powers of two (a Sobol piece is the
    first xor a digital shift only then), so streaming changes no AO bit."""
    whole = _fields(_bake(1536, sampler, threads=1, replicates=replicates))
    monkeypatch.setattr(samplers_base, "PIECE_RAYS", 256)
    samples = aobake.samplers.sample_set(sampler, 1536, replicates)
    assert samples.piece & (samples.piece - 1) == 0 and samples.piece < samples.m
    streamed = _fields(_bake(1536, sampler, threads=1, replicates=replicates))
    for name in ("ao", "ao_stderr", "ao_ci_low", "ao_ci_high"):
        np.testing.assert_array_equal(streamed[name], whole[name], err_msg=name)


def test_streamed_bits_do_not_depend_on_threads_or_chunks(sampler, small_pieces):
    a = _fields(_bake(2048, sampler, threads=1, chunk_rays=64))
    b = _fields(_bake(2048, sampler, threads=2))
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def test_streamed_rays_match_the_numpy_formulation(sampler, small_pieces, kernel):
    """The kernel's piece (js, mp) arguments against the numpy samplers' (j0, count)."""
    compiled = _fields(_bake(2048, sampler, threads=1))
    with _native.numpy_only():
        reference = _fields(_bake(2048, sampler, threads=1))
    for name in compiled:
        np.testing.assert_array_equal(compiled[name], reference[name], err_msg=name)


@pytest.mark.slow
def test_memory_does_not_grow_with_rays_per_point():
    """Peak traced memory at 2^22 rays per point (64 pieces) within 1.5x of one piece's
    (2^16 rays): one point's rays held at once would need ~64x (~200 MB)."""
    box, points, normals = _scene()

    def peak(rays):
        tracemalloc.start()
        try:
            aobake.bake_points(box, points[:1], normals[:1], rays=rays, threads=1,
                               quantities=QUANTITIES, max_distance="inf")
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    one_piece = peak(samplers_base.PIECE_RAYS)
    many = peak(64 * samplers_base.PIECE_RAYS)
    assert many < 1.5 * one_piece, (many, one_piece)


def test_sobol_pieces_are_the_net_in_order():
    """Piece tables (the first piece xor the digital shift of j0) are the Sobol points
    j0 .. j0 + piece - 1 of the whole net."""
    from aobake.samplers.sobol import reverse_bits, sobol_ints

    s = aobake.samplers.sample_set("sobol", 2**20)
    assert s.piece < s.m and len(s.table) == s.piece
    full = reverse_bits(sobol_ints(s.m))
    for j0 in range(0, s.m, s.piece):
        np.testing.assert_array_equal(s.table_for(j0, s.piece), full[j0:j0 + s.piece])
