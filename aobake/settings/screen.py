"""The screen-space methods' settings: one record shared by the three methods (section
``ssao``) and one per method where it has its own (``crytek``, ``gtao``).

Made by ``aobake.settings.spec.setting`` like every section's record, so that composing them
into ``BakeConfig`` gives ``--ssao-radius`` and the rest with their checks, help and
report keys; until then a method reads them from a config that has them (``of``), else
its class-level defaults.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from aobake.errors import InputError
from aobake.settings.spec import check as check_settings
from aobake.settings.spec import record_of, setting
from aobake.constants import DEPTH_CONVENTIONS

# The settings' choices are stated here, where every config reads them, and imported by the
# methods (``crytek``, ``gbuffer``): reading a config never imports a method.
#: depth buffers a method may read: the linear view depth, or a hardware depth (the names of
#: ``aobake.camera.DEPTH_CONVENTIONS``) linearised with the camera's near/far
DEPTH_SOURCES = ("linear",) + DEPTH_CONVENTIONS
#: normals a method may read: the geometric normal (the one the AO's hemisphere is built on:
#: the truth's) or the interpolated shading normal, both view space, facing the eye
NORMAL_SOURCES = ("geometric", "shading")
#: Crytek's normalisations of the visible fraction A (``aobake.screen.crytek``)
NORMALISATIONS = ("double", "crytek", "none")
#: Crytek's range checks (``aobake.screen.crytek``)
RANGE_CHECKS = ("plane", "depth")

#: the most samples, slices or steps a pixel may take (each is a depth fetch per pixel)
MAX_SAMPLES = 1024
#: the largest rotation pattern (and blur window): N x N
MAX_PATTERN = 16


def parse_radius(value) -> float | str:
    """A radius: a positive finite number (scene units) or 'P%' (P > 0, percent of the
    bounding-box diagonal); InputError otherwise."""
    if isinstance(value, str) and value.strip().endswith("%"):
        try:
            percent = float(value.strip()[:-1])
        except ValueError:
            percent = math.nan
        if not (math.isfinite(percent) and percent > 0):
            raise InputError(f"ssao radius {value!r}: the percentage must be finite and > 0")
        return f"{percent:g}%"
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if isinstance(value, bool) or not (math.isfinite(number) and number > 0):
        raise InputError(f"ssao radius must be a finite number > 0 (scene units) or 'P%' of "
                         f"the bounding-box diagonal, got {value!r}")
    return number


class _Record:
    """``of``: the record's settings from a config carrying them, else a default."""

    def __post_init__(self):
        check_settings(self)

    @classmethod
    def of(cls, config, default=None):
        return record_of(cls, config, default)


@dataclass(frozen=True)
class SsaoOptions(_Record):
    """Settings of every screen-space method (``crytek``, ``shanmugam``, ``gtao``)."""

    ssao_radius: float | str = setting(
        "5%", "parsed", "Screen-space methods: the radius they look for occluders in (scene "
        "units, or 'P%' of the bounding-box diagonal). Their truth is the ray-traced AO with "
        "--max-distance at this radius.", section="ssao", parse=parse_radius)
    ssao_samples: int = setting(
        16, "int", "--method crytek: samples in the ball; shanmugam: neighbour pixels read per "
        "pixel (the course: 8-32).", section="ssao", low=1, high=MAX_SAMPLES)
    ssao_rotate: bool = setting(
        True, "flag", "Screen-space methods: turn the kernel (gtao: the slices and steps) per "
        "pixel with a pattern repeating every --ssao-pattern pixels.", section="ssao",
        flags=("--ssao-rotate/--no-ssao-rotate",))
    ssao_blur: bool = setting(
        True, "flag", "Screen-space methods: average each pixel over an N x N window "
        "(N = --ssao-pattern) that stops at depth and normal discontinuities.",
        section="ssao", flags=("--ssao-blur/--no-ssao-blur",))
    ssao_pattern: int = setting(
        4, "int", "Screen-space methods: N, the rotation pattern's period and the blur's "
        "window (pixels).", section="ssao", low=1, high=MAX_PATTERN)
    ssao_depth: str = setting(
        "linear", "choice", "Screen-space methods: the depth buffer read: linear view depth, "
        "or a hardware depth (opengl, d3d, reversed) linearised with the camera's near/far "
        "as an engine does.", section="ssao", choices=DEPTH_SOURCES)
    ssao_normals: str = setting(
        "geometric", "choice", "Screen-space methods: the view-space normals read: geometric "
        "(the truth's hemisphere) or shading (interpolated vertex normals).", section="ssao",
        choices=NORMAL_SOURCES)
    ssao_blur_depth: float = setting(
        1.0, "float", "--ssao-blur: a neighbour counts if it lies within this many pixel sizes "
        "of the pixel's tangent plane.", section="ssao", low=0.0, low_open=True, high=1e6)
    ssao_blur_normal: float = setting(
        30.0, "float", "--ssao-blur: a neighbour counts if its normal is within this many "
        "degrees of the pixel's.", section="ssao", low=0.0, low_open=True, high=180.0)

    def radius(self, diagonal: float) -> float:
        """The radius in scene units for a scene of bounding-box ``diagonal``."""
        if isinstance(self.ssao_radius, str):
            value = float(self.ssao_radius[:-1]) / 100.0 * diagonal
            if not value > 0:
                raise InputError(f"ssao radius {self.ssao_radius} of a scene of diagonal "
                                 f"{diagonal:g} is 0")
            return value
        return float(self.ssao_radius)


@dataclass(frozen=True)
class CrytekOptions(_Record):
    """Settings of ``--method crytek`` beyond the shared ones."""

    crytek_normalise: str = setting(
        "double", "choice", "--method crytek: double (AO = min(1, 2A), A the visible "
        "fraction: an open wall, half of whose ball is behind it, reads 1), crytek "
        "(min(1, A + A^2), CryEngine 2's shader: a wall reads 3/4) or none (A: 1/2).",
        section="crytek", choices=NORMALISATIONS)
    crytek_range: str = setting(
        "plane", "choice", "--method crytek: the range check: plane (a sample more than the "
        "radius below the plane of the surface it is compared with counts 1/2) or depth (a "
        "sample more than the radius behind the surface, in depth, counts as open).",
        section="crytek", choices=RANGE_CHECKS)


@dataclass(frozen=True)
class GtaoOptions(_Record):
    """Settings of ``--method gtao`` (XeGTAO's defaults)."""

    gtao_slices: int = setting(
        4, "int", "--method gtao: slices per pixel (XeGTAO: 2-9).", section="gtao", low=1,
        high=MAX_SAMPLES)
    gtao_steps: int = setting(
        4, "int", "--method gtao: horizon-search steps on each side of a slice.",
        section="gtao", low=1, high=MAX_SAMPLES)
    gtao_multiplier: float = setting(
        1.457, "float", "--method gtao: the search radius is the radius times this "
        "(XeGTAO's default 1.457: with the default falloff the weight is 1/2 at 1.009 x the "
        "radius, so the fade straddles the truth's cut).", section="gtao", low=0.0,
        low_open=True, high=100.0)
    gtao_falloff: float = setting(
        0.615, "float", "--method gtao: the fraction of the radius over which a sample's "
        "weight fades to 0 at the radius (XeGTAO: 0.615; 0 = a hard cut).", section="gtao",
        low=0.0, high=1.0)


def parse_thickness(value) -> float | str:
    """A thickness: 'inf', a positive number (scene units) or 'P%' of the diagonal."""
    if isinstance(value, str) and value.strip().lower() in ("inf", "infinity"):
        return math.inf
    if isinstance(value, (int, float)) and not isinstance(value, bool) and value == math.inf:
        return math.inf
    try:
        return parse_radius(value)
    except InputError:
        raise InputError(f"heightfield thickness must be 'inf', a number > 0 or 'P%', got "
                         f"{value!r}") from None


@dataclass(frozen=True)
class HeightfieldOptions(_Record):
    """Settings of ``--method heightfield`` (the height-field truth) beyond the ray-traced
    truth's own (--rays, --sampler, --replicates, --seed, --max-distance, --confidence)."""

    heightfield_thickness: float | str = setting(
        math.inf, "parsed", "--method heightfield: how far behind each pixel's surface the "
        "solid reaches (scene units, 'P%' of the diagonal, or inf: the height field proper; "
        "the --ssao-radius is what the screen-space methods' range checks assume).",
        section="heightfield", parse=parse_thickness)

    def thickness(self, diagonal: float) -> float:
        value = self.heightfield_thickness
        if isinstance(value, str):
            return float(value[:-1]) / 100.0 * diagonal
        return float(value)


#: every record, for whoever composes them into BakeConfig
RECORDS = (SsaoOptions, CrytekOptions, GtaoOptions, HeightfieldOptions)
