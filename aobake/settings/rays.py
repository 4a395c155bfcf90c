"""The ray-traced method's options (``--method rays``): how many rays, how they are drawn,
where they start, and the error bars and accuracy asked of them."""

from __future__ import annotations

from dataclasses import dataclass

from aobake.samplers import SAMPLERS
from aobake.samplers.base import MAX_REPLICATES, MIN_REPLICATES, REPLICATES
from aobake.settings.spec import setting

#: largest rays per point (vertex, query point, texel or pixel).  Not a memory limit (a
#: point's rays stream in pieces of samplers.base.PIECE_RAYS, whatever their number): ray
#: counts are stored as float32 in glTF and EXR, exact up to 2^24, and at this count the
#: error is already ~1e-6; more is refused up front.
MAX_RAYS = 1 << 24
#: highest interval level: a two-sided tail of 1e-12 (a family-wise level over 10^10
#: points); nearer 1 the Student quantiles are not computable to a useful precision in
#: float64.
MAX_CONFIDENCE = 1.0 - 1e-12
#: default ray offset, as a fraction of the size of the point's own triangles (the square
#: root of twice their mean area: an edge length), never below OFFSET_ULPS float32 ulps of
#: the point's rebased coordinates.  Geometry at the point, not the bounding box: a stray
#: far-away triangle changes no point's offset.  (aobake.trace.point_offsets)  On the bunny
#: the float32 floor (2.4e-7 median) and 1e-3 of the triangle size (1.25e-6) give mean AO
#: 0.89496 and 0.89499: no self-hits at the floor, so the size term only needs to be small;
#: 1e-5 keeps its bias on coarse closed-form scenes (triangles 6 across) below 0.1 stderr at
#: 4096 rays.
DEFAULT_RAY_OFFSET = 1e-5
BACKFACES = ("occlude", "ignore")

_TOO_MANY = (f"per point is above the limit of {MAX_RAYS} (2^24: ray counts are stored "
             "exactly as float32 in glTF and EXR)")


@dataclass(frozen=True)
class RaysOptions:
    """The ``rays`` method's settings (each field's help is its documentation)."""

    rays: int = setting(
        256, "int", "Rays per vertex, or per texel (split over --texel-samples), or per "
        "pixel; at most 2^24. stratified rounds up to a multiple of --replicates (R, "
        f"default {REPLICATES}), sobol to R x 2^k. Above 65536 a point's rays stream in "
        "pieces: memory does not grow.",
        section="rays", low=1, high=MAX_RAYS, too_high=_TOO_MANY)
    sampler: str = setting(
        "sobol", "choice", "random: i.i.d.; stratified: --replicates jittered grids; sobol: "
        "--replicates Owen-scrambled Sobol nets. Every point randomised on its own; all "
        "unbiased.", section="rays", choices=tuple(SAMPLERS))
    replicates: int = setting(
        REPLICATES, "int", "stratified/sobol: independent replicates per point, whose spread "
        "is the stderr (R - 1 degrees of freedom). Fewer: a more accurate value for the rays, "
        "a less steady stderr and wider intervals (docs/accuracy.md).", section="rays",
        low=MIN_REPLICATES, high=MAX_REPLICATES)
    backfaces: str = setting(
        "occlude", "choice", "ignore: rays pass through back faces (costs closest-hit "
        "queries).", section="rays", choices=BACKFACES)
    ray_offset: float = setting(
        DEFAULT_RAY_OFFSET, "float", "Ray origin offset along the normal, as a fraction of "
        "the point's own triangle size (at least 64 float32 ulps of its coordinates).",
        section="rays", low=0.0, high=0.1, low_open=True, high_open=True,
        label="ray_offset")
    confidence: float = setting(
        0.95, "float", "Level of the *_ci_low / *_ci_high interval every ao and obscurance "
        "value carries.", section="rays", low=0.5, high=MAX_CONFIDENCE)
    tolerance: float | None = setting(
        None, "float", "Ask for an accuracy instead of a ray count: every ao/obscurance value "
        "within E of the truth at --confidence. --rays is then a pilot; each point casts "
        "fresh rays chosen from it (up to --max-rays). The report counts the points that "
        "met E.", section="rays", optional=True, low=0.0, high=0.5, high_open=True)
    max_rays: int = setting(
        65536, "int", "--tolerance: the most rays a point's final stage may cast.",
        section="rays", low=1, high=MAX_RAYS, too_high=_TOO_MANY)
    bounces: int = setting(
        1, "int", "-q indirect: reflections a path may take before it reaches the sky (its "
        "sample is albedo^k after k); 1 is one bounce of indirect light.", section="rays",
        low=1, high=64, panel="indirect")
    keep_distances: bool = setting(
        False, "flag", "NPZ: keep every ray's hit distance (4 bytes per ray), so that "
        "'aobake refit' recomputes ao/obscurance for another --max-distance (up to this "
        "one) or --tau without tracing.", section="rays")

    def check_rays(self) -> None:
        """The checks between this record's fields."""
        from aobake.errors import InputError

        if self.keep_distances and self.tolerance is not None:
            raise InputError("keep_distances needs one ray count for every point; it cannot "
                             "be combined with a tolerance")
