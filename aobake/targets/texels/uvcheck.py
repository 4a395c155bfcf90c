"""Can a mesh's own UVs be baked as they are?  (Range, overlap, mirroring, degeneracy.)

Conventions as in ``aobake.targets.texels.raster``: OBJ UVs, no wrapping.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aobake.targets.texels.raster import _check_uv_faces, rasterize

#: A UV triangle with |area| below this (in uv units, i.e. as a fraction of the
#: whole atlas) counts as degenerate.  At 16k x 16k one texel is ~3.7e-9, so
#: this is about a millionth of a texel at any practical resolution.
DEGENERATE_UV_AREA = 1e-15


@dataclass(frozen=True)
class UVCheck:
    """Result of checking a mesh's own UVs for baking.

    valid : bool
        True when no face has a corner outside [0, 1]^2, no texel centre is
        covered by more than one triangle, and the UVs cover something (some texel
        centre, and at most half the faces without UV area).
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
    """

    valid: bool
    out_of_range_faces: int
    overlapping_texels: int
    mirrored_faces: int
    degenerate_faces: int
    message: str


def _signed_uv_area(uv: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(f,) float64 signed area in uv units; > 0 for counter-clockwise (v up)."""
    t = uv[faces]
    e1 = t[:, 1] - t[:, 0]
    e2 = t[:, 2] - t[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def check_uvs(uv, faces, width: int, height: int, shared: np.ndarray | None = None) -> UVCheck:
    """Check whether a mesh's own UVs can be baked into a width x height image.

    uv : (n, 2) float, OBJ convention; faces : (f, 3) int.
    Overlap is measured by rasterising the texel centres (K = 1) with the
    module's coverage rule, so it is exactly the overlap the bake would see.
    shared : (height, width) int, ``TexelSamples.shared`` of a rasterisation of
        these UVs that was already made (any K: the centre counts do not depend
        on it), which saves rasterising again.
    """
    uv, faces = _check_uv_faces(uv, faces, width, height)
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
        shared = rasterize(uv, faces, width, height, texel_samples=1).shared
    elif np.shape(shared) != (height, width):
        raise ValueError(f"shared must be ({height}, {width}), got {np.shape(shared)}")
    overlapping = int(np.count_nonzero(np.asarray(shared) > 1))

    covered = int(np.count_nonzero(np.asarray(shared) > 0))
    n_degenerate = int(degenerate.sum())
    # UVs that cover (almost) nothing cannot hold a lightmap, however valid they are
    # otherwise: every face at one point, or most faces without area.
    empty = covered == 0 or n_degenerate > len(faces) // 2
    valid = out_of_range == 0 and overlapping == 0 and not empty
    parts = []
    if out_of_range:
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
    )
