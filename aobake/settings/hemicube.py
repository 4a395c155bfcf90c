"""The ``hemicube`` method's settings record (``HemicubeOptions``) and the limits it states,
apart from the method (``aobake.methods.hemicube``: the GL child, moderngl) so that every
bake's config can read them without importing the method."""

from __future__ import annotations

from dataclasses import dataclass

from aobake.errors import InputError
from aobake.settings.spec import check as check_settings
from aobake.settings.spec import record_of, setting

#: the largest resolution: a tile is 3R x R pixels and must fit the framebuffer's usable
#: half (hemicube_gl.half_size); at 512 one point is 786k pixels
MAX_RESOLUTION = 512
#: the default: discretisation error on the closed-form scenes at most ~0.01 (docs/hemicube.md)
DEFAULT_RESOLUTION = 64


@dataclass(frozen=True)
class HemicubeOptions:
    """The ``hemicube`` method's settings (each field's help is its documentation).

    Made by ``aobake.settings.spec.setting`` like every section's record: adding it to
    ``BakeConfig``'s bases gives ``--hemicube-resolution``, its check and its report key;
    until then ``HemicubeMethod.options`` (a class-level default) or ``prepare(...,
    options=)`` sets it, and :meth:`of` reads it from a config that has it.
    """

    hemicube_resolution: int = setting(
        DEFAULT_RESOLUTION, "int", "--method hemicube: pixels across the front face (the four "
        "side faces are R x R/2); even. The discretisation error falls as 1/R, the cost per "
        "point grows with the triangles, little with R (docs/hemicube.md).",
        section="hemicube", low=2, high=MAX_RESOLUTION, words="an even integer >= 2",
        too_high=f"is above the limit of {MAX_RESOLUTION} (a point's 3R x R tile must fit "
                 "the framebuffer)")

    def __post_init__(self):
        check_settings(self)
        self.check_hemicube()

    def check_hemicube(self) -> None:
        """The checks the field's spec cannot state: R even (a side face has R/2 rows)."""
        if self.hemicube_resolution % 2:
            raise InputError(f"--hemicube-resolution: the hemicube resolution must be an even "
                             f"integer >= 2, got {self.hemicube_resolution}")

    @classmethod
    def of(cls, config, default: "HemicubeOptions | None" = None) -> "HemicubeOptions":
        """The settings a config carries (once ``BakeConfig`` composes this record), else
        ``default`` (else the defaults)."""
        return record_of(cls, config, default)
