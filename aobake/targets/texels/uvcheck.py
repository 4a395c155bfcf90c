"""Can a mesh's own UVs be baked as they are?  (Range, wrapping, overlap, mirroring, degeneracy.)

Conventions as in ``aobake.targets.texels.raster``: OBJ UVs; the rasteriser itself never
wraps.  Own UVs partly outside [0, 1]^2 are baked *wrapped* (:func:`wrap_uvs`): the map is
then meant to be sampled with repeat wrapping (glTF sampler REPEAT; the outputs' metadata
say ``texture.wrap = "repeat"``), so a UV (u, v) reads the texel at (u mod 1, v mod 1).

Wrapping rule.  A face with every corner in [0, 1]^2 stays where it is (UVs already in
range bake exactly as before).  Any other face is moved by the whole tiles that bring its
centroid into [0, 1)^2: ``-floor(centroid)``.  A moved face that still crosses the border
of [0, 1]^2 covers texels on both sides of it under repeat wrapping, so it is rastered
once at every tile position whose bounding box overlaps the open square (at most 4; each
copy is clipped to the image by the rasteriser, and the copies' parts are disjoint).  A
face wider or taller than one tile would cover texels twice: such UVs are not wrappable
and are rejected as out of range (a new atlas).  After wrapping, overlap is measured as
for any layout (texel centres covered twice), so tiling UVs (a floor repeating a texture
ten times) still get a new atlas.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from aobake.targets.texels.raster import TexelSamples, _check_uv_faces, rasterize
from aobake.vectors import distinct, unique_ints

#: A UV triangle with |area| below this (in uv units, i.e. as a fraction of the
#: whole atlas) counts as degenerate.  At 16k x 16k one texel is ~3.7e-9, so
#: this is about a millionth of a texel at any practical resolution.
DEGENERATE_UV_AREA = 1e-15


@dataclass(frozen=True)
class UVCheck:
    """Result of checking a mesh's own UVs for baking.

    valid : bool
        True when the UVs, wrapped (module docstring), cover no texel centre with
        more than one triangle, no face is wider or taller than one tile, and they
        cover something (some texel centre, and at most half the faces without UV
        area).
    out_of_range_faces : int
        Faces with any corner outside [0, 1]^2 (or non-finite).
    overlapping_texels : int
        Texels whose centre is covered by two or more triangles (overlapping or
        mirrored-and-stacked shells).  Triangles sharing an edge never both
        cover one centre (see the module's coverage rule).
    mirrored_faces : int
        Non-degenerate faces whose signed UV area has the minority sign.
    degenerate_faces : int
        Faces with |UV area| < DEGENERATE_UV_AREA; they receive no texels.
    message : str
        One human-readable line summarising the above.
    wrapped : bool
        The faces outside [0, 1]^2 were wrapped into it: the map needs repeat wrapping.
    split_faces : int
        Wrapped faces crossing a border of [0, 1]^2, rastered on both sides of it.
    oversized_faces : int
        Faces wider or taller than one tile, or with non-finite corners (not wrappable).
    bakeable : bool
        Valid but for the overlap: wrappable and covering something (``--uv-overlap
        average`` bakes such UVs as they are).
    """

    valid: bool
    out_of_range_faces: int
    overlapping_texels: int
    mirrored_faces: int
    degenerate_faces: int
    message: str
    wrapped: bool = False
    split_faces: int = 0
    oversized_faces: int = 0
    bakeable: bool = False


@dataclass(frozen=True)
class Overlap:
    """Where a mesh's own UVs overlap: what ``--uv-overlap refuse`` shows.

    shared : (height, width) int32  triangles covering each texel centre (>= 2: overlap)
    faces : (k,) int64              input faces covering an overlapping texel centre, sorted
    pairs : (p, 2) int64            distinct pairs of different input faces sharing a texel
                                    centre (at each such texel, its faces in order paired
                                    with their neighbours), each row sorted, rows in order
    mirrored : int                  how many of ``faces`` are mirrored in UV (the minority
                                    orientation): a mirrored half stacked on its twin
    """

    shared: np.ndarray
    faces: np.ndarray
    pairs: np.ndarray
    mirrored: int

    @property
    def texels(self) -> int:
        """Texel centres covered by two or more triangles."""
        return int(np.count_nonzero(self.shared >= 2))


def find_overlap(uv, faces, width: int, height: int, layout: WrappedUVs | None = None) -> Overlap:
    """The faces and face pairs that share texel centres of a width x height image, by the
    bake's own coverage rule (a K = 1 rasterisation of the wrapped layout: exactly the
    overlap ``check_uvs`` counts).  uv : (n, 2) float, OBJ convention; faces : (f, 3) int."""
    uv, faces = _check_uv_faces(uv, faces, width, height)
    if layout is None:
        layout = wrap_uvs(uv, faces)
    samples = layout.to_faces(rasterize(layout.uv, layout.faces, width, height,
                                        texel_samples=1))
    hot = (samples.shared.reshape(-1)[samples.texel] >= 2) & ~samples.is_fallback
    texel, face = samples.texel[hot], samples.face[hot]  # sorted by texel
    # each texel's distinct faces in order; neighbours in that order make the pairs (every
    # pair where two faces stack, the usual case; a chain where more do)
    span = int(face.max(initial=0)) + 1
    texel, face = np.divmod(unique_ints(texel * span + face), span)
    same = texel[1:] == texel[:-1]
    low = np.minimum(face[:-1][same], face[1:][same]).astype(np.int64)
    high = np.maximum(face[:-1][same], face[1:][same]).astype(np.int64)
    # the distinct (low, high) rows in lexicographic order, as np.unique(axis=0) gives
    # them (its sort of row records took 0.6 s for a 1024^2 map that overlaps everywhere)
    pairs = np.stack(np.divmod(unique_ints(low * span + high), span), axis=1).reshape(-1, 2)
    involved = distinct(face, span)
    area = _signed_uv_area(uv, faces)
    sign = np.sign(area)
    minority = -1.0 if np.count_nonzero(sign > 0) >= np.count_nonzero(sign < 0) else 1.0
    mirrored = int(np.count_nonzero(sign[involved] == minority))
    return Overlap(samples.shared, involved, pairs, mirrored)


@dataclass(frozen=True)
class WrappedUVs:
    """Own UVs laid out for rasterising with repeat wrapping (module docstring).

    uv : (t, 2) float64        UVs to rasterise (the input's when nothing is wrapped)
    faces : (c, 3) int64       their triangles (the input's when nothing is wrapped)
    face : (c,) int64 | None   input face of each triangle, non-decreasing (so samples
                               sorted by triangle stay sorted by face); None: the identity
    moved_faces : int          faces moved by whole tiles
    split_faces : int          faces rastered at more than one tile position
    oversized_faces : int      faces wider or taller than one tile (or with non-finite
                               corners): not wrappable, and the layout is then the
                               input's, unwrapped
    """

    uv: np.ndarray
    faces: np.ndarray
    face: np.ndarray | None
    moved_faces: int = 0
    split_faces: int = 0
    oversized_faces: int = 0

    @property
    def wrapped(self) -> bool:
        """True when the layout differs from the input's: the map needs repeat wrapping."""
        return self.face is not None

    def to_faces(self, samples: TexelSamples) -> TexelSamples:
        """Samples of a rasterisation of this layout, with ``face`` = the input's faces."""
        if self.face is None:
            return samples
        return replace(samples, face=self.face[samples.face])


#: tile offsets a face copy may take, in the order copies are made
_TILES = np.array([(du, dv) for du in (-1, 0, 1) for dv in (-1, 0, 1)], dtype=np.float64)


def wrap_uvs(uv, faces) -> WrappedUVs:
    """The layout a mesh's own UVs are baked in, wrapped into [0, 1]^2 (module docstring).

    uv : (n, 2) float, OBJ convention; faces : (f, 3) int per-corner indices into ``uv``.
    """
    uv, faces = _check_uv_faces(uv, faces, 1, 1)
    corners = uv[faces]  # (f, 3, 2)
    inside = np.all((corners >= 0.0) & (corners <= 1.0), axis=(1, 2))
    if inside.all():
        return WrappedUVs(uv, faces, None)
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    # Non-finite corners cannot be moved anywhere either: counted with the oversized.
    unwrappable = ~np.isfinite(corners).all(axis=(1, 2)) | np.any(hi - lo > 1.0, axis=1)
    oversized = int(np.count_nonzero(~inside & unwrappable))
    if oversized:
        return WrappedUVs(uv, faces, None, oversized_faces=oversized)
    shift = np.where(inside[:, None], 0.0, -np.floor(corners.mean(axis=1)))  # (f, 2) whole tiles
    # Copies at each tile whose box overlaps the open square (0, 1)^2; the face's own
    # position always (a zero-area face on the border keeps its one copy).
    total = shift[:, None, :] + _TILES[None]  # (f, 9, 2), integers: exact
    keep = np.all((lo[:, None] + total < 1.0) & (hi[:, None] + total > 0.0), axis=2)
    keep[:, 4] = True  # _TILES[4] = (0, 0)
    face, tile = np.nonzero(keep)  # row-major: by face, then tile
    # One addition of the whole integer shift, so corners shared by two faces moved alike
    # stay bit-identical (the rasteriser's watertight edge rule relies on it).
    moved = corners[face] + total[face, tile][:, None, :]
    copies = np.bincount(face, minlength=len(faces))
    return WrappedUVs(moved.reshape(-1, 2), np.arange(3 * len(face), dtype=np.int64).reshape(-1, 3),
                      face.astype(np.int64), moved_faces=int(np.count_nonzero(shift.any(axis=1))),
                      split_faces=int(np.count_nonzero(copies > 1)))


def _signed_uv_area(uv: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(f,) float64 signed area in uv units; > 0 for counter-clockwise (v up)."""
    t = uv[faces]
    e1 = t[:, 1] - t[:, 0]
    e2 = t[:, 2] - t[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def check_uvs(uv, faces, width: int, height: int, shared: np.ndarray | None = None,
              layout: WrappedUVs | None = None) -> UVCheck:
    """Check whether a mesh's own UVs can be baked into a width x height image.

    uv : (n, 2) float, OBJ convention; faces : (f, 3) int.
    Overlap is measured by rasterising the texel centres (K = 1) of the wrapped
    layout (:func:`wrap_uvs`) with the raster module's coverage rule, so it is
    exactly the overlap the bake would see.
    shared : (height, width) int, ``TexelSamples.shared`` of a rasterisation of
        ``layout`` that was already made (any K: the centre counts do not depend
        on it), which saves rasterising again.
    layout : ``wrap_uvs(uv, faces)`` when already made.
    """
    uv, faces = _check_uv_faces(uv, faces, width, height)
    if layout is None:
        layout = wrap_uvs(uv, faces)
    corners = uv[faces]  # (f, 3, 2)
    in_range = np.all(np.isfinite(corners) & (corners >= 0.0) & (corners <= 1.0), axis=(1, 2))
    out_of_range = int(np.count_nonzero(~in_range))

    area = _signed_uv_area(uv, faces)
    finite = np.isfinite(area)
    degenerate = ~finite | (np.abs(area) < DEGENERATE_UV_AREA)
    n_pos = int(np.count_nonzero((area > 0) & ~degenerate))
    n_neg = int(np.count_nonzero((area < 0) & ~degenerate))
    # Which orientation is "mirrored" is only defined relative to the majority.
    mirrored = min(n_pos, n_neg)

    if shared is None:
        shared = rasterize(layout.uv, layout.faces, width, height, texel_samples=1).shared
    elif np.shape(shared) != (height, width):
        raise ValueError(f"shared must be ({height}, {width}), got {np.shape(shared)}")
    overlapping = int(np.count_nonzero(np.asarray(shared) > 1))

    covered = int(np.count_nonzero(np.asarray(shared) > 0))
    n_degenerate = int(degenerate.sum())
    # UVs that cover (almost) nothing cannot hold a lightmap, however valid they are
    # otherwise: every face at one point, or most faces without area.
    empty = covered == 0 or n_degenerate > len(faces) // 2
    wrappable = layout.wrapped or out_of_range == 0
    valid = wrappable and overlapping == 0 and not empty
    parts = []
    if layout.oversized_faces:
        parts.append(f"{out_of_range} faces have UVs outside [0, 1], {layout.oversized_faces} "
                     "of them wider or taller than one tile (not wrappable)")
    elif out_of_range and layout.wrapped:
        parts.append(f"{out_of_range} faces have UVs outside [0, 1], wrapped into it "
                     f"({layout.moved_faces} moved by whole tiles, {layout.split_faces} "
                     "rastered on both sides of a border; the map repeats)")
    elif out_of_range:
        parts.append(f"{out_of_range} faces have UVs outside [0, 1]")
    if overlapping:
        parts.append(f"{overlapping} texels are covered by more than one face")
    if mirrored:
        parts.append(f"{mirrored} faces are mirrored in UV")
    if n_degenerate:
        parts.append(f"{n_degenerate} faces have zero UV area")
    if empty:
        parts.append(f"the UVs cover {covered} texel centres of {width}x{height}")
    head = "UVs usable for baking" if valid else "UVs not usable for baking"
    message = head + (": " + "; ".join(parts) if parts else "")
    return UVCheck(
        valid=valid,
        out_of_range_faces=out_of_range,
        overlapping_texels=overlapping,
        mirrored_faces=mirrored,
        degenerate_faces=int(degenerate.sum()),
        message=message,
        wrapped=layout.wrapped,
        split_faces=layout.split_faces,
        oversized_faces=layout.oversized_faces,
        bakeable=wrappable and not empty,
    )
