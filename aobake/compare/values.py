"""How compare's messages name what a file holds (per-vertex values, a lightmap, a camera
view).  A file's values themselves are read by ``aobake.outputs.read`` (``Values``)."""

from __future__ import annotations

from aobake.outputs.values import Values


def kind(target: str) -> str:
    """How a message names what a file of ``target`` holds."""
    return "per-vertex values" if target == "vertices" else "a lightmap (per texel)"


def image_kind(values: Values) -> str | None:
    """What an image file holds by its aobake metadata: "view" (an ``aobake view``: a camera
    record), "lightmap" (any other aobake image: texels of a UV atlas), None (another tool's
    image: it says nothing, and is compared as the reference's kind)."""
    if not values.metadata:
        return None
    return "view" if isinstance(values.metadata.get("camera"), dict) else "lightmap"


#: how a message names each kind of image
IMAGE_KINDS = {"view": "a camera view (per pixel)", "lightmap": "a lightmap (per texel)"}
