"""The quantities a bake can estimate, and every per-point field a result holds.

``QUANTITIES`` is the registry (canonical order = output order); ``FIELDS`` adds
the two fields every bake has (``normals``, ``rays``).  Writers, the CLI and the
docs read names from here, so no name is typed twice.
"""

from __future__ import annotations

import numpy as np

from aobake.quantities import ao, bent_normal, indirect, obscurance, thickness
from aobake.quantities.base import Field, Quantity, Traced

#: name -> Quantity, in canonical (output) order
QUANTITIES: dict[str, Quantity] = {
    q.name: q for q in (ao.QUANTITY, obscurance.QUANTITY, bent_normal.QUANTITY,
                        indirect.QUANTITY, thickness.QUANTITY)
}

NORMALS = Field("normals", 3, np.float64, ("nx", "ny", "nz"), None, (),
                "normals the hemispheres were built on")
RAYS = Field("rays", 1, np.int32, ("rays",), "_RAYS", ("rays",), "rays cast for each point")

#: a high-to-low per-vertex bake's projection (``aobake.targets.projected``), per low vertex;
#: finite everywhere: a vertex with no hit has distance 0 (its ``missed`` says why)
MISSED = Field("missed", 1, np.uint8, ("missed",), None, (),
               "high-to-low: 1 where nothing was projected (the cage ray missed the source, or "
               "the vertex has no ray), else 0")
BACK_HIT = Field("back_hit", 1, np.uint8, ("back_hit",), None, (),
                 "high-to-low: 1 where the cage ray hit the back of a source face, else 0")
PROJECTION_DISTANCE = Field(
    "projection_distance", 1, np.float32, ("projection_distance",), None, (),
    "high-to-low: height of the projected point above the low surface along the cage ray, "
    "L - t (scene units; > 0: the source lies outside the low mesh); 0 where missed")
PROJECTION_FIELDS = (MISSED, BACK_HIT, PROJECTION_DISTANCE)

#: every per-point field, in output order: name -> Field
FIELDS: dict[str, Field] = {
    f.name: f for f in (NORMALS, *(f for q in QUANTITIES.values() for f in q.fields), RAYS,
                        *PROJECTION_FIELDS)
}

#: conventions every bake shares, whatever it computes
COMMON_CONVENTIONS = {
    "max_distance": "a hit beyond the max distance is a miss",
    "stderr": "one standard error of the Monte-Carlo estimate",
}


def canonical(names) -> tuple:
    """Quantity names (str or iterable; '-' accepted for '_') -> tuple in canonical order.

    Raises ValueError naming the unknown ones.
    """
    names = (names,) if isinstance(names, str) else tuple(names)
    names = tuple(str(n).replace("-", "_") for n in names)
    unknown = [n for n in names if n not in QUANTITIES]
    if unknown or not names:
        from aobake.errors import InputError

        raise InputError(f"quantities must be some of {tuple(QUANTITIES)}, got {names}")
    return tuple(n for n in QUANTITIES if n in names)


def conventions(weighting: str = "cosine", names=tuple(QUANTITIES)) -> dict:
    """What the numbers of a bake with this weighting mean (written into every output)."""
    out = {}
    for name in names:
        out.update(QUANTITIES[name].conventions[weighting])
    out.update(COMMON_CONVENTIONS)
    return out


__all__ = ["COMMON_CONVENTIONS", "FIELDS", "Field", "PROJECTION_FIELDS", "QUANTITIES", "Quantity", "Traced",
           "canonical", "conventions"]
