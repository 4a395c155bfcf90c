"""Whether two aobake files hold the same quantity: different weightings are refused,
other settings that change the number (max distance, ground plane, ...) are warned about."""

from __future__ import annotations

import logging
import math

from aobake.errors import InputError
from aobake.outputs.values import Values

log = logging.getLogger(__name__)

#: config keys that change what a quantity means (besides the weighting, which is refused)
_SAME_QUANTITY = ("max_distance", "ground_plane", "backfaces", "normals")


def check_same_quantity(reference: Values, candidate: Values, quantity: str) -> list:
    """Refuse different weightings (different quantities); warn about other settings that
    change the number.  Only when both files carry aobake metadata."""
    ref, cand = (v.metadata.get("config") or {} for v in (reference, candidate))
    if not isinstance(ref, dict) or not isinstance(cand, dict) or not ref or not cand:
        return []
    rw, cw = ref.get("weighting"), cand.get("weighting")
    if rw is not None and cw is not None and rw != cw:
        raise InputError(f"{candidate.path}: holds {cw}-weighted {quantity}, the reference "
                         f"{reference.path} {rw}-weighted {quantity}: different quantities, which "
                         "no conversion relates (bake both with the same --weighting)")
    keys = _SAME_QUANTITY + (("tau",) if quantity == "obscurance" else ())
    views = all(isinstance(v.metadata.get("camera"), dict) for v in (reference, candidate))
    if views:  # a view's AO is about the geometric normal facing the eye, whatever --normals
        keys = tuple(k for k in keys if k not in ("max_distance", "normals")) + ("reach",)
    warnings = []
    for key in keys:
        # resolved values (scene units) where the report has them: '10%' of the same mesh agrees
        a = _setting(reference.metadata, key)
        b = _setting(candidate.metadata, key)
        if a is not None and b is not None and not _same(a, b):
            text = (f"{key} differs ({reference.path}: {a}, {candidate.path}: {b}): the files "
                    f"may hold different {quantity}; compared anyway")
            log.warning("%s", text)
            warnings.append(text)
    return warnings


#: a lightmap's texture record entries that fix which surface point each texel is
_LAYOUT = ("width", "height", "atlas", "uv_set", "charts", "instances")


def check_same_layout(reference: Values, candidate: Values) -> None:
    """Refuse two aobake lightmaps whose texels are not the same surface points: another
    atlas (a new one against own UVs, another UV set, other charts) or a set's regions
    placed otherwise (a ``--bake`` subset's atlas holds only its instances).  Only when both
    files carry aobake's texture record."""
    ref, cand = (v.metadata.get("texture") for v in (reference, candidate))
    if not isinstance(ref, dict) or not isinstance(cand, dict):
        return
    for key in _LAYOUT:
        a, b = ref.get(key), cand.get(key)
        if a is not None and b is not None and a != b:
            what = "its instances' regions differ" if key == "instances" else \
                f"{key} {b!r} against {a!r}"
            raise InputError(f"{candidate.path}: is a lightmap of another layout than the "
                             f"reference {reference.path} ({what}): texel by texel they are "
                             "not the same surface points; bake both with the same atlas (a "
                             "set: the same --bake)")


def _setting(metadata: dict, key: str):
    if key == "reach":  # how far a view's method sees: a screen method's radius, else the rays'
        parameters = metadata.get("parameters")
        if isinstance(parameters, dict) and str(parameters.get("reads", "")).startswith("G-buffer"):
            return parameters.get("radius")
        return _setting(metadata, "max_distance")
    for part in ("parameters", "config"):
        section = metadata.get(part)
        if isinstance(section, dict) and key in section:
            return section[key]
    return None


def _same(a, b) -> bool:
    try:
        fa, fb = float(a), float(b)  # "inf" strings of the strict JSON metadata included
    except (TypeError, ValueError):
        return a == b
    return fa == fb or math.isclose(fa, fb, rel_tol=1e-9)

