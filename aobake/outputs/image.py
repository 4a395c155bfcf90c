"""Texture files: multi-channel EXR and 8/16-bit PNG/TIFF, through OpenImageIO.

Images follow the texel convention of ``aobake.targets.texels``: a map of
W x H texels is an array (H, W) or (H, W, C) whose row 0 is the TOP of the image
(v near 1 in OBJ-convention UVs).  Image files also store the top row first, so
arrays are written as they are, without flipping.

Every write goes through ``atomic_path``: a failed write leaves neither a
partial file nor a temporary one.  OpenImageIO failures raise ``OutputError``
naming the path and OpenImageIO's message.

OpenImageIO behaviours this module relies on or works around (checked with
OIIO 3.2):

- PNG and TIFF alpha: OIIO treats alpha as associated (premultiplied) by
  default, dividing colour by alpha when writing a PNG and multiplying when
  reading PNG or unassociated-alpha TIFF.  Our alpha is coverage, not opacity,
  so every LDR file is written with ``oiio:UnassociatedAlpha = 1`` (PNG data is
  stored untouched; TIFF is tagged ExtraSamples = unassociated alpha) and
  ``read_image`` asks for unassociated alpha too.
- Colour space: AO maps are data, written linear (no sRGB curve).  With
  ``oiio:ColorSpace = "lin_rec709_scene"`` the PNG writer stores a gAMA chunk
  of 1.0 and no sRGB chunk; without it OIIO writes sRGB + gAMA 1/2.2 chunks.
  TIFF has no such tag.  EXR is linear by definition.
- EXR channel order: OpenEXR stores channels sorted by name, and OIIO reads
  them back grouped (unlayered names first, then by layer), so the order given
  to ``write_exr`` is not what a reader sees.  It is kept in the
  ``aobake:channels`` attribute (JSON list).
- Custom attributes: PNG (text chunks) and EXR keep ``aobake:*`` attributes;
  TIFF drops them, so the metadata JSON also goes into ``ImageDescription``.
"""

from __future__ import annotations

import json
import logging
import tempfile
import threading
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from aobake.errors import OutputError
from aobake.outputs.atomic import atomic_path, outside_transaction
from aobake.outputs.report import to_jsonable

log = logging.getLogger(__name__)

LDR_SUFFIXES = (".png", ".tif", ".tiff")
#: EXR channels kept float32 under --half: counts and ids, which half would round above 2048
#: and turn into inf above 65504
FULL_PRECISION = ("rays", "object_id", "primitive_id")
#: the largest finite half float; a channel with a finite value beyond it stays float32
HALF_MAX = 65504.0
#: oiio:ColorSpace name that makes OIIO tag a PNG with gAMA = 1.0 (linear).
LINEAR_COLORSPACE = "lin_rec709_scene"


def _oiio():
    import OpenImageIO as oiio

    return oiio


def prefetch() -> None:
    """Import OpenImageIO on a daemon thread, so that the first image written finds it
    loaded: its import (~0.16 s) is a third of a 1024^2 lightmap's write.  For a caller
    that knows an image will be written and has a core to spare now (aobake's CLI, while
    xatlas's child process unwraps: its single-threaded steps leave one core idle).  An
    import that fails here fails again, with its message, where the image is written."""
    def load():
        try:
            _oiio()
        except Exception:  # noqa: BLE001 - reported by the writer that needs it
            pass

    threading.Thread(target=load, name="aobake-oiio-import", daemon=True).start()


def _metadata_attributes(metadata: Mapping[str, Any] | None) -> dict[str, str]:
    """'aobake:<key>' string attributes (non-strings as JSON) + 'aobake:metadata'."""
    # The one strict JSON conversion every writer shares (non-finite floats as "inf"...).
    metadata = to_jsonable(dict(metadata or {}))
    attrs = {}
    for key, value in metadata.items():
        attrs[f"aobake:{key}"] = value if isinstance(value, str) else json.dumps(value, allow_nan=False)
    attrs["aobake:metadata"] = json.dumps(metadata, sort_keys=True, allow_nan=False)
    return attrs


def _failure(path, tmp, message: str, nbytes: int) -> str:
    """One line for an OpenImageIO failure: the output's name (not the temporary file's) and,
    where the disk is what failed, the operating system's reason (OpenImageIO only says
    that a write failed)."""
    message = " ".join(str(message).replace(str(tmp), str(path)).split())
    try:
        import shutil

        full = shutil.disk_usage(Path(path).parent).free < nbytes + (1 << 16)
    except OSError:  # pragma: no cover
        full = False
    return f"{path}: no space left on device ({message})" if full else f"{path}: {message}"


def _write(path, pixels: np.ndarray, fmt, channel_names, attributes: Mapping[str, Any],
           channel_formats=None) -> None:
    """Write (H, W, C) pixels to path via a temp file; raise OutputError on failure."""
    oiio = _oiio()
    height, width, n_channels = pixels.shape
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:
            raise OutputError(f"{path}: {oiio.geterror() or 'no OpenImageIO writer for this file type'}")
        spec = oiio.ImageSpec(width, height, n_channels, fmt)
        spec.channelnames = tuple(channel_names)
        if channel_formats is not None:
            spec.channelformats = tuple(oiio.TypeDesc(f) for f in channel_formats)
        # No time stamp: OpenImageIO writes the time of writing as DateTime unless it is set
        # empty, and identical inputs must give byte-identical files (caches hash them).
        spec.attribute("DateTime", "")
        for name, value in attributes.items():
            spec.attribute(name, value)
        try:
            if not out.open(str(tmp), spec):
                raise OutputError(_failure(path, tmp, out.geterror() or "cannot open for writing",
                                           pixels.nbytes))
            if not out.write_image(np.ascontiguousarray(pixels)):
                raise OutputError(_failure(path, tmp, out.geterror() or "write failed",
                                           pixels.nbytes))
        finally:
            # Close before atomic_path renames or deletes the temp file; a close
            # after a failed write may still flush a partial file, which the
            # atomic_path cleanup then removes.
            ok = out.close()
        if not ok:
            raise OutputError(f"{path}: {out.geterror() or 'close failed'}")
    log.debug("wrote %s (%dx%d, %d channels)", path, width, height, n_channels)


def write_exr(path, channels: Mapping[str, np.ndarray], metadata: Mapping[str, Any] | None = None,
              half: bool = False) -> None:
    """Write named (H, W) float channels to an OpenEXR file (zip compression).

    channels : name -> (H, W) float array, e.g. 'ao', 'ao_stderr',
        'bent_normal.X'; written in the given order (but see the module note:
        readers see OpenEXR's sorted order; the given order is in
        'aobake:channels').
    metadata : stored as one string attribute 'aobake:<key>' per key (JSON
        text for non-strings) plus 'aobake:metadata', the whole dict as JSON.
    half : store 16-bit half floats instead of 32-bit floats (about 3 decimal
        digits, largest finite 65504); the ``FULL_PRECISION`` channels (ray counts, ids)
        stay float32, so they stay exact and finite at any count.  So does any channel with
        a finite value beyond half's range (a view's depth, distance and P of a scene far
        from the origin or larger than 65504 units): half would store inf there.  Those
        channels are named in a warning and in the ``aobake:float_channels`` attribute.
    """
    if not channels:
        raise ValueError("write_exr needs at least one channel")
    names = list(channels)
    arrays = [np.asarray(channels[name], dtype=np.float32) for name in names]
    shape = arrays[0].shape
    for name, array in zip(names, arrays):
        if array.ndim != 2 or array.shape != shape:
            raise ValueError(f"channel {name!r} must be (H, W) = {shape}, got {array.shape}")
    oiio = _oiio()
    attrs: dict[str, Any] = {"compression": "zip", "Software": "aobake"}
    attrs.update(_metadata_attributes(metadata))
    attrs["aobake:channels"] = json.dumps(names)
    # The pixels are handed over as float32; OIIO converts to half where asked.
    formats = None
    if half:
        beyond = [name for name, array in zip(names, arrays)
                  if name not in FULL_PRECISION and _largest_finite(array) > HALF_MAX]
        if beyond:
            log.warning("%s: %s hold values beyond half float's range (%g): written as "
                        "float32, not half", path, ", ".join(beyond), HALF_MAX)
            attrs["aobake:float_channels"] = json.dumps(beyond)
        full = set(FULL_PRECISION) | set(beyond)
        formats = [oiio.FLOAT if name in full else oiio.HALF for name in names]
    _write(path, np.stack(arrays, axis=-1), oiio.HALF if half else oiio.FLOAT, names, attrs,
           formats)


def _largest_finite(array: np.ndarray) -> float:
    """The largest |value| of the finite values of ``array`` (0 when there is none)."""
    finite = np.abs(array[np.isfinite(array)])
    return float(finite.max()) if finite.size else 0.0


def quantize(x, bit_depth: int) -> np.ndarray:
    """Map [0, 1] floats to integers: round(clip(x, 0, 1) * (2**bits - 1)).

    NaN maps to 0.  Returns uint8 for 8 bits, uint16 for 16 bits.
    """
    _check_bit_depth(bit_depth)
    top = float(2 ** bit_depth - 1)
    x = np.nan_to_num(np.asarray(x, dtype=np.float64), nan=0.0)
    return np.rint(np.clip(x, 0.0, 1.0) * top).astype(np.uint8 if bit_depth == 8 else np.uint16)


def _check_bit_depth(bit_depth) -> None:
    if bit_depth not in (8, 16):
        raise ValueError(f"bit_depth must be 8 or 16, got {bit_depth}")


def _ldr_pixels(value, coverage, bit_depth: int, r_only: bool) -> np.ndarray:
    value = np.asarray(value, dtype=np.float64)
    coverage = np.asarray(coverage, dtype=np.float64)
    if value.ndim != 2:
        raise ValueError(f"value must be (H, W), got {value.shape}")
    if coverage.shape != value.shape:
        raise ValueError(f"coverage must be {value.shape}, got {coverage.shape}")
    v = quantize(value, bit_depth)
    zero = np.zeros_like(v)
    rgb = [v, zero, zero] if r_only else [v, v, v]
    return np.stack(rgb + [quantize(coverage, bit_depth)], axis=-1)


def write_ldr(path, value, coverage, bit_depth: int = 8, r_only: bool = False,
              metadata: Mapping[str, Any] | None = None) -> None:
    """Write a [0, 1] map as an RGBA PNG or TIFF (.png, .tif, .tiff).

    value : (H, W) float, written to R, G and B (or to R only, with G = B = 0,
        when r_only: the glTF occlusion-texture convention reads R).
    coverage : (H, W) float in [0, 1], written to alpha (unassociated: colour is
        never multiplied by it).
    bit_depth : 8 or 16.  Integer = round(clip(x, 0, 1) * (2**bits - 1)), so
        0 -> 0 and 1 -> 255 or 65535; NaN -> 0.  Values are linear data, stored
        without an sRGB curve and tagged linear where the format can say so.
    metadata : as in ``write_exr``; also stored as JSON in ImageDescription.
    """
    _check_bit_depth(bit_depth)
    pixels = _ldr_pixels(value, coverage, bit_depth, r_only)
    _write_ldr_pixels(path, pixels, bit_depth, metadata)


def write_rgb(path, rgb, alpha=None, bit_depth: int = 8,
              metadata: Mapping[str, Any] | None = None) -> None:
    """Write a [0, 1] (H, W, 3) float image as RGB (or RGBA with ``alpha`` (H, W) float in
    [0, 1]) PNG or TIFF, quantised as :func:`write_ldr` does (linear data, no sRGB curve):
    an ORM map (R occlusion, G roughness, B metalness) or a diagnostic picture."""
    _check_bit_depth(bit_depth)
    rgb = np.asarray(rgb, dtype=np.float64)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb must be (H, W, 3), got {rgb.shape}")
    planes = [quantize(rgb[..., c], bit_depth) for c in range(3)]
    if alpha is not None:
        if np.shape(alpha) != rgb.shape[:2]:
            raise ValueError(f"alpha must be {rgb.shape[:2]}, got {np.shape(alpha)}")
        planes.append(quantize(alpha, bit_depth))
    _write_ldr_pixels(path, np.stack(planes, axis=-1), bit_depth, metadata)


def rgb_png_bytes(rgb, bit_depth: int = 8) -> bytes:
    """:func:`write_rgb`'s PNG as bytes (e.g. an ORM map to embed in a GLB)."""
    with tempfile.TemporaryDirectory(prefix="aobake-png-") as tmp, outside_transaction():
        path = Path(tmp, "image.png")
        write_rgb(path, rgb, bit_depth=bit_depth)
        return path.read_bytes()


def _write_ldr_pixels(path, pixels: np.ndarray, bit_depth: int,
                      metadata: Mapping[str, Any] | None) -> None:
    """(H, W, 3 or 4) uint8/uint16 pixels to a PNG/TIFF, tagged linear, alpha unassociated."""
    suffix = Path(path).suffix.lower()
    if suffix not in LDR_SUFFIXES:
        raise ValueError(f"{path}: LDR images must end in {', '.join(LDR_SUFFIXES)}")
    oiio = _oiio()
    attrs: dict[str, Any] = {
        "oiio:UnassociatedAlpha": 1,
        "oiio:ColorSpace": LINEAR_COLORSPACE,
        "Software": "aobake",
    }
    if suffix != ".png":
        attrs["compression"] = "zip"
    meta = _metadata_attributes(metadata)
    attrs.update(meta)
    attrs["ImageDescription"] = meta["aobake:metadata"]
    _write(path, pixels, oiio.UINT8 if bit_depth == 8 else oiio.UINT16,
           ("R", "G", "B", "A")[:pixels.shape[2]], attrs)


def png_bytes(value, coverage, bit_depth: int = 8, r_only: bool = True,
              metadata: Mapping[str, Any] | None = None) -> bytes:
    """Encode a map as PNG file bytes (e.g. to embed in a GLB); see ``write_ldr``."""
    # OIIO's Python binding has no in-memory writer, so go through a temp file.
    with tempfile.TemporaryDirectory(prefix="aobake-png-") as tmp, outside_transaction():
        path = Path(tmp, "image.png")
        write_ldr(path, value, coverage, bit_depth=bit_depth, r_only=r_only, metadata=metadata)
        return path.read_bytes()


