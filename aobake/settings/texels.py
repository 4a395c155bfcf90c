"""The lightmap target's options (``--target texels``): the image, its atlas, and what is
done to the texels after tracing."""

from __future__ import annotations

from dataclasses import dataclass

from aobake.errors import InputError
from aobake.settings.spec import setting

UNWRAP = ("auto", "always", "never")
BENT_SPACES = ("object", "tangent")
SEAMS = ("erase", "off")
#: what to do when the mesh's own UVs overlap (a texel centre covered twice): make a new
#: atlas (the default, as before), refuse (an error that shows the overlap), or bake the
#: own UVs anyway with shared texels averaging the surfaces that share them
UV_OVERLAP = ("atlas", "refuse", "average")
DEFAULT_RESOLUTION = (1024, 1024)
#: how a lightmap of a set of instances sizes each instance's region
#: (``aobake.targets.texels.instanced``): density (equal texels per scene unit on every
#: instance: its world area, the scale of its transform) or mesh (one size per mesh, at the
#: density its instances have on average: the instance's own scale ignored)
INSTANCE_REGIONS = ("density", "mesh")


def parse_resolution(value) -> tuple[int, int]:
    """'N' or 'WxH' (or an int / pair) -> (width, height); InputError on nonsense."""
    import numpy as np

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


def _path(value) -> str:
    from pathlib import Path

    if not isinstance(value, (str, Path)) or not str(value):
        raise InputError(f"overlap_mask must be a file path, got {value!r}")
    if Path(value).suffix.lower() != ".png":
        raise InputError(f"overlap_mask {value}: the overlap mask is a .png")
    return str(value)


@dataclass(frozen=True)
class LightmapOptions:
    """The lightmap target's settings (ignored by the other targets)."""

    resolution: tuple = setting(
        DEFAULT_RESOLUTION, "parsed", "Lightmap size: N (square) or WxH.", section="texels",
        parse=parse_resolution, show_default="1024")
    texel_density: float | None = setting(
        None, "float", "Instead of --resolution: texels per scene unit along the surface. A "
        "new atlas puts every chart at exactly this density in the smallest square image "
        "that holds them (own UVs: the smallest square reaching it on average).",
        section="texels", optional=True, low=0.0, low_open=True,
        words="a positive number (texels per scene unit)")
    padding: int = setting(
        2, "int", "Texels of dilation into the gutters (seamless bilinear/mip lookups).",
        section="texels", low=0, high=1 << 20)
    texel_samples: int = setting(
        4, "int", "Surface positions per texel, jittered over the covered part (antialiased "
        "edges). --rays is per texel, split over these.", section="texels", low=1,
        high=1 << 20)
    unwrap: str = setting(
        "auto", "choice", "Always make a new xatlas atlas / never (fail without usable UVs). "
        "Default: the mesh's own UVs when valid for baking, else a new atlas.",
        section="texels", choices=UNWRAP, flags=("--unwrap/--no-unwrap",))
    # uv_set is a common setting (aobake.settings.CommonOptions): the lightmap is baked
    # into it, and a view looks a lightmap up through it (--ao-from LIGHTMAP)
    uv_overlap: str = setting(
        "atlas", "choice", "When the own UVs overlap (a texel covered by two faces, e.g. a "
        "mirrored half sharing an island): atlas (bake a new xatlas atlas), refuse (exit 1 "
        "naming the overlapping faces; --overlap-mask writes them as an image), or average "
        "(bake the own UVs; a shared texel is the mean of its surfaces, with a warning).",
        section="texels", choices=UV_OVERLAP)
    overlap_mask: str | None = setting(
        None, "parsed", "With --uv-overlap refuse: write a PNG of the own UVs' overlap "
        "(red: texels covered twice or more, grey: once) to this path before refusing.",
        section="texels", optional=True, parse=_path, show_default=False)
    instance_regions: str = setting(
        "density", "choice", "A lightmap of a glTF set of instances holds one region per "
        "baked instance: density (the same texels per scene unit on every instance, by its "
        "world area) or mesh (every instance of a mesh the same region, its scale ignored) "
        "(docs/scale.md).", section="texels", choices=INSTANCE_REGIONS)
    bent_space: str = setting(
        "object", "choice", "Lightmap bent normals in object space or tangent space "
        "(MikkTSpace-style frames of the atlas UVs).", section="texels", choices=BENT_SPACES)
    seams: str = setting(
        "erase", "choice", "Lightmaps: erase (make bilinear lookups agree across UV seams by "
        "a least-squares change of the texels they read) or off.", section="texels",
        choices=SEAMS)
    denoise: bool = setting(
        False, "flag", "Lightmaps (EXR): add ao_denoised / ao_denoised_stderr (and "
        "obscurance's) beside the raw channels: a surface-guided filter that keeps creases, "
        "charts and seams (docs/lightmaps.md).", section="texels")

    def check_lightmap(self) -> None:
        """The checks between this record's fields."""
        # the image size follows from a density: a resolution too would be two answers to
        # one question
        if self.texel_density is not None and self.resolution != DEFAULT_RESOLUTION:
            raise InputError("give a resolution or a texel density, not both")
        if self.overlap_mask is not None and self.uv_overlap != "refuse":
            raise InputError("overlap_mask is written when --uv-overlap refuse refuses; "
                             f"got uv_overlap={self.uv_overlap!r}")
