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

Collapsed faces.  A face with surface area whose own UVs have none (its corners at one
point, or on one line) gets no texel of its own: it reads the texels at its point.  Such UVs
are baked all the same (collapsing hidden faces' UVs to a point is a common way to save
texture space; a warning names the count, ``bake_collapsed``): where the point is on the
surface's texels the face reads them; where it is off every chart, clear of them, the
texel at the point is baked with the faces collapsed there (a fallback sample each, at its
centroid), so its lookups read its own surface rather than a gutter's fill.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from aobake.targets.texels.raster import (FALLBACK_COVERAGE_FRACTION, TexelSamples,
                                         _check_uv_faces, rasterize)
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
    collapsed_faces : int | None
        Degenerate faces (above) that have surface area: their UVs collapse to a point or a
        line (module docstring); None when the surface was not given.
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
    collapsed_faces: int | None = None


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
              layout: WrappedUVs | None = None, has_area: np.ndarray | None = None) -> UVCheck:
    """Check whether a mesh's own UVs can be baked into a width x height image.

    uv : (n, 2) float, OBJ convention; faces : (f, 3) int.
    Overlap is measured by rasterising the texel centres (K = 1) of the wrapped
    layout (:func:`wrap_uvs`) with the raster module's coverage rule, so it is
    exactly the overlap the bake would see.
    shared : (height, width) int, ``TexelSamples.shared`` of a rasterisation of
        ``layout`` that was already made (any K: the centre counts do not depend
        on it), which saves rasterising again.
    layout : ``wrap_uvs(uv, faces)`` when already made.
    has_area : (f,) bool the faces with surface area (``seams.degenerate_faces`` negated),
        or None: ``collapsed_faces`` counts the degenerate ones among them.
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
    collapsed = None
    if has_area is not None:
        has_area = np.asarray(has_area, dtype=bool)
        if has_area.shape != (len(faces),):
            raise ValueError(f"has_area must be ({len(faces)},), got {has_area.shape}")
        collapsed = int(np.count_nonzero(degenerate & has_area))
    if n_degenerate:
        parts.append(f"{n_degenerate} faces have zero UV area" + (
            f" ({collapsed} of them with surface area)" if collapsed else ""))
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
        collapsed_faces=collapsed,
    )


@dataclass(frozen=True)
class Collapsed:
    """What ``bake_collapsed`` did with the faces whose UVs collapse (module docstring).

    faces : int        faces with surface area and no UV area (in the layout baked)
    on_surface : int   of them, at a point on a texel the surface covers: they read it
    baked : int        at a point off every chart, its texel and the 8 around it uncovered:
                       that texel baked with their own surface (a fallback sample each)
    gutter : int       the rest (off every chart but next to one, or outside the image):
                       they read the gutter's fill there
    """

    faces: int = 0
    on_surface: int = 0
    baked: int = 0
    gutter: int = 0

    def message(self) -> str:
        """One line for the warning: the count and what each part reads."""
        parts = [(self.on_surface, "lie on other faces' texels and read them"),
                 (self.baked, "off every chart, had the texel at their point baked with "
                              "their own surface"),
                 (self.gutter, "read the gutter where they lie, next to a chart or outside "
                               "the image")]
        return (f"{self.faces} faces with surface area have UVs collapsed to a point or a line "
                "(no texel of their own): "
                + "; ".join(f"{n} {what}" for n, what in parts if n))


def bake_collapsed(samples: TexelSamples, uv, faces, has_area) -> tuple[TexelSamples, Collapsed]:
    """Fallback samples for the collapsed faces off every chart (module docstring).

    samples : a rasterisation of ``uv`` (n, 2), ``faces`` (f, 3) (the layout baked, e.g.
    ``WrappedUVs.uv`` / ``.faces``, before ``to_faces``); has_area : (f,) bool the faces
    with surface area.  A face with |UV area| < DEGENERATE_UV_AREA and surface area has its
    point at its UV centroid; where that point's texel and the 8 around it hold no sample,
    the texel gets one fallback sample per face there (sample 0, barycentrics 1/3, sorted
    by face; coverage FALLBACK_COVERAGE_FRACTION / K, as the rasteriser's): no chart's
    lookup reads that texel, so it can hold their value.  Returns (samples, counts); the
    samples unchanged when no face is baked.
    """
    uv, faces = _check_uv_faces(uv, faces, samples.width, samples.height)
    has_area = np.asarray(has_area, dtype=bool)
    area = _signed_uv_area(uv, faces)
    collapsed = np.flatnonzero(has_area & ~(np.abs(area) >= DEGENERATE_UV_AREA))
    if not len(collapsed):
        return samples, Collapsed()
    width, height = samples.width, samples.height
    point = uv[faces[collapsed]].mean(axis=1)
    x, y = point[:, 0] * width, (1.0 - point[:, 1]) * height
    inside = np.isfinite(x) & np.isfinite(y) & (x >= 0) & (x <= width) & (y >= 0) & (y <= height)
    col = np.clip(np.floor(np.where(inside, x, 0.0)), 0, width - 1).astype(np.int64)
    row = np.clip(np.floor(np.where(inside, y, 0.0)), 0, height - 1).astype(np.int64)
    covered = samples.coverage > 0
    on_surface = inside & covered[row, col]
    padded = np.zeros((height + 2, width + 2), dtype=bool)
    padded[1:-1, 1:-1] = covered
    near = np.zeros(len(collapsed), dtype=bool)
    for dr in (0, 1, 2):
        for dc in (0, 1, 2):
            near |= padded[row + dr, col + dc]
    bake = inside & ~near
    n_surface, n_baked = int(np.count_nonzero(on_surface)), int(np.count_nonzero(bake))
    counts = Collapsed(len(collapsed), n_surface, n_baked, len(collapsed) - n_surface - n_baked)
    if not bake.any():
        return samples, counts
    new_face, new_texel = collapsed[bake], (row * width + col)[bake]
    order = np.lexsort((new_face, new_texel))  # by texel, then face
    new_face, new_texel = new_face[order], new_texel[order]
    # these texels hold no sample: each goes where a stable sort by texel would put it
    at = np.searchsorted(samples.texel, new_texel)
    coverage = samples.coverage.copy()
    coverage.reshape(-1)[new_texel] = FALLBACK_COVERAGE_FRACTION / samples.texel_samples
    third = np.full((len(new_face), 3), 1.0 / 3.0)
    return replace(samples, texel=np.insert(samples.texel, at, new_texel),
                   face=np.insert(samples.face, at, new_face),
                   bary=np.insert(samples.bary, at, third, axis=0),
                   sample=np.insert(samples.sample, at, 0),
                   is_fallback=np.insert(samples.is_fallback, at, True),
                   coverage=coverage), counts
