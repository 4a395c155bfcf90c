"""From texel samples (triangle + barycentrics) to surface points and shading normals."""

from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from aobake.targets.texels.raster import TexelSamples
from aobake.vectors import check_rows, normalize

log = logging.getLogger(__name__)


def surface_points(positions, normals, faces, samples: TexelSamples, threads: int = 1,
                   kernels=None, face_normals: bool = True):
    """Interpolate positions and shading normals at the samples.

    positions : (n, 3) float; normals : (n, 3) float vertex normals, or None
    for flat shading; faces : (f, 3) int, the faces the samples refer to; threads : blocks
    interpolated at once (the result does not depend on it); kernels : the compiled module
    (``aobake._native.kernels()``: interpolation and normalisation in one pass, the same
    bits) or None (numpy).

    Returns (points (s, 3) float64, normals (s, 3) float64 unit, face_normals
    (s, 3) float64 unit, or None with ``face_normals=False``: the bake does not need them,
    and 2M rows of them are 50 MB of fresh memory, ~0.1 s in first touches).  The shading normal is the normalised interpolated
    vertex normal n, except:

    * on a face that agrees with its vertex normals (``(n_0 + n_1 + n_2) . f >= 0``
      for its unit face normal f and unit corner normals n_i), f where n is zero or
      points against the face (``n . f <= 0``): near a crease the smoothed normal can
      tip below the face, and a hemisphere around it would dip into the surface;
    * on a face *turned against* its vertex normals (that sum ``. f < 0``): n, and
      ``-f`` where n is zero.  Such a face is a folded sliver (a near-degenerate
      triangle whose corner lies past the opposite edge: its own normal points into
      the solid while the surface around it faces out) or a triangle wound against its
      neighbours (``--fix-normals``); its vertex normals, averages over the surface
      around it, say where outside is, and a hemisphere around f would bake a dark
      texel on a surface that is open.

    A face with zero 3D area has a zero face normal; its shading normal is then the
    interpolated one, or zero if that is zero too (such samples have no surface and
    should be dropped by the caller).
    """
    positions = check_rows("positions", positions)
    faces = np.asarray(faces, dtype=np.int64)
    if normals is not None:
        normals = check_rows("normals", normals, n=len(positions))
    # Face normals once per face (not per sample): np.cross on millions of rows is slow.
    ftri = positions[faces]
    fn = np.cross(ftri[:, 1] - ftri[:, 0], ftri[:, 2] - ftri[:, 0])
    unit, fn_len = normalize(fn)
    turned = None
    has_face = fn_len[:, 0] > 0  # (f,) bool
    if normals is not None:
        unit_normals = normalize(normals)[0]
        corner_sum = unit_normals[faces].sum(axis=1)  # (f, 3)
        turned = np.einsum("ij,ij->i", corner_sum, unit) < 0  # (f,) bool, False if f = 0
    s = samples.n_samples
    if kernels is not None:  # C-contiguous buffers for the kernel
        positions, faces = np.ascontiguousarray(positions), np.ascontiguousarray(faces)
        normals = None if normals is None else np.ascontiguousarray(normals)
        empty = np.zeros((0, 3))
    points, shading = np.empty((s, 3)), np.empty((s, 3))
    kept = np.empty((s, 3)) if face_normals else None

    def block(lo):
        """Fill rows lo .. lo + _SURFACE_BLOCK - 1; returns (n_bad, n_turned) of the block."""
        hi = min(s, lo + _SURFACE_BLOCK)
        face = samples.face[lo:hi]
        bary = samples.bary[lo:hi]

        def interpolate(values):  # the numpy formulation (the kernel's, operation for operation)
            corners = faces[face]  # (b, 3)
            return (bary[:, 0, None] * values[corners[:, 0]] + bary[:, 1, None] * values[corners[:, 1]]
                    + bary[:, 2, None] * values[corners[:, 2]])

        if kept is not None:
            kept[lo:hi] = unit[face]
        if kernels is not None:
            n, n_len = np.empty((hi - lo, 3)), np.empty((hi - lo, 1))
            kernels.surface_interp(positions, empty if normals is None else normals, faces,
                                   face, bary, points[lo:hi], n, n_len)
            if normals is not None:  # the choice below, in one pass
                return kernels.surface_shading(face, unit, has_face, turned, n, n_len,
                                               shading[lo:hi])
        else:
            points[lo:hi] = interpolate(positions)
        fnorm = unit[face]
        if normals is None:
            shading[lo:hi] = fnorm
            return 0, 0
        n, n_len = normalize(interpolate(normals))
        zero = n_len[:, 0] == 0
        against = turned[face]
        along = (n[:, 0] * fnorm[:, 0] + n[:, 1] * fnorm[:, 1]) + n[:, 2] * fnorm[:, 2]
        bad = has_face[face] & ~against & (zero | (along <= 0))
        n[bad] = fnorm[bad]
        flip = against & zero  # no interpolated direction: the face's, on its normals' side
        n[flip] = -fnorm[flip]
        shading[lo:hi] = n
        return int(bad.sum() + flip.sum()), int(against.sum())

    # In blocks: row-wise arithmetic, so the result is the same, but the temporaries
    # stay small (whole-array temporaries of millions of rows cost more in page
    # faults than in arithmetic).  Blocks write disjoint rows, so threads (numpy releases
    # the GIL in these passes) change nothing but the time.
    starts = range(0, s, _SURFACE_BLOCK)
    if threads > 1 and len(starts) > 1:
        with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="aobake-surface") as pool:
            counts = list(pool.map(block, starts))
    else:
        counts = [block(lo) for lo in starts]
    n_bad = sum(c[0] for c in counts)
    n_turned = sum(c[1] for c in counts)
    if n_bad:
        log.debug("%d samples use the face normal (vertex normal zero or flipped)", n_bad)
    if n_turned:
        log.debug("%d samples lie on faces turned against their vertex normals (folded slivers "
                  "or inconsistent winding): they use the vertex normals", n_turned)
    return points, shading, kept


#: samples interpolated at once by :func:`surface_points` (memory, not results)
_SURFACE_BLOCK = 1 << 16
