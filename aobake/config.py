"""Bake configuration: one frozen dataclass, validated once, serialisable for the report.

One name per concept: the CLI flag ``--max-distance`` is the field
``max_distance`` and the report key ``max_distance``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

from aobake.errors import InputError

from aobake.backends import BACKENDS
from aobake.quantities import QUANTITIES, canonical
from aobake.repair import MODES as FIX_NORMALS
from aobake.samplers import SAMPLERS
from aobake.samplers.base import MAX_REPLICATES, MIN_REPLICATES, REPLICATES
from aobake.warp import WEIGHTINGS

NORMALS = ("file", "angle", "area")
BACKFACES = ("occlude", "ignore")
AXES = ("x", "y", "z")
UNWRAP = ("auto", "always", "never")
BENT_SPACES = ("object", "tangent")
SEAMS = ("erase", "off")

#: default ray offset, as a fraction of the size of the point's own triangles (the square
#: root of twice their mean area: an edge length), never below OFFSET_ULPS float32 ulps of
#: the point's rebased coordinates.  Geometry at the point, not the bounding box: a stray
#: far-away triangle changes no point's offset.  (aobake.trace.point_offsets)  On the bunny the
#: float32 floor (2.4e-7 median) and 1e-3 of the triangle size (1.25e-6) give mean AO 0.89496
#: and 0.89499: no self-hits at the floor, so the size term only needs to be small; 1e-5
#: keeps its bias on coarse closed-form scenes (triangles 6 across) below 0.1 stderr at 4096 rays.
DEFAULT_RAY_OFFSET = 1e-5
#: float32 ulps of a point's (rebased) coordinates its origin is lifted at least: Embree's
#: hit distances carry a few ulps of error, so 64 keeps a ray off its own triangle.
OFFSET_ULPS = 64
#: largest rays per point (vertex, query point or texel).  Not a memory limit (a point's
#: rays stream in pieces of samplers.base.PIECE_RAYS, whatever their number): ray counts are
#: stored as float32 in glTF and EXR, exact up to 2^24, and at this count the error is
#: already ~1e-6; more is refused up front.
MAX_RAYS = 1 << 24
#: highest interval level: a two-sided tail of 1e-12 (a family-wise level over 10^10 points);
#: nearer 1 the Student quantiles are not computable to a useful precision in float64.
MAX_CONFIDENCE = 1.0 - 1e-12
#: default tau for obscurance, in units of 1 / diagonal: rho reaches 1 - 1/e at a tenth of the scene size.
DEFAULT_TAU_DIAGONALS = 10.0


def parse_resolution(value) -> tuple[int, int]:
    """'N' or 'WxH' (or an int / pair) -> (width, height); ValueError on nonsense."""
    if isinstance(value, str):
        parts = value.lower().split("x")
        if len(parts) not in (1, 2) or not all(p.strip().isdigit() for p in parts):
            raise InputError(f"resolution must be N or WxH, got {value!r}")
        dims = [int(p) for p in parts]
    elif isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        dims = [int(value)]
    else:
        try:
            dims = [int(v) for v in value]
        except (TypeError, ValueError):
            raise InputError(f"resolution must be N or WxH, got {value!r}") from None
    if len(dims) not in (1, 2):
        raise InputError(f"resolution must be N or WxH, got {value!r}")
    width, height = (dims[0], dims[0]) if len(dims) == 1 else dims
    if width < 1 or height < 1:
        raise InputError(f"resolution must be at least 1x1, got {width}x{height}")
    return width, height


def parse_distance(value) -> float | str:
    """Accept a number (scene units), 'inf', or 'P%' (percent of the bounding-box diagonal).

    Returns a float or the string 'P%' unchanged; raises ValueError otherwise.
    """
    try:
        return _parse_distance(value)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"max distance must be a number, 'inf' or 'P%', got {value!r}") from None


def _parse_distance(value) -> float | str:
    if isinstance(value, str):
        text = value.strip().lower()
        if text.endswith("%"):
            percent = float(text[:-1])
            if not math.isfinite(percent) or percent < 0:
                raise InputError(f"max distance {value!r}: percentage must be finite and >= 0")
            return f"{percent:g}%"
        value = float(text)  # accepts 'inf'
    value = float(value)
    if math.isnan(value) or value < 0:
        raise InputError(f"max distance must be >= 0 (or inf), got {value}")
    return value


@dataclass(frozen=True)
class BakeConfig:
    """Everything that decides a bake's numbers (threads and chunking do not); the one
    source of every default (the CLI reads them from here).

    quantities   subset of QUANTITIES, in canonical order
    rays         rays per point (vertex, query point) or per texel, requested (the
                 report also gives rays actually cast)
    max_distance float in scene units (inf = unlimited) or 'P%' of the diagonal
    tau          obscurance decay per scene unit; None = DEFAULT_TAU_DIAGONALS / diagonal
    seed, sampler, weighting, normals, ground_plane, up_axis, backfaces: see the CLI help
    replicates   independent replicates per point of the stratified and sobol samplers (>= 2;
                 their spread is the stderr, with R - 1 degrees of freedom)
    fix_normals  warn | fix | off: triangles wound against their neighbours and components
                 pointing inward (``aobake.repair``) are counted in a warning, flipped, or
                 not looked for.  Default warn: a closed shell wound inward may be meant
                 (a room seen from inside), and a reference bakes what it is given
    ray_offset   origin offset along the normal, as a fraction of the point's own triangle
                 size (at least OFFSET_ULPS float32 ulps of its coordinates)
    backend      tracing backend (BACKENDS): embree, or the slow float64 reference
    confidence   two-sided level of every ``*_ci_low`` / ``*_ci_high`` interval
    tolerance    None (``rays`` per point) or E in [0, 0.5): each point casts ``rays`` as a
                 pilot, then a fresh fixed count chosen from it so that the half-width of
                 its intervals (ao, obscurance) is at most E (``aobake.adaptive``)
    max_rays     --tolerance's cap on a point's final rays (the pilot's come on top)
    keep_distances keep every ray's hit distance in the result (NPZ ``ray_distances``), so
                 that ``aobake refit`` recomputes AO and obscurance for another max distance
                 or tau without tracing (per vertex / point, not with a tolerance)
    Lightmaps only (ignored per vertex):
    resolution   (width, height) texels
    texel_density None, or texels per scene unit along the surface instead of a resolution:
                 a new atlas puts every chart at exactly this density in the smallest square
                 image that holds them; own UVs get the smallest square at which their mean
                 density reaches it.  ``resolution`` must then be left at its default
    padding      texels of gutter dilation; a new atlas leaves 2 x padding empty texels between
                 charts (default 2: bilinear lookups at mip levels 0 and 1 read one chart)
    texel_samples surface positions per texel; ``rays`` is split over them
    unwrap       auto (own UVs when valid, else xatlas) | always | never
    bent_space   object | tangent
    seams        erase (bilinear lookups made to agree across UV seams by a least-squares
                 change of the texels there, ``aobake.targets.texels.seams``) | off
    denoise      add ``<q>_denoised`` / ``<q>_denoised_stderr`` channels for AO and obscurance
                 beside the raw ones (``aobake.targets.texels.denoise``); EXR only
    """

    quantities: tuple = ("ao",)
    rays: int = 256
    max_distance: float | str = math.inf
    tau: float | None = None
    seed: int = 0
    sampler: str = "sobol"
    replicates: int = REPLICATES
    weighting: str = "cosine"
    normals: str = "file"
    fix_normals: str = "warn"
    ground_plane: bool = False
    up_axis: str = "y"
    backfaces: str = "occlude"
    ray_offset: float = DEFAULT_RAY_OFFSET
    backend: str = "embree"
    confidence: float = 0.95
    tolerance: float | None = None
    max_rays: int = 65536
    keep_distances: bool = False
    resolution: tuple = (1024, 1024)
    texel_density: float | None = None
    padding: int = 2
    texel_samples: int = 4
    unwrap: str = "auto"
    bent_space: str = "object"
    seams: str = "erase"
    denoise: bool = False

    def __post_init__(self):
        object.__setattr__(self, "quantities", canonical(self.quantities))
        for name, low in (("rays", 1), ("padding", 0), ("texel_samples", 1), ("max_rays", 1),
                          ("replicates", MIN_REPLICATES)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer, float)) \
                    or int(value) != value or value < low:
                what = {0: "a non-negative integer", 1: "a positive integer"}.get(
                    low, f"an integer >= {low}")
                raise InputError(f"{name.replace('_', ' ')} must be {what}, got {value}")
            object.__setattr__(self, name, int(value))
        if self.replicates > MAX_REPLICATES:
            raise InputError(f"replicates must be at most {MAX_REPLICATES}, got {self.replicates}")
        for name in ("rays", "max_rays"):
            if getattr(self, name) > MAX_RAYS:
                raise InputError(f"{name.replace('_', ' ')} {getattr(self, name)} per point is "
                                 f"above the limit of {MAX_RAYS} (2^24: ray counts are stored "
                                 "exactly as float32 in glTF and EXR)")
        if self.tolerance is not None:
            try:
                tolerance = float(self.tolerance)
            except (TypeError, ValueError):
                raise InputError(f"tolerance must be a number in [0, 0.5), got "
                                 f"{self.tolerance!r}") from None
            # Every interval lies in [0, 1]: a half-width of 0.5 is met by knowing nothing.
            if not 0 <= tolerance < 0.5:
                raise InputError(f"tolerance must be in [0, 0.5) (a half-width of 0.5 is met "
                                 f"by the interval [0, 1] without a ray), got {self.tolerance}")
            object.__setattr__(self, "tolerance", tolerance)
        object.__setattr__(self, "max_distance", parse_distance(self.max_distance))
        object.__setattr__(self, "resolution", parse_resolution(self.resolution))
        if self.texel_density is not None:
            try:
                density = float(self.texel_density)
            except (TypeError, ValueError):
                raise InputError(f"texel density must be a positive number (texels per scene "
                                 f"unit), got {self.texel_density!r}") from None
            if isinstance(self.texel_density, bool) or not (math.isfinite(density)
                                                            and density > 0):
                raise InputError(f"texel density must be a positive number (texels per scene "
                                 f"unit), got {self.texel_density!r}")
            # the image size then follows from the density: a resolution too would be two
            # answers to one question
            if self.resolution != _DEFAULT_RESOLUTION:
                raise InputError("give a resolution or a texel density, not both")
            object.__setattr__(self, "texel_density", density)
        if self.tau is not None:
            try:
                tau = float(self.tau)
            except (TypeError, ValueError):
                raise InputError(f"tau must be a number >= 0 (or inf), got {self.tau!r}") from None
            if math.isnan(tau) or tau < 0:
                raise InputError(f"tau must be >= 0 (or inf), got {self.tau}")
            object.__setattr__(self, "tau", tau)
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) \
                or not 0 <= self.seed < 2**63:
            raise InputError(f"seed must be an integer in [0, 2^63), got {self.seed}")
        object.__setattr__(self, "seed", int(self.seed))
        for name, allowed in CHOICES.items():
            if getattr(self, name) not in allowed:
                raise InputError(f"{name} must be one of {sorted(allowed)}, got {getattr(self, name)!r}")
        try:
            offset = float(self.ray_offset)
            confidence = float(self.confidence)
        except (TypeError, ValueError):
            raise InputError(f"ray_offset and confidence must be numbers, got "
                             f"{self.ray_offset!r}, {self.confidence!r}") from None
        if not (math.isfinite(offset) and 0 < offset < 0.1):
            raise InputError(f"ray_offset must be in (0, 0.1) of the triangle size, got {self.ray_offset}")
        object.__setattr__(self, "ray_offset", offset)
        object.__setattr__(self, "ground_plane", bool(self.ground_plane))
        object.__setattr__(self, "keep_distances", bool(self.keep_distances))
        object.__setattr__(self, "denoise", bool(self.denoise))
        if self.denoise and not {"ao", "obscurance"} & set(self.quantities):
            raise InputError("denoise filters ao and obscurance; bake at least one of them "
                             f"(got {', '.join(self.quantities)})")
        if self.keep_distances and self.tolerance is not None:
            raise InputError("keep_distances needs one ray count for every point; it cannot "
                             "be combined with a tolerance")
        if not (0.5 <= confidence <= MAX_CONFIDENCE):
            raise InputError(f"confidence must be in [0.5, {MAX_CONFIDENCE}], got {self.confidence}")
        object.__setattr__(self, "confidence", confidence)

    def resolve_max_distance(self, diagonal: float) -> float:
        """Max distance in scene units."""
        if isinstance(self.max_distance, str):
            return float(self.max_distance[:-1]) / 100.0 * diagonal
        return float(self.max_distance)

    def resolve_tau(self, diagonal: float) -> float:
        """tau per scene unit."""
        return DEFAULT_TAU_DIAGONALS / diagonal if self.tau is None else self.tau

    def to_dict(self) -> dict:
        """Plain JSON types; ``from_dict(to_dict())`` gives an equal config."""
        out = asdict(self)
        out["quantities"] = list(self.quantities)
        out["resolution"] = list(self.resolution)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "BakeConfig":
        """A config from ``to_dict()`` or a report's ``config`` (non-finite floats may be
        the strings 'inf'/'nan' of strict JSON); unknown keys are an error."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise InputError(f"unknown configuration keys {unknown}")
        data = dict(data)
        if isinstance(data.get("ray_offset"), str):
            data["ray_offset"] = float(data["ray_offset"])
        if isinstance(data.get("tau"), str):
            data["tau"] = float(data["tau"])
        return cls(**data)


_DEFAULT_RESOLUTION = BakeConfig.resolution

#: field -> allowed values (the CLI's choices come from the same registries)
CHOICES = {
    "sampler": tuple(SAMPLERS), "weighting": tuple(WEIGHTINGS), "normals": NORMALS,
    "fix_normals": FIX_NORMALS,
    "up_axis": AXES, "backfaces": BACKFACES, "backend": tuple(BACKENDS), "unwrap": UNWRAP,
    "bent_space": BENT_SPACES, "seams": SEAMS,
}

#: the defaults, by field name (``BakeConfig().to_dict()``)
DEFAULTS = {f.name: f.default for f in fields(BakeConfig)}

__all__ = ["AXES", "BACKFACES", "BENT_SPACES", "BakeConfig", "CHOICES", "DEFAULTS", "FIX_NORMALS",
           "NORMALS", "QUANTITIES", "UNWRAP", "parse_distance", "parse_resolution"]
