"""The settings of a bake, in one package: one module per section, composed here into one
frozen, validated, serialisable ``BakeConfig``.

``CommonOptions`` here (what every method and target reads: the quantities, the scene, the
AO's definition); ``rays`` (the ray-traced method), ``file``, ``discs``, ``hemicube``,
``screen`` (the screen-space methods and the height field), ``view`` (the camera
target), ``texels`` (the lightmap target) and ``studio`` (high-to-low and occluder groups)
each hold one section's record.
Every field is made by ``aobake.settings.spec.setting``: its default, check, CLI flag,
choices and help in one place (the CLI generates its options from them).  Settings are
values only: this package imports no method, target or command (the plugins import their
record from here; ``aobake.api`` turns the studio settings into a target and a selection).
One name per concept: the CLI flag ``--max-distance`` is the field ``max_distance`` and the
report key ``max_distance``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from aobake.backends import BACKENDS
from aobake.constants import AXES, OFFSET_ULPS  # noqa: F401  (re-exported)
from aobake.errors import InputError
from aobake.settings.depthmaps import DepthmapsOptions
from aobake.settings.discs import DiscsOptions
from aobake.settings.file import FileOptions
from aobake.settings.hemicube import HemicubeOptions
from aobake.settings.rays import (BACKFACES, DEFAULT_RAY_OFFSET, MAX_CONFIDENCE,  # noqa: F401
                                         MAX_RAYS, RaysOptions)
from aobake.settings.spec import check as check_settings
from aobake.settings.spec import setting, specs
from aobake.quantities import QUANTITIES, canonical
from aobake.settings.screen import CrytekOptions, GtaoOptions, HeightfieldOptions, SsaoOptions
from aobake.repair import MODES as FIX_NORMALS
from aobake.settings.studio import StudioOptions
from aobake.settings.texels import (BENT_SPACES, DEFAULT_RESOLUTION,  # noqa: F401
                                           SEAMS, UNWRAP, LightmapOptions, parse_resolution)
from aobake.settings.view import PIXEL_FILTERS, ViewOptions  # noqa: F401
from aobake.warp import WEIGHTINGS

NORMALS = ("file", "angle", "area")
#: the settings that name files a bake reads, with their flags (no output may overwrite one)
INPUT_FILES = {"source": "--from", "cage": "--cage", "ao_from": "--ao-from"}
#: default tau for obscurance, in units of 1 / diagonal: rho reaches 1 - 1/e at a tenth of the scene size.
DEFAULT_TAU_DIAGONALS = 10.0


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


def _quantities(value) -> tuple:
    return canonical(value)


def _tau(value) -> float:
    try:
        tau = float(value)
    except (TypeError, ValueError):
        raise InputError(f"tau must be a number >= 0 (or inf), got {value!r}") from None
    if isinstance(value, bool) or math.isnan(tau) or tau < 0:
        raise InputError(f"tau must be >= 0 (or inf), got {value}")
    return tau


@dataclass(frozen=True)
class CommonOptions:
    """What every method and target reads: what to compute, on which scene, by which
    definition (each field's help is its documentation)."""

    quantities: tuple = setting(
        ("ao",), "parsed", "What to bake (repeatable). Default: ao.", parse=_quantities,
        flags=("--quantity", "-q"), multiple=True, show_default=False)
    max_distance: float | str = setting(
        math.inf, "parsed", "Occluder search distance: scene units, 'inf', or 'P%' of the "
        "bounding-box diagonal. Default inf: AO as defined, with no cut-off.",
        parse=lambda v: parse_distance(v))
    tau: float | None = setting(
        None, "parsed", "Obscurance decay per scene unit in rho(L) = 1 - exp(-tau L). "
        "Default: 10 / bounding-box diagonal.", optional=True, parse=_tau,
        show_default=False)
    seed: int = setting(
        0, "int", "Same inputs + seed = bit-identical outputs, for any --threads.", low=0,
        high=2**63 - 1, words="an integer in [0, 2^63)")
    weighting: str = setting(
        "cosine", "choice", "What AO averages over: cosine ((1/pi) int V cos, the default) or "
        "uniform ((1/2pi) int V: libigl's and xNormal's convention, a different number).",
        choices=tuple(WEIGHTINGS))
    normals: str = setting(
        "file", "choice", "Vertex normals: the file's (angle-weighted where it has none), or "
        "computed.", choices=NORMALS)
    fix_normals: str = setting(
        "warn", "choice", "Faces wound against their neighbours and components pointing "
        "inward: warn with counts, fix (flip them; computed normals follow), or off.",
        choices=FIX_NORMALS)
    ground_plane: bool = setting(
        False, "flag", "Add an infinite solid ground plane at the scene's lowest point along "
        "--up-axis.")
    up_axis: str = setting("y", "choice", "Up axis for --ground-plane (and a view's default "
                           "camera).", choices=AXES)
    albedo: float = setting(
        0.5, "float", "-q indirect: the albedo rho of every surface (two-sided Lambertian) "
        "under a uniform white sky.", low=0.0, high=1.0, panel="indirect")
    backend: str = setting(
        "embree", "choice", "Tracing backend: embree; warp (NVIDIA Warp: a CUDA GPU where "
        "there is one, else the CPU; the warp extra, docs/gpu.md); or reference (float64 "
        "numpy, every ray against every triangle: slow, for validating on small scenes).",
        choices=tuple(BACKENDS), panel="run")
    embree_mode: str = setting(
        "robust", "choice", "Embree's traversal: robust (watertight: no ray slips between two "
        "triangles sharing an edge) or fast (Embree's default flags). The report says which "
        "ran (docs/performance.md).", choices=("robust", "fast"), panel="run")
    uv_set: int = setting(
        0, "int", "Which UV set of the input a lightmap belongs to: glTF TEXCOORD_N (1 is the "
        "lightmap set engines use). A lightmap bake bakes into it (a .glb output puts the map "
        "on that set, occlusionTexture.texCoord = N, and keeps the others); --ao-from "
        "LIGHTMAP looks the lightmap up at it. OBJ and the other formats have set 0 only.",
        low=0, high=255, panel="texels")


@dataclass(frozen=True)
class BakeConfig(StudioOptions, LightmapOptions, ViewOptions, HeightfieldOptions,
                 GtaoOptions, CrytekOptions, SsaoOptions, DepthmapsOptions,
                 HemicubeOptions, DiscsOptions, FileOptions, RaysOptions, CommonOptions):
    """Everything that decides a bake's numbers (threads, executors and chunking do not): the
    common settings, the ray-traced method's, the file method's, the disc method's, the
    hemicube method's, the screen-space methods' (aobake.settings.screen), the view
    target's (aobake.settings.view), the lightmap target's and the studio's (high-to-low,
    groups), in that order (each section's record documents its fields; ``python -c "from
    aobake.settings import BakeConfig; help(BakeConfig)"`` or ``aobake --help`` shows them).
    The one source of every default: the CLI reads them from here.
    """

    def __post_init__(self):
        check_settings(self)
        self.check_rays()
        self.check_hemicube()
        self.check_lightmap()
        self.check_studio()
        if self.tolerance is not None and not {"ao", "obscurance"} & set(self.quantities):
            # bent normals have no interval: a tolerance would be "met" by nothing baked
            raise InputError("tolerance bounds the intervals of ao and obscurance; bake at "
                             f"least one of them (got {', '.join(self.quantities)})")
        if "indirect" in self.quantities and self.backfaces == "ignore":
            raise InputError("indirect light reflects off every face it hits; it cannot be "
                             "combined with backfaces='ignore'")
        if self.denoise and not {"ao", "obscurance"} & set(self.quantities):
            raise InputError("denoise filters ao and obscurance; bake at least one of them "
                             f"(got {', '.join(self.quantities)})")

    def resolve_max_distance(self, diagonal: float) -> float:
        """Max distance in scene units."""
        if isinstance(self.max_distance, str):
            return float(self.max_distance[:-1]) / 100.0 * diagonal
        return float(self.max_distance)

    def resolve_tau(self, diagonal: float) -> float:
        """tau per scene unit."""
        return DEFAULT_TAU_DIAGONALS / diagonal if self.tau is None else self.tau

    def to_dict(self, sections=None) -> dict:
        """Plain JSON types; ``from_dict(to_dict())`` gives an equal config.  sections : the
        settings sections to keep (None: all of them)."""
        out = asdict(self)
        out["quantities"] = list(self.quantities)
        out["resolution"] = list(self.resolution)
        if sections is not None:
            out = {name: value for name, value in out.items() if SECTIONS[name] in sections}
        return out

    def record(self, method: str, target: str) -> dict:
        """The config a report of a bake by ``method`` at ``target`` records: the common
        settings and the sections of the method and the target that ran
        (``capabilities.sections_used``), and the studio's when any of them is set (groups
        and cut-outs apply to every target).  ``from_dict`` of it re-bakes the bake bit for
        bit: what is left out is what the bake did not read."""
        from aobake.capabilities import sections_used

        sections = sections_used(method, target)
        studio = [name for name, section in SECTIONS.items() if section == "studio"]
        if any(getattr(self, name) != DEFAULTS[name] for name in studio):
            sections += ("studio",)
        return self.to_dict(sections)

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


#: the settings of every section, by field name (``aobake.settings.spec.Spec``)
SPECS = specs(BakeConfig)

#: field -> allowed values (the CLI's choices come from the same registries)
CHOICES = {name: spec.choices for name, spec in SPECS.items() if spec.kind == "choice"}

#: the defaults, by field name (``BakeConfig().to_dict()``)
DEFAULTS = {f.name: f.default for f in fields(BakeConfig)}

#: which section each field belongs to ('common', 'rays', 'texels')
SECTIONS = {name: spec.section for name, spec in SPECS.items()}

__all__ = ["AXES", "BACKFACES", "BENT_SPACES", "BakeConfig", "CHOICES", "DEFAULTS", "FIX_NORMALS",
           "NORMALS", "QUANTITIES", "UNWRAP", "parse_distance", "parse_resolution"]
