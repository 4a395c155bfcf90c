"""The ``file`` method's settings (section "file"): which bake (per vertex, or a lightmap) it
reads."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from aobake.errors import InputError
from aobake.settings.spec import setting


def _path(value):
    if not isinstance(value, (str, Path)):
        raise InputError(f"ao_from must be a file path, got {value!r}")
    return str(value)


@dataclass(frozen=True)
class FileOptions:
    """The ``file`` method's settings."""

    ao_from: str | None = setting(
        None, "parsed", "Read the values (--method file, which it implies; ao, and "
        "obscurance with -q obscurance) from this per-vertex bake of the same mesh (.npz, "
        ".ply, .glb: interpolated on the triangles) or this lightmap of it (.exr, .png, .tif: "
        "looked up at the mesh's UVs, --uv-set, --lightmap-filter), at every pixel or texel, "
        "e.g. to look at a bake with 'aobake view MESH --ao-from ao.ply --out look.png'.",
        section="file",
        optional=True, parse=_path, show_default=False)
