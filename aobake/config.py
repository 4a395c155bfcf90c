"""Bake configuration: one frozen dataclass, validated once, serialisable for the report.

One name per concept: the CLI flag ``--max-distance`` is the field
``max_distance`` and the report key ``max_distance``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from aobake.samplers import SAMPLERS
from aobake.warp import WEIGHTINGS

#: quantities a bake can compute; CLI choices come from here.
QUANTITIES = ("ao", "obscurance", "bent-normal")
NORMALS = ("file", "angle", "area")
BACKFACES = ("occlude", "ignore")
AXES = ("x", "y", "z")

#: default ray offset, as a fraction of the bounding-box diagonal: ~300 float32
#: ulps of the rebased coordinates (no self-hits) yet 1% of a 1e-3 gap (no leaks).
DEFAULT_RAY_OFFSET = 1e-5
#: default tau for obscurance, in units of 1 / diagonal: rho reaches 1 - 1/e at a tenth of the scene size.
DEFAULT_TAU_DIAGONALS = 10.0


def parse_distance(value) -> float | str:
    """Accept a number (scene units), 'inf', or 'P%' (percent of the bounding-box diagonal).

    Returns a float or the string 'P%' unchanged; raises ValueError otherwise.
    """
    if isinstance(value, str):
        text = value.strip().lower()
        if text.endswith("%"):
            percent = float(text[:-1])
            if not math.isfinite(percent) or percent < 0:
                raise ValueError(f"max distance {value!r}: percentage must be finite and >= 0")
            return f"{percent:g}%"
        value = float(text)  # accepts 'inf'
    value = float(value)
    if math.isnan(value) or value < 0:
        raise ValueError(f"max distance must be >= 0 (or inf), got {value}")
    return value


@dataclass(frozen=True)
class BakeConfig:
    """Everything that decides a bake's numbers (threads and chunking do not).

    quantities   subset of QUANTITIES, in canonical order
    rays         rays per point requested (the report also gives rays actually cast)
    max_distance float in scene units (inf = unlimited) or 'P%' of the diagonal
    tau          obscurance decay per scene unit; None = DEFAULT_TAU_DIAGONALS / diagonal
    seed, sampler, weighting, normals, ground_plane, up_axis, backfaces: see the CLI help
    ray_offset   origin offset along the normal, as a fraction of the diagonal
    """

    quantities: tuple = ("ao",)
    rays: int = 256
    max_distance: float | str = math.inf
    tau: float | None = None
    seed: int = 0
    sampler: str = "sobol"
    weighting: str = "cosine"
    normals: str = "file"
    ground_plane: bool = False
    up_axis: str = "y"
    backfaces: str = "occlude"
    ray_offset: float = DEFAULT_RAY_OFFSET

    def __post_init__(self):
        quantities = (self.quantities,) if isinstance(self.quantities, str) else tuple(self.quantities)
        unknown = [q for q in quantities if q not in QUANTITIES]
        if unknown or not quantities:
            raise ValueError(f"quantities must be some of {QUANTITIES}, got {quantities}")
        object.__setattr__(self, "quantities", tuple(q for q in QUANTITIES if q in quantities))
        if isinstance(self.rays, bool) or int(self.rays) != self.rays or self.rays < 1:
            raise ValueError(f"rays must be a positive integer, got {self.rays}")
        object.__setattr__(self, "rays", int(self.rays))
        object.__setattr__(self, "max_distance", parse_distance(self.max_distance))
        if self.tau is not None:
            tau = float(self.tau)
            if math.isnan(tau) or tau < 0:
                raise ValueError(f"tau must be >= 0 (or inf), got {self.tau}")
            object.__setattr__(self, "tau", tau)
        if int(self.seed) != self.seed or not 0 <= self.seed < 2**63:
            raise ValueError(f"seed must be an integer in [0, 2^63), got {self.seed}")
        for name, allowed in (("sampler", tuple(SAMPLERS)), ("weighting", tuple(WEIGHTINGS)),
                              ("normals", NORMALS), ("up_axis", AXES), ("backfaces", BACKFACES)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {sorted(allowed)}, got {getattr(self, name)!r}")
        offset = float(self.ray_offset)
        if not (math.isfinite(offset) and 0 < offset < 0.1):
            raise ValueError(f"ray_offset must be in (0, 0.1) of the diagonal, got {self.ray_offset}")

    def resolve_max_distance(self, diagonal: float) -> float:
        """Max distance in scene units."""
        if isinstance(self.max_distance, str):
            return float(self.max_distance[:-1]) / 100.0 * diagonal
        return float(self.max_distance)

    def resolve_tau(self, diagonal: float) -> float:
        """tau per scene unit."""
        return DEFAULT_TAU_DIAGONALS / diagonal if self.tau is None else self.tau

    def to_dict(self) -> dict:
        out = asdict(self)
        out["quantities"] = list(self.quantities)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "BakeConfig":
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in names})
