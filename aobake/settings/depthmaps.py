"""The ``depthmaps`` method's settings record (``DepthmapsOptions``) and the limits it states,
apart from the method (``aobake.methods.depthmaps``: the GL child, moderngl) so that every
bake's config can read them without importing the method."""

from __future__ import annotations

from dataclasses import dataclass

from aobake.settings.spec import check as check_settings
from aobake.settings.spec import record_of, setting

#: the most directions: each is one draw of the whole mesh (llvmpipe: ~40 ms for the
#: bunny's 69k triangles on a loaded core), so 65536 is already ~45 minutes there
MAX_DIRECTIONS = 65536
#: the largest map: N^2 float32 heights plus a 24-bit depth buffer, 128 MiB at 4096
MAX_RESOLUTION = 4096
#: the defaults: docs/depthmaps.md measures the error of each against K, N and b
DEFAULT_DIRECTIONS = 256
DEFAULT_RESOLUTION = 1024
DEFAULT_BIAS = 1.0


@dataclass(frozen=True)
class DepthmapsOptions:
    """The ``depthmaps`` method's settings (each field's help is its documentation)."""

    depthmaps_directions: int = setting(
        DEFAULT_DIRECTIONS, "int", "--method depthmaps: K, the directions over the sphere, "
        "one orthographic depth map each (a spherical Fibonacci lattice rotated by --seed; "
        "every point shares them). About half are above a point's horizon. The cost grows "
        "as K x (triangles + points); the error falls with K (docs/depthmaps.md).",
        section="depthmaps", low=1, high=MAX_DIRECTIONS,
        words=f"an integer in [1, {MAX_DIRECTIONS}]")
    depthmaps_resolution: int = setting(
        DEFAULT_RESOLUTION, "int", "--method depthmaps: N, each map's texels across (N x N "
        "over the scene's bounding sphere; a texel is 2 x radius / N wide). Occluders are "
        "located to a texel, and the bias grows with it.", section="depthmaps", low=16,
        high=MAX_RESOLUTION, words=f"an integer in [16, {MAX_RESOLUTION}]")
    depthmaps_bias: float = setting(
        DEFAULT_BIAS, "float", "--method depthmaps: b, the slope-scaled depth bias in texels: "
        "a point is open along w when no map height exceeds its own by more than b x texel / "
        "(n . w). b >= 0.71 keeps a flat surface from shadowing itself; the bias misses "
        "occluders within b texels above the point's tangent plane.", section="depthmaps",
        low=0.0, high=64.0)

    def __post_init__(self):
        check_settings(self)

    @classmethod
    def of(cls, config, default: "DepthmapsOptions | None" = None) -> "DepthmapsOptions":
        """The settings a config carries, else ``default`` (else the defaults)."""
        return record_of(cls, config, default)
