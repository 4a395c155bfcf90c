"""How compare's messages name what a file holds (per-vertex values, a lightmap, a camera
view).  A file's values themselves are read by ``aobake.outputs.read`` (``Values``)."""

from __future__ import annotations

from aobake.outputs.values import Values


def kind(values: Values) -> str:
    """How a message names what a file holds: per-vertex values, a lightmap, a camera view
    (by its aobake metadata), or another tool's image."""
    if values.target == "vertices":
        return "per-vertex values"
    return IMAGE_KINDS.get(image_kind(values), "an image (per texel or pixel)")


def image_kind(values: Values) -> str | None:
    """What an image file holds by its aobake metadata: "view" (an ``aobake view``: a camera
    record), "lightmap" (any other aobake image: texels of a UV atlas), None (another tool's
    image: it says nothing, and is compared as the reference's kind)."""
    if not values.metadata:
        return None
    return "view" if isinstance(values.metadata.get("camera"), dict) else "lightmap"


#: how a message names each kind of image
IMAGE_KINDS = {"view": "a camera view (per pixel)", "lightmap": "a lightmap (per texel)"}
