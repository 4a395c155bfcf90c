"""The error as a picture: a diverging blue-white-red colour map (``diverging``), drawn on
the reference's vertices (binary PLY) or its covered texels (RGBA PNG), written atomically."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from aobake.errors import OutputError
from aobake.outputs.atomic import atomic_path
from aobake.outputs.strictjson import metadata_json
from aobake.outputs.values import Values

#: heatmap colours (sRGB bytes): e = -scale, 0, +scale
_BLUE, _WHITE, _RED = np.array([59, 76, 192]), np.array([255, 255, 255]), np.array([180, 4, 38])


def check_path(path: Path, target: str, inputs) -> None:
    """Refuse a heatmap path before anything is read: the wrong suffix for ``target``, a missing
    directory, a directory, one of the ``inputs``.  Raises OutputError."""
    want = ".png" if target == "texels" else ".ply"
    if path.suffix.lower() != want:
        what = "per-vertex values" if target == "vertices" else "an image (per texel or pixel)"
        raise OutputError(f"{path}: a heatmap of {what} is written as {want}")
    if not path.parent.resolve().is_dir():
        raise OutputError(f"{path}: directory {path.parent} does not exist")
    if path.is_dir():
        raise OutputError(f"{path}: is a directory; --heatmap needs a file name")
    if any(path.resolve() == p.resolve() for p in inputs):
        raise OutputError(f"{path}: refusing to overwrite an input with the heatmap")


def write_heatmap(path: Path, reference: Values, error: np.ndarray, where: np.ndarray | None,
                  scale: float, quantity: str) -> None:
    """``error`` (n,) float64 = candidate - reference, full colour at |error| = scale: on the
    reference's vertices (``where`` None) or on its texels ``where`` (H, W) bool, in mask order.
    Raises OutputError naming the file and the reason (a full disk, a lost mount ...)."""
    try:
        if where is not None:
            _write_png(path, error, where, scale, quantity)
        else:
            _write_ply(path, reference, error, scale, quantity)
    except OutputError:
        raise
    except OSError as exc:  # a full disk, a lost mount: the file and the reason, one line
        raise OutputError(f"{path}: {(exc.strerror or str(exc)).lower()}") from None


def diverging(t: np.ndarray) -> np.ndarray:
    """(n,) float error / scale -> (n, 3) uint8 sRGB: blue at -1, white at 0, red at +1
    (clipped beyond)."""
    t = np.clip(np.asarray(t, dtype=np.float64), -1.0, 1.0)[:, None]
    end = np.where(t < 0, _BLUE, _RED)
    return np.rint(_WHITE + np.abs(t) * (end - _WHITE)).astype(np.uint8)


def _heatmap_metadata(quantity: str, scale: float) -> dict:
    return {"heatmap": {"quantity": quantity, "error": f"candidate - reference {quantity}",
                        "scale": scale, "colours": "white = equal; red = candidate higher "
                        "(more open), blue = candidate lower; full colour at |error| = scale"}}


def _write_ply(path: Path, reference: Values, error: np.ndarray, scale: float,
               quantity: str) -> None:
    """The reference's vertices (and faces) with ``error`` (n,) as a float property and as
    diverging red/green/blue, binary little-endian PLY, written atomically."""
    if reference.positions is None:
        raise OutputError(f"{path}: the reference {reference.path} has no vertex positions to "
                          "draw a heatmap on")
    n = len(error)
    colours = diverging(error / scale)
    vertex = np.empty(n, dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("error", "<f4"),
                                ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for i, axis in enumerate("xyz"):
        vertex[axis] = reference.positions[:, i]
    vertex["error"] = error
    for i, channel in enumerate(("red", "green", "blue")):
        vertex[channel] = colours[:, i]
    faces = reference.faces if reference.faces is not None else np.zeros((0, 3), np.int64)
    face = np.empty(len(faces), dtype=[("count", "u1"), ("vertex_indices", "<i4", (3,))])
    face["count"], face["vertex_indices"] = 3, faces
    from aobake.outputs.ply import METADATA_COMMENT

    header = ["ply", "format binary_little_endian 1.0",
              f"comment {METADATA_COMMENT} "
              f"{metadata_json(_heatmap_metadata(quantity, scale), compact=True)}",
              f"element vertex {n}", "property double x", "property double y",
              "property double z", "property float error", "property uchar red",
              "property uchar green", "property uchar blue", f"element face {len(faces)}",
              "property list uchar int vertex_indices", "end_header"]
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:
            handle.write(("\n".join(header) + "\n").encode("ascii"))
            handle.write(vertex.tobytes())
            handle.write(face.tobytes())


def _write_png(path: Path, error: np.ndarray, mask: np.ndarray, scale: float,
               quantity: str) -> None:
    """An 8-bit RGBA PNG: the compared texels (mask (H, W) bool) in diverging colours of
    ``error`` (n,) (in mask order), opaque; the others transparent black."""
    import OpenImageIO as oiio

    from aobake.outputs.image import write_pixels

    pixels = np.zeros((*mask.shape, 4), dtype=np.uint8)
    pixels[mask, :3] = diverging(error / scale)
    pixels[mask, 3] = 255
    attrs = {"oiio:UnassociatedAlpha": 1, "Software": "aobake",
             "aobake:metadata": json.dumps(_heatmap_metadata(quantity, scale), allow_nan=False)}
    write_pixels(path, pixels, oiio.UINT8, ("R", "G", "B", "A"), attrs)

