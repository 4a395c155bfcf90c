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

The reader beside the writers: ``read`` (any image's channels as a ``Table``), on
``read_pixels`` / ``read_size``, which check a PNG's bytes before libpng sees them, bound
the pixels by the file's size and keep the image library's own complaints off the terminal
(``quiet_stderr``).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import struct
import sys
import tempfile
import threading
import zlib
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
    """An image (EXR, PNG, TIFF) as a ``Table`` (``naming`` 'exr'): every channel as (H, W)
    float (integer files scaled to [0, 1]), alpha unassociated (coverage is not opacity),
    the first subimage; aobake's metadata attribute (TIFF: its ImageDescription) as the
    metadata.  Raises ``Unreadable``."""
    pixels, names, attrs = read_pixels(path)
    columns = {name: pixels[:, :, i] for i, name in enumerate(names)}
    metadata = {}
    for attr in ("aobake:metadata", "ImageDescription"):  # TIFF keeps only the description
        text = attrs.get(attr)
        if not isinstance(text, str):
            continue
        try:
            candidate = parse_json(text)
        except Unreadable:  # a description that is not aobake's metadata
            continue
        if isinstance(candidate, dict) and "config" in candidate:
            metadata = candidate
            break
    return Table(columns, "exr", metadata=metadata)


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


def read_pixels(path) -> tuple[np.ndarray, list[str], dict]:
    """The first subimage through OpenImageIO, alpha unassociated (colour is not multiplied by
    alpha; in aobake's files alpha is coverage, not opacity).

    Returns (pixels (H, W, C) float32, channel names, attributes).  Float files come back as
    stored; integer files in OIIO's normalised scale, x / (2**bits - 1).  The attributes are
    the file's, plus 'oiio:format' (e.g. 'uint8', 'half') and 'oiio:channelformats' (the
    per-channel formats of a mixed file; [] when uniform).
    """
    import OpenImageIO as oiio

    with open(path, "rb") as handle:
        head = handle.read(len(_PNG_SIGNATURE))
        size = os.fstat(handle.fileno()).st_size
        if head == _PNG_SIGNATURE:  # libpng reports a broken file on stderr itself: check first
            handle.seek(0)
            check_png(handle.read())
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    with quiet_stderr() as said:
        inp = oiio.ImageInput.open(str(path), config)
        if inp is None:
            raise Unreadable(oiio.geterror() or "OpenImageIO cannot open it")
        try:
            spec = inp.spec()
            need = spec.width * spec.height * max(spec.nchannels, 1) * 4
            if need > max(_IMAGE_FLOOR, _IMAGE_RATIO * size):
                raise Unreadable(f"its header claims {spec.width}x{spec.height} pixels of "
                                 f"{spec.nchannels} channels ({need} bytes as float) from "
                                 f"{size} bytes")
            pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
            if pixels is None:
                raise Unreadable(inp.geterror() or "cannot read its pixels")
            attrs = {p.name: p.value for p in spec.extra_attribs}
            attrs["oiio:format"] = str(spec.format)
            attrs["oiio:channelformats"] = [str(f) for f in spec.channelformats]
            names = list(spec.channelnames)
        finally:
            inp.close()
    if said:
        log.debug("%s: the image library said: %s", path, " ".join(said))
    pixels = np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
    return pixels, names, attrs


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
#: colour type -> channels, and the bit depths allowed for it (the PNG specification, 11.2.2)
_PNG_COLOUR = {0: (1, (1, 2, 4, 8, 16)), 2: (3, (8, 16)), 3: (1, (1, 2, 4, 8)),
               4: (2, (8, 16)), 6: (4, (8, 16))}


def check_png(data: bytes) -> None:
    """Refuse (``Unreadable``) a PNG that libpng would fail on: a bad signature, a chunk
    running past the end or failing its CRC, no IHDR first, no IEND, or image data that
    does not inflate to exactly the rows the header describes.  Inflating is bounded by
    that size."""
    if not data.startswith(_PNG_SIGNATURE):
        raise Unreadable("not a PNG file")
    at, chunks, idat = len(_PNG_SIGNATURE), [], []
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
