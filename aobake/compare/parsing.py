"""What NPZ, PLY, GLB and image files hold, as stored: the byte-level parsing, done once.

``readers`` turns these into compare's table, ``aobake.refit`` reads its NPZ with
``read_npz``; ``tests/readers.py`` reads aobake's own outputs back with the same functions
(``strict=True`` where the tests refuse what aobake never writes but compare tolerates in
another tool's file).  Every malformation raises ``Unreadable`` (a ``ValueError``) with the
reason, without the file name.

What a reader allocates is bounded by what the file holds: a header's count (a PLY element,
a glTF accessor, an NPZ array's shape, an image's size) is checked against the bytes that
would hold it before anything of that size is made, so a file of a few bytes claiming
terabytes is refused, not attempted.  JSON nested beyond any real metadata is refused
(``parse_json``), and the libraries' own complaints (libpng's) never reach the terminal.
"""

from __future__ import annotations

import contextlib
import logging
import os
import struct
import sys
import tempfile
import tokenize
import zipfile
import zlib
from dataclasses import dataclass, field

import numpy as np

from aobake.outputs import gltf
from aobake.outputs.table import Unreadable, parse_json

log = logging.getLogger(__name__)

PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


# ---------------------------------------------------------------------------------------------
# NPZ

#: the most bytes one byte of deflate data can expand to (deflate's limit is 1032)
_DEFLATE_RATIO = 1040


def read_npz(path, names=None) -> dict:
    """Arrays of an NPZ archive (``np.savez``'s format): {name: array} for ``names`` (None:
    all; names it does not hold are left out), never unpickled.  Each array's size is
    checked against the bytes the archive holds for it before it is allocated.  Raises
    ``Unreadable`` for anything malformed (OSError for a file that cannot be opened)."""
    with _npz_errors():
        with zipfile.ZipFile(path) as archive:
            members = npz_members(archive)
            wanted = members if names is None else [n for n in names if n in members]
            return {name: npz_array(archive, name) for name in wanted}


def npz_names(path) -> list:
    """The array names of an NPZ archive.  Raises ``Unreadable`` (OSError: cannot open)."""
    with _npz_errors():
        with zipfile.ZipFile(path) as archive:
            return npz_members(archive)


@contextlib.contextmanager
def _npz_errors():
    """What zipfile and zlib raise on a malformed archive, as ``Unreadable``."""
    try:
        yield
    except zipfile.BadZipFile as exc:
        raise Unreadable(f"not an NPZ archive ({exc})") from None
    except zlib.error as exc:
        raise Unreadable(f"corrupt compressed data ({exc})") from None
    except NotImplementedError as exc:  # zipfile: an unknown version or feature
        raise Unreadable(f"not an NPZ archive np.savez writes ({exc})") from None
    except (EOFError, struct.error):
        raise Unreadable("truncated archive") from None


def npz_members(archive: zipfile.ZipFile) -> list:
    """The array names of an open NPZ archive (its ``.npy`` members, without the suffix)."""
    return [info.filename[:-4] for info in archive.infolist() if info.filename.endswith(".npy")]


def npz_array(archive: zipfile.ZipFile, name: str) -> np.ndarray:
    """Array ``name`` of an open NPZ archive, its header checked first: no Python objects,
    and no more bytes than the member holds (itself at most what its compressed bytes can
    expand to)."""
    info = archive.getinfo(name + ".npy")
    if info.flag_bits & 0x1:
        raise Unreadable(f"array {name!r} is encrypted (np.savez never encrypts)")
    if info.compress_type == zipfile.ZIP_STORED:
        if info.file_size != info.compress_size:
            raise Unreadable(f"array {name!r}: the archive's sizes disagree")
    elif info.compress_type == zipfile.ZIP_DEFLATED:
        if info.file_size > info.compress_size * _DEFLATE_RATIO + 1024:
            raise Unreadable(f"array {name!r}: claims {info.file_size} bytes from "
                             f"{info.compress_size} compressed ones (more than deflate makes)")
    else:
        raise Unreadable(f"array {name!r}: compression method {info.compress_type} "
                         "(np.savez writes stored or deflated members)")
    with archive.open(info) as member:
        try:
            version = np.lib.format.read_magic(member)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(member)
            elif version == (2, 0):
                shape, _, dtype = np.lib.format.read_array_header_2_0(member)
            else:
                raise Unreadable(f"array {name!r}: .npy format version {version} not read")
        except (ValueError, SyntaxError, RecursionError, tokenize.TokenError) as exc:
            if isinstance(exc, Unreadable):
                raise
            raise Unreadable(f"array {name!r}: malformed .npy header ({' '.join(str(exc).split())})"
                             ) from None
        if dtype.hasobject:
            raise Unreadable(f"array {name!r} holds Python objects (never unpickled)")
        count = 1
        for extent in shape:
            count *= int(extent)
        if count * dtype.itemsize > info.file_size:
            raise Unreadable(f"array {name!r}: its header claims {shape} of {dtype}, "
                             f"{count * dtype.itemsize} bytes, but the archive holds "
                             f"{info.file_size} for it")
    with archive.open(info) as member:
        try:
            return np.lib.format.read_array(member, allow_pickle=False)
        except ValueError as exc:  # e.g. "EOF: reading array data"
            raise Unreadable(f"array {name!r}: {' '.join(str(exc).split())}") from None


# ---------------------------------------------------------------------------------------------
# PLY


@dataclass
class Ply:
    """A PLY file as stored.

    format : 'ascii' | 'binary_little_endian' | 'binary_big_endian'
    elements : the header's (name, count, props) in file order; a prop is (name, dtype) for a
      scalar, (name, count dtype, item dtype) for a list (dtypes as in ``PLY_TYPES``)
    vertex : (n,) structured array, one field per vertex property in file order (binary: in
      the file's byte order)
    faces : (f, 3) int64 of the face element's first list, or None (no face element, not all
      triangles, or truncated after the vertices)
    metadata : the ``comment aobake-metadata`` line's JSON as parsed (not checked to be a
      dict), {} without one
    """

    format: str
    elements: list
    vertex: np.ndarray
    faces: np.ndarray | None = None
    metadata: object = field(default_factory=dict)


def parse_ply(data: bytes) -> Ply:
    """PLY in any of its three formats: the header, every vertex property, the triangles."""
    from aobake.outputs.ply import METADATA_COMMENT

    if not data.startswith(b"ply"):
        raise Unreadable("not a PLY file (no 'ply' line)")
    end = data.find(b"end_header")
    if end < 0:
        raise Unreadable("no end_header")
    newline = data.find(b"\n", end)
    if newline < 0:
        raise Unreadable("truncated after end_header")
    body = newline + 1
    fmt, metadata, elements = None, {}, []
    for line in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        words = line.split()
        if not words:
            continue
        if words[0] == "format":
            fmt = words[1] if len(words) > 1 else None
        elif words[0] == "comment" and words[1:2] == [METADATA_COMMENT]:
            text = line.split(None, 2)[2] if len(words) > 2 else ""
            metadata = parse_json(text, f"its {METADATA_COMMENT} comment")
        elif words[0] == "element":
            if len(words) != 3:
                raise Unreadable(f"malformed header line {line.strip()!r}")
            elements.append((words[1], _ply_count(words[1], words[2], len(data)), []))
        elif words[0] == "property":
            if not elements:
                raise Unreadable("a property before any element")
            if len(words) != (5 if words[1:2] == ["list"] else 3):
                raise Unreadable(f"malformed header line {line.strip()!r}")
            if words[1] == "list":
                elements[-1][2].append((words[4], _ply_type(words[2]), _ply_type(words[3])))
            else:
                elements[-1][2].append((words[2], _ply_type(words[1])))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise Unreadable(f"unknown format {fmt!r}")
    parsed = _ply_ascii(data[body:], elements) if fmt == "ascii" else \
        _ply_binary(data, body, elements, "<" if fmt == "binary_little_endian" else ">")
    if "vertex" not in parsed:
        raise Unreadable("no vertex element")
    return Ply(fmt, elements, parsed["vertex"], parsed.get("face"), metadata)


def _ply_count(name: str, text: str, size: int) -> int:
    """An element's count: a whole number, at most the file's size in bytes (every item
    takes at least one byte), so nothing is allocated beyond what the file holds."""
    try:
        count = int(text)
    except ValueError:
        raise Unreadable(f"element {name!r} has count {text!r}, not a number") from None
    if count < 0 or count > size:
        raise Unreadable(f"element {name!r} claims {count} items in a file of {size} bytes")
    return count


def _ply_type(name: str) -> str:
    if name not in PLY_TYPES:
        raise Unreadable(f"unknown property type {name!r}")
    return PLY_TYPES[name]


def _ply_binary(data: bytes, offset: int, elements, order: str) -> dict:
    """{'vertex': structured (n,), 'face': (f, 3) int64} as far as they can be read (a face
    list that is not all triangles ends the reading: later elements cannot be located)."""
    out = {}
    for name, count, props in elements:
        dtype = []
        for prop in props:
            if len(prop) == 2:
                dtype.append((prop[0], order + prop[1]))
            else:  # a list, read as if of 3, then checked
                dtype += [(prop[0] + "#count", order + prop[1]), (prop[0], order + prop[2], (3,))]
        dtype = np.dtype(dtype)
        if offset + dtype.itemsize * count > len(data):
            lists = [p[0] for p in props if len(p) == 3]
            whole = max(len(data) - offset, 0) // dtype.itemsize  # the items the bytes hold
            head = np.frombuffer(data, dtype=dtype, count=whole, offset=offset) if whole \
                else None
            if lists and (head is None or any((head[p + "#count"] != 3).any() for p in lists)):
                break  # not all triangles: read as 3-lists, its true size is unknown here
            # the vertex element, or a triangle list, that ends before its count: a file cut
            # short (the faces cannot be dropped: the values would be read without them)
            raise Unreadable(f"truncated: element {name!r} runs past the end of the file "
                             f"({count} items declared, {whole} there)")
        array = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
        lists = [p[0] for p in props if len(p) == 3]
        if any((array[p + "#count"] != 3).any() for p in lists):
            break  # not all triangles: stop (the vertices were read first, or are not here)
        offset += array.nbytes
        if name == "vertex":
            out["vertex"] = array
        elif name == "face" and lists:
            out["face"] = array[lists[0]].astype(np.int64)
        if "vertex" in out and "face" in out:
            break
    return out


def _ply_ascii(body: bytes, elements) -> dict:
    """The ASCII layout, read as one stream of tokens (line breaks do not matter)."""
    tokens = body.decode("ascii").split()
    out, at = {}, 0
    for name, count, props in elements:
        lists = [i for i, p in enumerate(props) if len(p) == 3]
        width = len(props) + 3 * len(lists)  # every list assumed to hold 3 (checked)
        chunk = tokens[at:at + width * count]
        if len(chunk) < width * count:
            whole = len(chunk) // width
            counts = np.array(chunk[:whole * width], dtype=object).reshape(whole, width)
            counts = counts[:, _lists_at(props)].astype(np.float64)
            if (counts != 3).any():
                break  # not all triangles: read as 3-lists, its true length is unknown here
            raise Unreadable(f"truncated: element {name!r} runs past the end of the file "
                             f"({count} items declared, {whole} there)")
        table = np.array(chunk, dtype=np.float64).reshape(count, width)
        columns, col = {}, 0
        for prop in props:
            if len(prop) == 2:
                columns[prop[0]] = _ascii_column(prop[0], table[:, col], prop[1])
                col += 1
            else:
                if (table[:, col] != 3).any():
                    return out  # not all triangles
                columns[prop[0]] = table[:, col + 1:col + 4].astype(np.int64)
                col += 4
        at += width * count
        if name == "vertex":
            vertex = np.empty(count, dtype=[(p[0], p[1]) for p in props if len(p) == 2])
            for key in vertex.dtype.names:
                vertex[key] = columns[key]
            out["vertex"] = vertex
        elif name == "face" and lists:
            out["face"] = columns[props[lists[0]][0]]
        if "vertex" in out and "face" in out:
            break
    return out


def _lists_at(props) -> list:
    """The token offsets of the list counts in one row of ``props``, every list read as
    holding 3 (``_ply_ascii``'s layout)."""
    at, out = 0, []
    for prop in props:
        if len(prop) == 3:
            out.append(at)
            at += 4
        else:
            at += 1
    return out


def _ascii_column(name: str, values: np.ndarray, dtype: str) -> np.ndarray:
    """A text column in its declared type: an integer type's values must be whole numbers
    within its range (a cast would wrap them silently)."""
    dtype = np.dtype(dtype)
    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        bad = ~((values >= info.min) & (values <= info.max) & (values == np.floor(values)))
        if bad.any():
            raise Unreadable(f"property {name!r}: {values[bad][0]:g} is not a {dtype} value")
        return values.astype(dtype)
    with np.errstate(over="ignore"):  # a float32 property beyond its range is inf, refused later
        return values.astype(dtype)


# ---------------------------------------------------------------------------------------------
# GLB


def parse_glb(data: bytes, *, strict: bool = False) -> tuple[dict, bytes]:
    """The GLB container (``aobake.outputs.gltf.parse_glb``), b"" for no BIN chunk."""
    document, binary = gltf.parse_glb(data, strict=strict)
    return document, b"" if binary is None else binary


def glb_view(gltf_json: dict, binary: bytes, index: int) -> bytes:
    """Bytes of bufferView ``index`` (``aobake.outputs.gltf.view_bytes``)."""
    return gltf.view_bytes(gltf_json, binary, index)


def glb_accessor(gltf_json: dict, binary: bytes, index: int, *, strict: bool = False,
                 max_bytes: int | None = None) -> np.ndarray:
    """Accessor ``index`` as stored (``aobake.outputs.gltf.accessor_array``)."""
    return gltf.accessor_array(gltf_json, binary, index, strict=strict, max_bytes=max_bytes)


# ---------------------------------------------------------------------------------------------
# images


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
