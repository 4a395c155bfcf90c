"""The studio settings (section "studio"): high-to-low baking through a cage
(``aobake.targets.projected``) and what occludes what (``aobake.groups``).

A record like the others (``aobake.settings.spec``), composed into ``BakeConfig``;
``aobake.api`` turns it into a target (``projected_target``) and a selection
(``aobake.groups.Selection``):

    aobake LOW.obj --from HIGH.obj --out ao.exr [--cage-offset D | --cage CAGE.obj]
           [--low-occludes] [--alpha-cutout] [--exclude NAME ...] [--receive-only NAME ...] [--occluder-only NAME ...]
    aobake SET.glb --bake NODE_GLOB --out ao.npz [--instances trace|flatten]
    aobake LEVEL.obj --bake 'object:crate*' --out crates.npz

``--bake`` and ``--instances`` shape a scene of instances (``aobake.instances``): which
glTF nodes (or OBJ objects and groups) are baked while everything occludes, and how the
placements are traced.

With ``--from`` the positional mesh is the low mesh (where the values are stored: its UVs
for an image, its vertices for .ply/.npz/.glb) and ``--from`` the source, the pipeline's
scene (``run(config, config.source, api.projected_target(config, per, low))``); the
groups select faces of
the pipeline's scene (the source with ``--from``).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

from aobake.errors import InputError
from aobake.settings.spec import check, setting


def parse_offset(value) -> float | str:
    """A cage offset: a number > 0 (scene units) or 'P%' (P > 0, percent of the low mesh's
    bounding-box diagonal).  Returns a float or the normalised 'P%' string; InputError on
    anything else."""
    text = value.strip().lower() if isinstance(value, str) else value
    try:
        if isinstance(text, str) and text.endswith("%"):
            percent = float(text[:-1])
            if math.isfinite(percent) and percent > 0:
                return f"{percent:g}%"
        elif not isinstance(text, bool):
            number = float(text)
            if math.isfinite(number) and number > 0:
                return number
    except (TypeError, ValueError):
        pass
    raise InputError(f"cage offset must be a number > 0 (scene units) or 'P%' (percent of "
                     f"the low mesh's diagonal), got {value!r}")


def _path(value) -> str:
    if not isinstance(value, (str, os.PathLike)) or not str(value):
        raise InputError(f"expected a mesh file, got {value!r}")
    return str(value)


def _patterns(role: str):
    """The parser of one role's name patterns (``aobake.groups``): one glob (str) or a list
    or tuple of them, None for none; InputError naming the role for anything else (an int
    is not iterable, bytes would iterate as numbers, a dict as its keys)."""
    def parse(value) -> tuple:
        if value is None:
            return ()
        if isinstance(value, str):
            values = (value,)
        elif isinstance(value, (list, tuple)):
            values = tuple(value)
        else:
            raise InputError(f"{role} takes a name pattern (str) or a list of them, got "
                             f"{type(value).__name__} {value!r}")
        for pattern in values:
            if not isinstance(pattern, str) or not pattern:
                raise InputError(f"{role}: a name pattern must be a non-empty string, got "
                                 f"{pattern!r}")
        return values
    parse.__name__ = f"parse_{role}"
    return parse


@dataclass(frozen=True)
class StudioOptions:
    """High-to-low baking and occluder groups (each field's help is its documentation)."""

    source: str | None = setting(
        None, "parsed", "Bake the AO of this high-poly mesh onto MESH (the low-poly mesh: its "
        "UVs for an image --out, its vertices for .ply/.npz/.glb), each point projected "
        "onto the source along a cage (docs/studio.md).", section="studio", optional=True,
        parse=_path, flags=("--from",), show_default=False)
    cage_offset: float | str | None = setting(
        None, "parsed", "With --from: the cage is MESH pushed out along its vertex normals by "
        "D (scene units, or 'P%' of MESH's diagonal); rays run from the cage through MESH "
        "for twice that. Default 1%.", section="studio", optional=True, parse=parse_offset,
        show_default=False)
    cage: str | None = setting(
        None, "parsed", "With --from: a cage mesh with MESH's topology (same vertices and "
        "triangles) instead of --cage-offset.", section="studio", optional=True, parse=_path,
        show_default=False)
    low_occludes: bool = setting(
        False, "flag", "With --from: MESH (the low mesh) occludes too, beside the source: its "
        "front faces beyond twice the cage's reach from each point (docs/studio.md).",
        section="studio")
    alpha_cutout: bool = setting(
        False, "flag", "Alpha-tested occluders: faces whose glTF material has alphaMode MASK "
        "let rays through where their base colour's alpha (texture x factor) is below "
        "alphaCutoff (docs/studio.md).", section="studio")
    exclude: tuple = setting(
        (), "parsed", "Faces whose object/group/node/mesh/material name matches this glob "
        "('material:glass*' for one kind) neither occlude nor are baked (repeatable).",
        section="studio", parse=_patterns("exclude"), multiple=True, show_default=False)
    receive_only: tuple = setting(
        (), "parsed", "Faces matching this glob are baked but cast nothing (repeatable).",
        section="studio", parse=_patterns("receive_only"), multiple=True,
        show_default=False)
    occluder_only: tuple = setting(
        (), "parsed", "Faces matching this glob cast but are not baked (with --from: cage "
        "rays pass through them) (repeatable).", section="studio",
        parse=_patterns("occluder_only"),
        multiple=True, show_default=False)
    bake: tuple = setting(
        (), "parsed", "What to bake, by name (a glob; repeatable): glTF nodes ('mesh:NAME' "
        "for every node of a mesh) or OBJ objects and groups ('object:NAME', 'group:NAME'). "
        "Only they are sampled (per vertex, or one lightmap region per glTF instance); "
        "everything else still occludes. Nodes that share a mesh stay instances "
        "(docs/scale.md).",
        # its own section: the targets whose points are the scene's vertices read it
        # (capabilities.TARGETS), so a view does not offer it
        section="instances", panel="studio", parse=_patterns("bake"), multiple=True,
        show_default=False)
    instances: str = setting(
        "trace", "choice", "glTF meshes placed more than once: traced as Embree instances "
        "(trace: one copy of each mesh) or flattened (one copy per placement: the flattened "
        "scene's bake, memory growing with the placements).", section="studio",
        choices=("trace", "flatten"))

    def __post_init__(self):
        check(self)
        self.check_studio()

    def check_studio(self) -> None:
        """The checks between this record's fields."""
        if self.cage is not None and self.cage_offset is not None:
            raise InputError("give --cage-offset or --cage, not both")
        if self.source is None and (self.cage is not None or self.cage_offset is not None):
            raise InputError("--cage-offset and --cage shape the projection of --from: give "
                             "--from HIGH")
        if self.source is None and self.low_occludes:
            raise InputError("--low-occludes adds the low mesh of --from to the occluders: "
                             "give --from HIGH")
        if self.bake:
            # the baked instances are the scene's faces; these act on those faces alone
            for given, flag in ((self.source, "--from"), (self.alpha_cutout, "--alpha-cutout"),
                                (self.exclude, "--exclude"), (self.receive_only, "--receive-only"),
                                (self.occluder_only, "--occluder-only")):
                if given:
                    raise InputError(f"--bake chooses what is baked and lets everything else "
                                     f"occlude: not with {flag}")
            if "indirect" in getattr(self, "quantities", ()):
                raise InputError("--bake: -q indirect follows paths across every instance's "
                                 "faces, which a selection does not hold: bake without --bake")
