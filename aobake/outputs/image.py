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
  TIFF has no tag that says linear (short of an ICC profile): aobake's TIFFs
  are known by the metadata in their ImageDescription, which says they are
  aobake's (linear by its convention).  EXR is linear by definition.
- EXR channel order: OpenEXR stores channels sorted by name, and OIIO reads
  them back grouped (unlayered names first, then by layer), so the order given
  to ``write_exr`` is not what a reader sees.  It is kept in the
  ``aobake:channels`` attribute (JSON list).
- Custom attributes: PNG (text chunks) and EXR keep ``aobake:*`` attributes;
  TIFF drops them, so the metadata JSON also goes into ``ImageDescription``.

The reader beside the writers: ``read`` (every channel of every part of any image as a
``Table``: a multi-part EXR's subimages, Blender's render passes, included; each channel
with its transfer function as the file's colour tags say, ``transfer_of``: PNG chunks
cICP / iCCP / sRGB / gAMA, ICC profiles, TIFF's EXIF colour space, EXR's colorInteropID),
on ``read_parts`` / ``read_pixels`` / ``read_size``, which check a PNG's bytes before libpng
sees them, bound the pixels by the file's size and keep the image library's own complaints
off the terminal (``quiet_stderr``).

OpenImageIO reports ``oiio:ColorSpace = "srgb_rec709_scene"`` for every PNG without colour
chunks (its default guess, not the file's word), so a PNG's transfer is read from its
chunks, here, never from that attribute.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import struct
import sys
import tempfile
import threading
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from aobake.errors import OutputError
from aobake.outputs.atomic import atomic_path, outside_transaction
from aobake.outputs.strictjson import to_jsonable
from aobake.outputs.table import Table, Unreadable, parse_json

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


def write_pixels(path, pixels: np.ndarray, fmt, channel_names, attributes: Mapping[str, Any],
                 channel_formats=None) -> None:
    """Write (H, W, C) ``pixels`` to ``path`` as they are, atomically: ``fmt`` the
    OpenImageIO pixel type (e.g. ``oiio.UINT8``), ``channel_names`` one per channel,
    ``attributes`` the file's (name -> value), ``channel_formats`` per-channel types or None.
    OutputError naming ``path`` on failure.  (The other writers here are built on it.)"""
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
    write_pixels(path, np.stack(arrays, axis=-1), oiio.HALF if half else oiio.FLOAT, names, attrs,
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
    write_pixels(path, pixels, oiio.UINT8 if bit_depth == 8 else oiio.UINT16,
           ("R", "G", "B", "A")[:pixels.shape[2]], attrs)


def png_bytes(value, coverage, bit_depth: int = 8, r_only: bool = True,
              metadata: Mapping[str, Any] | None = None) -> bytes:
    """Encode a map as PNG file bytes (e.g. to embed in a GLB); see ``write_ldr``."""
    # OIIO's Python binding has no in-memory writer, so go through a temp file.
    with tempfile.TemporaryDirectory(prefix="aobake-png-") as tmp, outside_transaction():
        path = Path(tmp, "image.png")
        write_ldr(path, value, coverage, bit_depth=bit_depth, r_only=r_only, metadata=metadata)
        return path.read_bytes()


# ---------------------------------------------------------------------------------------------
# reading


def read(path) -> Table:
    """An image (EXR, PNG, TIFF) as a ``Table`` (``naming`` 'exr'): every channel of every
    part (an EXR's subimages: Blender writes each render pass as a part) as (H, W) float
    (integer files scaled to [0, 1]), alpha unassociated (coverage is not opacity), and
    each channel's transfer function as the file tags it (``transfers``: see
    ``transfer_of``); aobake's metadata attribute (TIFF: its ImageDescription) as the
    metadata.  Channels of a multi-part file are named ``part.channel`` unless their own
    name already starts with the part's (Blender's ``ViewLayer.AO.R`` in part
    ``ViewLayer.AO``).  Raises ``Unreadable``."""
    parts, chunks = _read(path, every_part=True)
    metadata = {}
    for attr in ("aobake:metadata", "ImageDescription"):  # TIFF keeps only the description
        text = parts[0].attrs.get(attr)
        if not isinstance(text, str):
            continue
        try:
            candidate = parse_json(text)
        except Unreadable:  # a description that is not aobake's metadata
            continue
        if isinstance(candidate, dict) and "config" in candidate:
            metadata = candidate
            break
    columns, transfers, listing = {}, {}, {}
    for index, part in enumerate(parts):
        names = listing.setdefault(part.name or f"part {index}", [])
        for i, channel in enumerate(part.names):
            name = _column_name(part.name, channel, len(parts) > 1)
            if name in columns:  # the same names in two parts (a stereo pair's views)
                name = f"{part.name or index}.{channel}"
            if name in columns:
                name = f"{name} (part {index})"
            columns[name] = part.pixels[:, :, i]
            transfers[name] = transfer_of(Path(path).suffix.lower(), part.attrs, part.format,
                                          channel, chunks)
            names.append(name)
    return Table(columns, "exr", metadata=metadata, transfers=transfers,
                 parts=listing if len(parts) > 1 else None)


def _column_name(part: str, channel: str, multi: bool) -> str:
    """A channel's column: its own name, prefixed with its part's in a multi-part file
    unless it already starts with it (Blender names channels layer.pass.channel in part
    layer.pass)."""
    if not multi or not part or channel == part or channel.startswith(part + "."):
        return channel
    return f"{part}.{channel}"


@dataclass(frozen=True)
class Part:
    """One part (subimage) of an image file: name ('' when it has none), pixels (H, W, C)
    float32, channel names, attributes (plus 'oiio:format', 'oiio:channelformats'), format
    (the pixel type: 'uint8', 'uint16', 'half', 'float', ...)."""

    name: str
    pixels: np.ndarray
    names: list
    attrs: dict
    format: str


#: parts read from one file at most (Blender writes one per pass and view: a few dozen)
MAX_PARTS = 1024


def read_parts(path) -> list:
    """Every part (subimage) of an image through OpenImageIO, alpha unassociated: a list of
    ``Part``.  The pixels of all parts together are bounded by the file's size as
    :func:`read_pixels` bounds one.  ``Unreadable`` for a broken file."""
    return _read(path, every_part=True)[0]


def read_pixels(path) -> tuple[np.ndarray, list[str], dict]:
    """The first subimage through OpenImageIO, alpha unassociated (colour is not multiplied by
    alpha; in aobake's files alpha is coverage, not opacity).

    Returns (pixels (H, W, C) float32, channel names, attributes).  Float files come back as
    stored; integer files in OIIO's normalised scale, x / (2**bits - 1).  The attributes are
    the file's, plus 'oiio:format' (e.g. 'uint8', 'half') and 'oiio:channelformats' (the
    per-channel formats of a mixed file; [] when uniform).
    """
    part = _read(path, every_part=False)[0][0]
    return part.pixels, part.names, part.attrs


def _read(path, every_part: bool) -> tuple[list, dict]:
    """(the parts (every one, or the first), a PNG's colour chunks ({} for other files))."""
    import OpenImageIO as oiio

    chunks = {}
    with open(path, "rb") as handle:
        head = handle.read(len(_PNG_SIGNATURE))
        size = os.fstat(handle.fileno()).st_size
        if head == _PNG_SIGNATURE:  # libpng reports a broken file on stderr itself: check first
            handle.seek(0)
            chunks = check_png(handle.read())
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    parts, need = [], 0
    with quiet_stderr() as said:
        inp = oiio.ImageInput.open(str(path), config)
        if inp is None:
            raise Unreadable(oiio.geterror() or "OpenImageIO cannot open it")
        try:
            index = 0
            while True:
                if index and (not every_part or not inp.seek_subimage(index, 0)):
                    break
                if index >= MAX_PARTS:
                    raise Unreadable(f"has more than {MAX_PARTS} parts")
                spec = inp.spec()
                need += spec.width * spec.height * max(spec.nchannels, 1) * 4
                if need > max(_IMAGE_FLOOR, _IMAGE_RATIO * size):
                    raise Unreadable(f"its header claims {spec.width}x{spec.height} pixels of "
                                     f"{spec.nchannels} channels"
                                     f"{f' in part {index}' if index else ''} ({need} bytes "
                                     f"as float) from {size} bytes")
                pixels = inp.read_image(index, 0, 0, spec.nchannels, oiio.FLOAT)
                if pixels is None:
                    raise Unreadable(inp.geterror() or "cannot read its pixels")
                attrs = {p.name: p.value for p in spec.extra_attribs}
                attrs["oiio:format"] = str(spec.format)
                attrs["oiio:channelformats"] = [str(f) for f in spec.channelformats]
                name = attrs.get("oiio:subimagename", attrs.get("name", ""))
                pixels = np.asarray(pixels, dtype=np.float32).reshape(
                    spec.height, spec.width, spec.nchannels)
                parts.append(Part(name if isinstance(name, str) else "", pixels,
                                  list(spec.channelnames), attrs, str(spec.format)))
                index += 1
        finally:
            inp.close()
    if said:
        log.debug("%s: the image library said: %s", path, " ".join(said))
    return parts, chunks


# ---------------------------------------------------------------------------------------------
# transfer functions: how an image's stored values relate to linear ones


@dataclass(frozen=True)
class Transfer:
    """How a channel's stored values v in [0, 1] relate to the linear values they encode.

    kind : 'linear' (x = v) | 'srgb' (the sRGB EOTF: v / 12.92 up to 0.04045, else
      ((v + 0.055) / 1.055)^2.4) | 'gamma' (x = v^gamma) | 'curve' (an ICC profile's curve:
      ``curve`` holds x at evenly spaced v in [0, 1], interpolated linearly) |
      'display' (no tag says, and the format's convention is display-referred: an 8/16-bit
      PNG or TIFF is shown as sRGB by every viewer, but it may hold a view transform's
      output, or linear values: unknown) |
      'unsupported' (a tag says something this reader does not invert: a log or PQ curve,
      an unknown colour space)
    source : what says so, for messages ("the PNG's gAMA chunk (1.0)")
    """

    kind: str
    source: str
    gamma: float = 1.0
    curve: tuple = ()

    @property
    def known(self) -> bool:
        """Whether the stored values can be linearised."""
        return self.kind in ("linear", "srgb", "gamma", "curve")

    @property
    def name(self) -> str:
        """How the record names it: 'linear', 'srgb', 'gamma 2.2', 'ICC curve'."""
        return {"gamma": f"gamma {self.gamma:.4g}", "curve": "ICC curve"}.get(self.kind, self.kind)

    @property
    def says(self) -> str:
        """How a message names the values: 'sRGB-encoded', 'gamma 2.2-encoded', 'linear'."""
        return {"linear": "linear", "srgb": "sRGB-encoded", "display": "display-referred",
                "unsupported": "non-linear"}.get(self.kind, f"{self.name}-encoded")

    def to_linear(self, v: np.ndarray) -> np.ndarray:
        """(...) float64 linear values of stored values ``v`` (float, in [0, 1] for an integer
        file; float files may hold more: the curve is extended as a power or a line)."""
        v = np.asarray(v, dtype=np.float64)
        if self.kind == "linear":
            return v.copy()
        if self.kind == "srgb":
            a = np.abs(v)  # odd extension below 0, as OCIO's sRGB does
            return np.sign(v) * np.where(a <= 0.04045, a / 12.92,
                                         ((a + 0.055) / 1.055) ** 2.4)
        if self.kind == "gamma":
            return np.sign(v) * np.abs(v) ** self.gamma
        if self.kind == "curve":
            curve = np.asarray(self.curve, dtype=np.float64)
            return np.interp(v, np.linspace(0.0, 1.0, len(curve)), curve)
        raise ValueError(f"cannot linearise values of transfer {self.kind!r}")

    def slope(self, v: np.ndarray) -> np.ndarray:
        """d linear / d stored at ``v``: what a standard error of stored values is multiplied
        by (the delta method), by a central difference of ``to_linear``."""
        v = np.asarray(v, dtype=np.float64)
        h = 1e-6
        return (self.to_linear(v + h) - self.to_linear(v - h)) / (2 * h)


#: the transfers a user may state for a file (``--candidate-transfer``, ``transfer=``)
TRANSFERS = {
    "linear": Transfer("linear", "stated"),
    "srgb": Transfer("srgb", "stated"),
}

#: colour space names (lower case) that hold linear values: OpenColorIO's and Blender's
#: common names; every ASWF colour interop ID starting 'lin_' is linear too
_LINEAR_SPACES = {
    "linear", "scene_linear", "scene-linear", "data", "raw", "non-color", "noncolor",
    "utility - raw", "acescg", "aces2065-1", "aces - acescg", "aces - aces2065-1",
    "linear rec.709", "linear rec.709 (srgb)", "linear rec.2020", "linear srgb",
    "linear cie-xyz d65", "linear cie-xyz e", "linear dci-p3 d65", "linear p3-d65",
    "linear filmlight e-gamut", "utility - linear - srgb", "utility - linear - rec.709",
    "utility - linear - rec.2020", "cie-xyz-d65", "ciexyz", "xyz",
}
#: colour space names (lower case) that hold sRGB-encoded values; every interop ID starting
#: 'srgb_' is sRGB-encoded too
_SRGB_SPACES = {
    "srgb", "srgb texture", "srgb - texture", "utility - srgb - texture", "srgb_texture",
    "srgb_tx", "output - srgb", "srgb - display", "srgb display", "srgb_display",
    "srgb iec61966-2.1", "srgb2.2",
}


def named_transfer(space: str, source: str) -> Transfer:
    """The transfer of a colour space named ``space`` (an OpenEXR colorInteropID, OIIO's
    ``oiio:ColorSpace``): linear, sRGB, a pure gamma (ASWF interop IDs 'g22_...', 'g24_...',
    Rec.1886 = gamma 2.4), or 'unsupported' for any other (a log encoding, a view transform
    such as Filmic or AgX, a name this table does not know)."""
    lower = " ".join(str(space).split()).lower()
    where = f"{source} ({space!r})"
    if lower.startswith("lin_") or lower in _LINEAR_SPACES:
        return Transfer("linear", where)
    if lower.startswith("srgb_") or lower in _SRGB_SPACES:
        return Transfer("srgb", where)
    match = re.fullmatch(r"g(\d)(\d)_\w+", lower)
    if match:
        return Transfer("gamma", where, gamma=int(match.group(1)) + int(match.group(2)) / 10)
    if lower.startswith("rec1886_") or lower in ("rec.1886", "rec1886", "bt.1886"):
        return Transfer("gamma", where, gamma=2.4)
    return Transfer("unsupported", f"{where} names a colour space compare cannot linearise")


def transfer_of(suffix: str, attrs: Mapping, fmt: str, channel: str = "R",
                png_chunks: Mapping | None = None) -> Transfer:
    """The transfer function a file's tags give a channel's values.

    PNG (its chunks, by the PNG specification's precedence): cICP (transfer 8 linear, 13
    sRGB, 4 gamma 2.2, 5 gamma 2.8), iCCP (the ICC profile's curve for the channel), sRGB,
    gAMA (gamma 1/g); none of them: display-referred (an 8/16-bit image without tags is
    shown as sRGB by every viewer).  TIFF: an ICC profile, else the colour space
    OpenImageIO reads (the EXIF ColorSpace tag: sRGB), else linear for a float file and
    display-referred for an integer one.  EXR: its colorInteropID (or ``oiio:ColorSpace``),
    else linear (OpenEXR's convention: scene-linear values).  Chromaticities (primaries)
    do not change a transfer, and are not read.
    """
    bits = {"uint8": "8-bit", "uint16": "16-bit"}.get(fmt, fmt)
    if suffix == ".png":
        return _png_transfer(png_chunks or {}, channel, bits)
    icc = attrs.get("ICCProfile")
    if icc is not None:
        return icc_transfer(bytes(np.asarray(icc, dtype=np.uint8)), channel, "its ICC profile")
    if suffix == ".exr":
        for attr in ("colorInteropID", "oiio:ColorSpace"):
            space = attrs.get(attr)
            if isinstance(space, str) and space.strip():
                return named_transfer(space, f"its {attr} attribute")
        return Transfer("linear", "an EXR without a colour space (linear by OpenEXR's convention)")
    space = attrs.get("oiio:ColorSpace")
    if isinstance(space, str) and space.strip():
        return named_transfer(space, "its colour space tag")
    if fmt in ("half", "float", "double"):
        return Transfer("linear", f"a {fmt} image without a colour tag (linear by convention)")
    return Transfer("display", f"{_article(bits)} {bits} {suffix[1:].upper()} without a colour "
                               "tag (an ICC profile or the EXIF colour space)")


#: cICP transfer characteristics (ITU-T H.273) this reader inverts
_CICP = {8: ("linear", 1.0), 13: ("srgb", 1.0), 4: ("gamma", 2.2), 5: ("gamma", 2.8)}


def _png_transfer(chunks: Mapping, channel: str, bits: str) -> Transfer:
    """A PNG's transfer from its colour chunks (``transfer_of``)."""
    if b"cICP" in chunks:
        body = chunks[b"cICP"]
        if len(body) != 4:
            return Transfer("unsupported", "its cICP chunk is malformed")
        primaries, transfer, matrix, full = body
        where = f"its cICP chunk (transfer {transfer})"
        if matrix != 0 or full != 1:
            return Transfer("unsupported", f"{where} says "
                                           f"{'narrow-range' if not full else 'YCbCr'} values, "
                                           "which compare does not read")
        if transfer not in _CICP:
            return Transfer("unsupported", f"{where} says a transfer (ITU-T H.273) compare "
                                           "cannot undo")
        kind, gamma = _CICP[transfer]
        return Transfer(kind, where, gamma=gamma)
    if b"iCCP" in chunks:
        body = chunks[b"iCCP"]
        end = body.find(b"\0")
        if end < 1 or end + 2 > len(body) or body[end + 1] != 0:
            return Transfer("unsupported", "its iCCP chunk is malformed")
        inflate = zlib.decompressobj()
        try:
            profile = inflate.decompress(body[end + 2:], _ICC_LIMIT)
        except zlib.error:
            return Transfer("unsupported", "its iCCP chunk's profile does not inflate")
        if inflate.unconsumed_tail:
            return Transfer("unsupported", f"its ICC profile is larger than {_ICC_LIMIT} bytes")
        return icc_transfer(profile, channel, "its ICC profile (iCCP)")
    if b"sRGB" in chunks:
        return Transfer("srgb", "its sRGB chunk")
    if b"gAMA" in chunks:
        body = chunks[b"gAMA"]
        (g,) = struct.unpack(">I", body) if len(body) == 4 else (0,)
        if g <= 0:
            return Transfer("unsupported", "its gAMA chunk is malformed")
        # gAMA holds the encoding exponent g x 100000: linear = stored^(1/g)
        gamma = 100000.0 / g
        where = f"its gAMA chunk ({g / 100000:.5g})"
        if abs(gamma - 1.0) < 1e-3:
            return Transfer("linear", where)
        return Transfer("gamma", where, gamma=gamma)
    return Transfer("display", f"{_article(bits)} {bits} PNG without a colour chunk (sRGB, "
                               "gAMA, cICP or iCCP)")


def _article(word: str) -> str:
    return "an" if word[:1] in "8aeiou" or word.startswith(("11", "18")) else "a"


#: the largest ICC profile read (a profile's curves and header are a few kB; LUT profiles
#: reach a few hundred)
_ICC_LIMIT = 4 << 20
#: sRGB's EOTF as an ICC parametric curve (type 3: g, a, b, c, d)
_SRGB_PARA = (2.4, 1 / 1.055, 0.055 / 1.055, 1 / 12.92, 0.04045)


def icc_transfer(profile: bytes, channel: str, source: str) -> Transfer:
    """The transfer of ``channel`` in an ICC profile: its TRC tag (kTRC for a grey profile,
    else rTRC, gTRC or bTRC by the channel), a 'curv' (identity, a gamma, or a table) or a
    'para' (the five parametric types).  Named 'linear', 'srgb' or 'gamma' when it is one
    (within 1e-3), else 'curve' (the curve sampled at 4096 points)."""
    try:
        values = _icc_curve(profile, channel)
    except (struct.error, ValueError, IndexError, ZeroDivisionError, OverflowError) as exc:
        return Transfer("unsupported", f"{source}'s curve cannot be read ({exc})")
    if isinstance(values, Transfer):
        return Transfer(values.kind, source, gamma=values.gamma)
    if values is None:
        return Transfer("unsupported", f"{source} has no curve for {channel}")
    grid = np.linspace(0.0, 1.0, len(values))
    for kind, gamma in (("linear", 1.0), ("srgb", 1.0), ("gamma", 2.2)):
        reference = Transfer(kind, source, gamma=gamma).to_linear(grid)
        if np.max(np.abs(values - reference)) < 1e-3:
            return Transfer(kind, source, gamma=gamma)
    if not (np.all(np.isfinite(values)) and np.all(np.diff(values) >= 0)):
        return Transfer("unsupported", f"{source}'s curve is not increasing")
    return Transfer("curve", source, curve=tuple(float(x) for x in values))


def _icc_curve(profile: bytes, channel: str):
    """The TRC of ``channel`` as a Transfer (identity, gamma) or (4096,) float64 samples in
    [0, 1], or None when the profile has none."""
    if len(profile) < 132 or profile[36:40] != b"acsp":
        raise ValueError("not an ICC profile")
    space = profile[16:20]
    wanted = [b"kTRC"] if space == b"GRAY" else \
        [{"G": b"gTRC", "B": b"bTRC"}.get(channel.rsplit(".", 1)[-1], b"rTRC")]
    (count,) = struct.unpack_from(">I", profile, 128)
    count = min(count, (len(profile) - 132) // 12)
    tags = {}
    for i in range(count):
        sig, offset, size = struct.unpack_from(">4sII", profile, 132 + 12 * i)
        tags.setdefault(sig, (offset, size))
    for sig in wanted:
        if sig not in tags:
            continue
        offset, size = tags[sig]
        body = profile[offset:offset + size]
        kind = body[:4]
        if kind == b"curv":
            (n,) = struct.unpack_from(">I", body, 8)
            if n == 0:
                return Transfer("linear", "")
            if n == 1:
                (g,) = struct.unpack_from(">H", body, 12)
                return Transfer("linear", "") if g == 256 else Transfer("gamma", "", gamma=g / 256)
            table = np.frombuffer(body[12:12 + 2 * n], dtype=">u2").astype(np.float64) / 65535
            if len(table) != n:
                raise ValueError("its curv table is cut short")
            return np.interp(np.linspace(0, 1, 4096), np.linspace(0, 1, n), table)
        if kind == b"para":
            (function,) = struct.unpack_from(">H", body, 8)
            counts = {0: 1, 1: 3, 2: 4, 3: 5, 4: 7}
            if function not in counts:
                raise ValueError(f"unknown parametric curve type {function}")
            params = [x / 65536 for x in struct.unpack_from(f">{counts[function]}i", body, 12)]
            if function == 0:
                g = params[0]
                return Transfer("linear", "") if abs(g - 1) < 1e-4 else \
                    Transfer("gamma", "", gamma=g)
            # ICC.1 10.18: Y = (aX + b)^g + e for X >= d, else cX + f; types 1 and 2 have
            # d = -b / a and the constant c (type 2) on both sides; type 3 has e = f = 0
            g, a, b = params[:3]
            if function == 1:
                c, d, e, f = 0.0, -b / a, 0.0, 0.0
            elif function == 2:
                c, d, e, f = 0.0, -b / a, params[3], params[3]
            else:
                c, d = params[3:5]
                e, f = (params[5], params[6]) if function == 4 else (0.0, 0.0)
            x = np.linspace(0.0, 1.0, 4096)
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                return np.where(x >= d, np.maximum(a * x + b, 0.0) ** g + e, c * x + f)
        raise ValueError(f"unknown curve type {kind!r}")
    return None


def read_size(path) -> tuple[int, int, int]:
    """(width, height, channels) of an image from its header, as :func:`read_pixels` would
    read it: a PNG checked first (libpng would write its own complaint on stderr), whatever
    the image library says kept off the terminal; ``Unreadable`` for a broken file."""
    import OpenImageIO as oiio

    with open(path, "rb") as handle:
        if handle.read(len(_PNG_SIGNATURE)) == _PNG_SIGNATURE:
            handle.seek(0)
            check_png(handle.read())
    with quiet_stderr() as said:
        inp = oiio.ImageInput.open(str(path))
        if inp is None:
            raise Unreadable(oiio.geterror() or "OpenImageIO cannot open it")
        try:
            spec = inp.spec()
            size = (spec.width, spec.height, spec.nchannels)
        finally:
            inp.close()
    if said:
        log.debug("%s: the image library said: %s", path, " ".join(said))
    return size


#: an image's pixels (as float32) may take this many times its file's size (compressed
#: formats of smooth maps reach a few hundred), or _IMAGE_FLOOR bytes whatever the size
_IMAGE_RATIO, _IMAGE_FLOOR = 4096, 256 << 20


@contextlib.contextmanager
def quiet_stderr():
    """Keep what C libraries write to the process's stderr (libpng's ``libpng error: ...``)
    off the terminal: file descriptor 2 points at a temporary file for the block, and the
    list yielded receives its text (stripped lines) afterwards.  Python's own sys.stderr is
    flushed first, so nothing of ours is caught."""
    said: list = []
    fd = 2  # where C's stderr writes, whatever Python's sys.stderr is at the moment
    try:
        saved = os.dup(fd)
    except OSError:  # no stderr at all: nothing to keep quiet
        yield said
        return
    try:
        if sys.stderr is not None:
            sys.stderr.flush()
        with tempfile.TemporaryFile() as caught:
            os.dup2(caught.fileno(), fd)
            try:
                yield said
            finally:
                os.dup2(saved, fd)
                caught.seek(0)
                text = caught.read(1 << 16).decode("utf-8", errors="replace")
                said.extend(line.strip() for line in text.splitlines() if line.strip())
    finally:
        os.close(saved)


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: the chunks that say how a PNG's values are encoded (``transfer_of``)
_COLOUR_CHUNKS = (b"cICP", b"iCCP", b"sRGB", b"gAMA")
#: colour type -> channels, and the bit depths allowed for it (the PNG specification, 11.2.2)
_PNG_COLOUR = {0: (1, (1, 2, 4, 8, 16)), 2: (3, (8, 16)), 3: (1, (1, 2, 4, 8)),
               4: (2, (8, 16)), 6: (4, (8, 16))}


def check_png(data: bytes) -> dict:
    """Refuse (``Unreadable``) a PNG that libpng would fail on: a bad signature, a chunk
    running past the end or failing its CRC, no IHDR first, no IEND, or image data that
    does not inflate to exactly the rows the header describes.  Inflating is bounded by
    that size.  Returns its colour chunks (cICP, iCCP, sRGB, gAMA: type -> body, the first
    of each before the image data, where the specification puts them)."""
    if not data.startswith(_PNG_SIGNATURE):
        raise Unreadable("not a PNG file")
    at, chunks, idat, colour_chunks = len(_PNG_SIGNATURE), [], [], {}
    while True:
        if at + 12 > len(data):
            raise Unreadable(f"truncated: a chunk header at byte {at} runs past the end")
        length, kind = struct.unpack_from(">I4s", data, at)
        if at + 12 + length > len(data):
            raise Unreadable(f"truncated: chunk {kind.decode('latin-1')!r} at byte {at} runs "
                             "past the end")
        body = data[at + 8:at + 8 + length]
        (crc,) = struct.unpack_from(">I", data, at + 8 + length)
        if zlib.crc32(kind + body) != crc:
            raise Unreadable(f"chunk {kind.decode('latin-1')!r} at byte {at} fails its CRC")
        chunks.append(kind)
        if kind == b"IDAT":
            idat.append(body)
        elif kind in _COLOUR_CHUNKS and not idat:
            colour_chunks.setdefault(kind, body)
        elif kind == b"IHDR":
            if len(chunks) != 1 or length != 13:
                raise Unreadable("malformed IHDR chunk")
            width, height, depth, colour, method, filtering, interlace = \
                struct.unpack(">IIBBBBB", body)
        at += 12 + length
        if kind == b"IEND":
            break
    if chunks[0] != b"IHDR":
        raise Unreadable("the first chunk is not IHDR")
    if colour not in _PNG_COLOUR or depth not in _PNG_COLOUR[colour][1] or method or filtering \
            or interlace > 1 or not width or not height:
        raise Unreadable(f"unsupported IHDR ({width}x{height}, colour type {colour}, depth "
                         f"{depth}, interlace {interlace})")
    if not idat:
        raise Unreadable("no image data (IDAT)")
    bits = _PNG_COLOUR[colour][0] * depth
    passes = [(0, 0, 1, 1)] if not interlace else \
        [(0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2),
         (0, 1, 1, 2)]
    expected = 0
    for x0, y0, dx, dy in passes:
        w, h = (width - x0 + dx - 1) // dx, (height - y0 + dy - 1) // dy
        if w > 0 and h > 0:
            expected += h * (1 + (w * bits + 7) // 8)
    inflate, got = zlib.decompressobj(), 0
    try:
        for piece in idat:
            while piece:
                got += len(inflate.decompress(piece, 1 << 20))
                piece = inflate.unconsumed_tail
                if got > expected:
                    raise Unreadable(f"its image data inflates to more than the {expected} "
                                     "bytes its header describes")
        got += len(inflate.flush())
    except zlib.error as exc:
        raise Unreadable(f"corrupt image data ({exc})") from None
    if got != expected or not inflate.eof:
        raise Unreadable(f"truncated image data: {got} of {expected} bytes")
    return colour_chunks
