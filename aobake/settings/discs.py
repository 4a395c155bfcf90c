"""The ``discs`` method's settings record (``DiscsOptions``) and the constants it states, apart
from the method (``aobake.methods.discs``) so that every bake's config can read them without
importing the method."""

from __future__ import annotations

from dataclasses import dataclass

from aobake.settings.spec import check as check_settings
from aobake.settings.spec import record_of, setting

#: how a receiver reaches the elements: through the hierarchy, or every element
TRAVERSALS = ("hierarchy", "brute")

#: the shadow models: the chapter's (GPU Gems 2 ch. 14, as its CD does it), or Hoberock and
#: Jia's robust one (GPU Gems 3 ch. 12: exact near field, smooth levels, two-sided open sheets)
MODELS = ("chapter", "robust")

#: the default model: robust.  Its per-vertex RMSE against the ray-traced truth (1024 rays)
#: is a third of the chapter's on the Stanford bunny (0.014 against 0.038) and a ninth on
#: the bundled still life, whose floor is an open sheet (0.047 against 0.42), for about
#: twice to three times the time (docs/discs.md)
DEFAULT_MODEL = "robust"

#: the default kappa: the smallest of 1, 2, 4, 8 whose AO on the Stanford bunny is as far
#: from the ray-traced truth as brute force's (RMSE 0.0376 against brute force's 0.0372;
#: 0.0458 at kappa = 2; 0.0373 at 8 for 3.6 times the time; docs/discs.md)
DEFAULT_KAPPA = 4.0

#: the most passes: each costs one gather per element at prepare time, and the iteration
#: settles fast (on the bunny passes 3 to 8 have the same mean, 0.8903 to 0.8905)
MAX_PASSES = 16

#: the defaults of the indirect light's passes, chosen from the error against the
#: ray-traced ``indirect`` (docs/approximations.md): two passes (one shadow pass), the result
#: the second pass alone.  RMSE of passes 1, 2, 3 at kappa 4: still life 0.097, 0.051,
#: 0.058; ogre 0.034, 0.022, 0.025; bunny 0.011, 0.015, 0.014 (pass 2 the best or within
#: 0.004 of it; weighting passes 2 and 3 never did better than pass 2 alone by more)
DEFAULT_INDIRECT_PASSES = 2
DEFAULT_INDIRECT_WEIGHT = 1.0


@dataclass(frozen=True)
class DiscsOptions:
    """The ``discs`` method's settings (each field's help is its documentation).

    Made by ``aobake.settings.spec.setting`` like every section's record, so that adding this
    record to ``BakeConfig``'s bases gives ``--discs-kappa`` and the rest, their checks and
    their report keys; until then ``DiscsMethod.options`` (a class-level default) or
    ``prepare(..., options=)`` sets them, and :meth:`of` reads them from a config that has
    them.
    """

    discs_model: str = setting(
        DEFAULT_MODEL, "choice", "--method discs: chapter (Bunnell, GPU Gems 2 ch. 14: the "
        "chapter's shadow, cast from an element's back only) or robust (Hoberock and Jia, GPU "
        "Gems 3 ch. 12: cosine-weighted form factors, exact for the nearby triangles, smooth "
        "between hierarchy levels, open sheets casting from both sides).", section="discs",
        choices=MODELS)
    discs_k: float = setting(
        4.0, "float", "--method discs: the receiver term's gain in sat(k n_R . v): 4 in the "
        "book's printed listing, 3 in the CD's shader (the chapter's model only).",
        section="discs", low=0.0, low_open=True, high=1e6, label="discs_k")
    discs_passes: int = setting(
        2, "int", "--method discs: shadow passes; pass j weights each element's shadow by its "
        "own pass j-1 accessibility (1: the over-dark first pass alone).", section="discs",
        low=1, high=MAX_PASSES)
    discs_weight: float = setting(
        0.6, "float", "--method discs: the result is weight x the last pass + (1 - weight) x "
        "the one before (the CD: 0.6).", section="discs", low=0.0, high=1.0)
    discs_kappa: float = setting(
        DEFAULT_KAPPA, "float", "--method discs: open a hierarchy node where the point is "
        "closer than kappa x the node's equivalent-disc radius sqrt(A/pi) (the CD: 2, the "
        "lecture: about 4). Larger: nearer brute force, slower.", section="discs", low=0.0,
        low_open=True, high=1e6)
    discs_traversal: str = setting(
        "hierarchy", "choice", "--method discs: hierarchy (O(log n) per point) or brute (every "
        "element: O(n) per point).", section="discs", choices=TRAVERSALS)
    discs_indirect_passes: int = setting(
        DEFAULT_INDIRECT_PASSES, "int", "--method discs -q indirect: passes of indirect light; "
        "pass 1 gathers every element's reflected light (albedo x its AO) unshadowed, pass j "
        "subtracts the light each element blocks (its own pass j-1 light).", section="discs",
        low=1, high=MAX_PASSES)
    discs_indirect_weight: float = setting(
        DEFAULT_INDIRECT_WEIGHT, "float", "--method discs -q indirect: the result is weight x "
        "the last indirect pass + (1 - weight) x the one before.", section="discs", low=0.0,
        high=1.0)

    def __post_init__(self):
        check_settings(self)

    @classmethod
    def of(cls, config, default: "DiscsOptions | None" = None) -> "DiscsOptions":
        """The settings a config carries (once ``BakeConfig`` composes this record), else
        ``default`` (else the defaults)."""
        return record_of(cls, config, default)
