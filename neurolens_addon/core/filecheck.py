"""Reading back a file just written, before it may replace the old one (core.atomic).

A writer can fail without saying so: Blender's image writer on a nearly full disk logs an
error, returns normally and leaves a truncated PNG or OpenEXR file, which renaming into place
would put over a good frame. So every image written is read back first, streaming, with pure
Python (zlib and struct: no bpy, so the core's writers use it too, and nothing the size of the
decoded image is held in memory):

  PNG      the signature, every chunk's length and CRC up to IEND, IHDR first, and the image
           data inflated completely: exactly the bytes IHDR's size, colour type, bit depth
           and interlacing call for, and zlib's own Adler-32 check of them.
  OpenEXR  the magic number and version, every header (single and multi-part), the offset
           table complete, each chunk where the table says, of the part, line or tile the
           table says, whole inside the file; chunks stored uncompressed or with ZIP / ZIPS
           (Blender's default) inflated to exactly the bytes their lines or tile hold (other
           codecs: their size within that).
  .npy     the header read by numpy and the file exactly as long as the array it declares.

`check_file(path)` picks the check by the file's suffix (other formats: nothing to check
beyond what core.atomic does); problems raise FileCheckError (a ValueError) whose text says
what is wrong, without the path (core.atomic names the file the user asked for).
"""

from __future__ import annotations

import os
import struct
import zlib

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
EXR_MAGIC = b"\x76\x2f\x31\x01"

#: read pieces of this size: the checks stream, whatever the image's size
_PIECE = 1 << 20


class FileCheckError(ValueError):
    """The file does not read back as what it claims to be (the text says why)."""


def check_file(path, suffix: str | None = None):
    """Check `path` as the format its suffix (or `suffix`) names; what the check returns
    (a PNG's or OpenEXR's (width, height), a .npy array's shape), None for other formats."""
    ext = (suffix if suffix is not None else os.path.splitext(str(path))[1]).lower()
    check = {".png": check_png, ".exr": check_exr, ".npy": check_npy}.get(ext)
    return None if check is None else check(path)


def _read_exact(fh, n: int, what: str) -> bytes:
    data = fh.read(n)
    if len(data) != n:
        raise FileCheckError(f"cut short inside {what}")
    return data


# ---------------------------------------------------------------------------------------- PNG

#: channels of each PNG colour type
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
#: Adam7's passes: (x0, y0, dx, dy)
_ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2),
          (0, 1, 1, 2))


def _png_data_size(w: int, h: int, bits_per_pixel: int, interlaced: bool) -> int:
    """Bytes of filtered image data (a filter byte per row) the image's IDAT must inflate to."""
    def rows(width, height):
        return 0 if width <= 0 or height <= 0 else height * (1 + (width * bits_per_pixel + 7) // 8)
    if not interlaced:
        return rows(w, h)
    return sum(rows(-(-(w - x0) // dx), -(-(h - y0) // dy)) for x0, y0, dx, dy in _ADAM7)


def check_png(path) -> tuple[int, int]:
    """(width, height) of a PNG that reads back completely, else FileCheckError."""
    with open(path, "rb") as fh:
        if fh.read(8) != PNG_SIGNATURE:
            raise FileCheckError("not a PNG file (no PNG signature)")
        size = None
        inflate = zlib.decompressobj()
        inflated = 0
        first = True
        while True:
            length, kind = struct.unpack(">I4s", _read_exact(fh, 8, "a chunk header"))
            if length > 0x7FFFFFFF:
                raise FileCheckError(f"a {kind!r} chunk claims {length} bytes")
            if first and kind != b"IHDR":
                raise FileCheckError("the first chunk is not IHDR")
            crc = zlib.crc32(kind)
            body = b""
            left = length
            while left:
                piece = _read_exact(fh, min(left, _PIECE), f"the {kind.decode('latin-1')} chunk")
                left -= len(piece)
                crc = zlib.crc32(piece, crc)
                if kind == b"IDAT":
                    inflated += _inflate(inflate, piece)
                elif kind == b"IHDR":
                    body += piece
            if struct.unpack(">I", _read_exact(fh, 4, "a chunk's CRC"))[0] != crc & 0xFFFFFFFF:
                raise FileCheckError(f"the {kind.decode('latin-1')} chunk's CRC does not match "
                                     "its data")
            if kind == b"IHDR":
                if not first or length != 13:
                    raise FileCheckError("a malformed IHDR chunk")
                w, h, depth, colour, _comp, _filt, interlace = struct.unpack(">IIBBBBB", body)
                if not (0 < w < 1 << 31 and 0 < h < 1 << 31) or colour not in _PNG_CHANNELS \
                        or depth not in (1, 2, 4, 8, 16) or interlace not in (0, 1):
                    raise FileCheckError(f"IHDR describes no valid image ({w} x {h}, colour "
                                         f"type {colour}, depth {depth})")
                size = (w, h)
                expected = _png_data_size(w, h, _PNG_CHANNELS[colour] * depth, interlace == 1)
            first = False
            if kind == b"IEND":
                break
    if not inflate.eof:
        raise FileCheckError(f"the image data stops after {inflated} of {expected} bytes")
    if inflated != expected:
        raise FileCheckError(f"the image data holds {inflated} bytes, {size[0]} x {size[1]} "
                             f"needs {expected}")
    return size


def _inflate(inflate, data: bytes, limit: int = 1 << 62) -> int:
    """Feed `data` to a zlib decompressor; the bytes it gave (in bounded pieces: a small
    compressed stream may stand for a very large image)."""
    n = 0
    try:
        while data:
            if inflate.eof:
                raise FileCheckError("data after the end of the compressed stream")
            n += len(inflate.decompress(data, _PIECE))
            data = inflate.unconsumed_tail
            if n > limit:
                break
    except zlib.error as exc:
        raise FileCheckError(f"the compressed image data is corrupt ({exc})") from None
    return n


# ------------------------------------------------------------------------------------ OpenEXR

_EXR_TILED, _EXR_LONG_NAMES, _EXR_DEEP, _EXR_MULTIPART = 0x200, 0x400, 0x800, 0x1000
#: scan lines a chunk holds, per compression (OpenEXR's Compression enum)
_EXR_LINES = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256, 10: 256,
              11: 32, 12: 256, 13: 1}
_EXR_NONE, _EXR_ZIPS, _EXR_ZIP = 0, 2, 3
#: bytes per sample of UINT, HALF, FLOAT
_EXR_SAMPLE_BYTES = {0: 4, 1: 2, 2: 4}


def _exr_name(fh, longest: int, what: str) -> bytes:
    """A NUL-terminated name (b"" for the NUL alone that ends a list)."""
    out = bytearray()
    while True:
        c = _read_exact(fh, 1, what)
        if c == b"\0":
            return bytes(out)
        out += c
        if len(out) > longest:
            raise FileCheckError(f"{what}: a name longer than {longest} bytes")


def _exr_channels(value: bytes) -> list[tuple[int, int, int]]:
    """(pixel type, x sampling, y sampling) of each channel of a chlist attribute."""
    out, pos = [], 0
    while True:
        end = value.find(b"\0", pos)
        if end < 0:
            raise FileCheckError("a malformed channel list")
        if end == pos:
            return out
        if end + 1 + 16 > len(value):
            raise FileCheckError("a malformed channel list")
        ptype, _linear, xs, ys = struct.unpack_from("<iB3xii", value, end + 1)
        if ptype not in _EXR_SAMPLE_BYTES or xs < 1 or ys < 1:
            raise FileCheckError(f"channel {value[pos:end]!r}: pixel type {ptype}, sampling "
                                 f"{xs} x {ys}")
        out.append((ptype, xs, ys))
        pos = end + 17


def _exr_header(fh, longest: int, file_size: int) -> dict:
    """One header's attributes {name: (type, value bytes)}; {} for the empty header that ends
    a multi-part file's list."""
    attrs = {}
    while True:
        name = _exr_name(fh, longest, "the header")
        if not name:
            return attrs
        kind = _exr_name(fh, longest, "the header")
        (n,) = struct.unpack("<i", _read_exact(fh, 4, "the header"))
        if not 0 <= n <= file_size:
            raise FileCheckError(f"attribute {name!r} claims {n} bytes")
        attrs[name.decode("latin-1")] = (kind, _read_exact(fh, n, "the header"))


def _count_multiples(a: int, b: int, s: int) -> int:
    """How many integers in [a, b] are multiples of s (a channel's sampled rows or columns)."""
    return b // s - (a - 1) // s


class _ExrPart:
    """What the checks need of one part's header."""

    def __init__(self, attrs: dict, version_flags: int, multipart: bool):
        def need(name):
            if name not in attrs:
                raise FileCheckError(f"the header has no '{name}' attribute")
            return attrs[name][1]
        if len(need("dataWindow")) != 16:
            raise FileCheckError("a malformed dataWindow")
        self.x0, self.y0, self.x1, self.y1 = struct.unpack("<4i", need("dataWindow"))
        if self.x1 < self.x0 or self.y1 < self.y0:
            raise FileCheckError("an empty dataWindow")
        if len(need("compression")) != 1:
            raise FileCheckError("a malformed compression attribute")
        self.compression = need("compression")[0]
        self.channels = _exr_channels(need("channels"))
        kind = attrs.get("type", (b"", b""))[1].rstrip(b"\0").decode("latin-1")
        if multipart and not kind:
            raise FileCheckError("a part without a 'type' attribute")
        self.tiled = "tile" in kind if kind else bool(version_flags & _EXR_TILED)
        self.deep = kind.startswith("deep") if kind else bool(version_flags & _EXR_DEEP)
        self.tile = None
        if self.tiled:
            tiles = need("tiles")
            if len(tiles) != 9:
                raise FileCheckError("a malformed tiles attribute")
            tx, ty, mode = struct.unpack("<IIB", tiles)
            if tx < 1 or ty < 1 or (mode & 0xF) > 2:
                raise FileCheckError(f"tiles of {tx} x {ty}, level mode {mode & 0xF}")
            self.tile = (tx, ty, mode & 0xF, mode >> 4)
        if "chunkCount" in attrs:
            (self.chunks,) = struct.unpack("<i", attrs["chunkCount"][1][:4].ljust(4, b"\0"))
        elif multipart:
            raise FileCheckError("a part without a 'chunkCount' attribute")
        elif self.tiled:
            self.chunks = sum(self._tiles_x(lx) * self._tiles_y(ly) for lx, ly in self.levels())
        elif self.compression in _EXR_LINES:
            self.chunks = -(-(self.y1 - self.y0 + 1) // _EXR_LINES[self.compression])
        else:
            self.chunks = None          # a codec newer than this table: see check_exr
        if self.chunks is not None and self.chunks < 0:
            raise FileCheckError(f"chunkCount {self.chunks}")

    # tiled parts: the levels of a mip- or rip-map and their tiles
    def _level_count(self, n: int) -> int:
        up = self.tile[3] == 1
        k = max(n.bit_length() - 1, 0)             # floor(log2 n)
        return k + 1 + (1 if up and (1 << k) < n else 0)

    def _level_size(self, n: int, level: int) -> int:
        up = self.tile[3] == 1
        return max(1, (n + (1 << level) - 1 if up else n) >> level)

    def levels(self):
        w, h = self.x1 - self.x0 + 1, self.y1 - self.y0 + 1
        mode = self.tile[2]
        if mode == 0:
            return [(0, 0)]
        if mode == 1:
            return [(k, k) for k in range(self._level_count(max(w, h)))]
        return [(i, j) for j in range(self._level_count(h)) for i in range(self._level_count(w))]

    def _tiles_x(self, lx: int) -> int:
        return -(-self._level_size(self.x1 - self.x0 + 1, lx) // self.tile[0])

    def _tiles_y(self, ly: int) -> int:
        return -(-self._level_size(self.y1 - self.y0 + 1, ly) // self.tile[1])

    def line_bytes(self, y0: int, y1: int) -> int:
        """Bytes of the scan lines y0..y1 of every channel, uncompressed."""
        return sum(_count_multiples(self.x0, self.x1, xs) * _count_multiples(y0, y1, ys)
                   * _EXR_SAMPLE_BYTES[ptype] for ptype, xs, ys in self.channels)

    def tile_bytes(self, tx: int, ty: int, lx: int, ly: int) -> int:
        """Bytes of tile (tx, ty) of level (lx, ly), every channel, uncompressed (the tiles at
        the right and bottom edges are cut by the level's size)."""
        w = self._level_size(self.x1 - self.x0 + 1, lx)
        h = self._level_size(self.y1 - self.y0 + 1, ly)
        tw = min(self.tile[0], w - tx * self.tile[0])
        th = min(self.tile[1], h - ty * self.tile[1])
        return tw * th * sum(_EXR_SAMPLE_BYTES[p] for p, _x, _y in self.channels)


def check_exr(path) -> tuple[int, int]:
    """(width, height) of the first part of an OpenEXR file whose headers, offset tables and
    chunks are all complete (and whose ZIP / uncompressed scan lines inflate to their size),
    else FileCheckError."""
    file_size = os.path.getsize(path)
    with open(path, "rb") as fh:
        if fh.read(4) != EXR_MAGIC:
            raise FileCheckError("not an OpenEXR file (no OpenEXR magic number)")
        (version,) = struct.unpack("<I", _read_exact(fh, 4, "the version field"))
        if version & 0xFF != 2:
            raise FileCheckError(f"OpenEXR version {version & 0xFF} (expected 2)")
        multipart = bool(version & _EXR_MULTIPART)
        longest = 255 if version & _EXR_LONG_NAMES else 31
        parts = []
        while True:
            attrs = _exr_header(fh, longest, file_size)
            if not attrs:
                if not parts:
                    raise FileCheckError("an empty header")
                break
            parts.append(_ExrPart(attrs, version, multipart))
            if not multipart:
                break
        tables = []
        for part in parts:
            if part.chunks is None:
                # a single part in a codec this module does not know: its table ends where the
                # first chunk begins, which in increasing-y order (Blender's) is the first entry
                (first,) = struct.unpack("<Q", _read_exact(fh, 8, "the offset table"))
                fh.seek(-8, os.SEEK_CUR)
                part.chunks = (first - fh.tell()) // 8
                if part.chunks < 1:
                    raise FileCheckError("a malformed offset table")
            if part.chunks * 8 > file_size:
                raise FileCheckError(f"an offset table of {part.chunks} chunks in a "
                                     f"{file_size}-byte file: cut short")
            raw = _read_exact(fh, 8 * part.chunks, "the offset table")
            tables.append(struct.unpack(f"<{part.chunks}Q", raw))
        start = fh.tell()
        for number, (part, table) in enumerate(zip(parts, tables)):
            for k, offset in enumerate(table):
                if not start <= offset < file_size:
                    raise FileCheckError(f"chunk {k} of part {number} lies outside the "
                                         f"{file_size}-byte file: cut short")
                fh.seek(offset)
                if multipart:
                    (p,) = struct.unpack("<i", _read_exact(fh, 4, f"chunk {k}"))
                    if p != number:
                        raise FileCheckError(f"chunk {k} of part {number} is marked part {p}")
                _exr_chunk(fh, part, k, file_size)
    first = parts[0]
    return first.x1 - first.x0 + 1, first.y1 - first.y0 + 1


def _exr_chunk(fh, part: _ExrPart, k: int, file_size: int) -> None:
    """Check chunk `k` of `part`, read from just after its part number."""
    where = f"chunk {k}"
    if part.tiled:
        tx, ty, lx, ly = struct.unpack("<4i", _read_exact(fh, 16, where))
        levels = part.levels()
        if (lx, ly) not in levels or not (0 <= tx < part._tiles_x(lx)
                                          and 0 <= ty < part._tiles_y(ly)):
            raise FileCheckError(f"{where}: tile ({tx}, {ty}) of level ({lx}, {ly}) is not "
                                 "in the image")
        raw = part.tile_bytes(tx, ty, lx, ly)
    else:
        (y,) = struct.unpack("<i", _read_exact(fh, 4, where))
        lines = _EXR_LINES.get(part.compression)
        if lines is not None and not part.deep:
            if y != part.y0 + k * lines:
                raise FileCheckError(f"{where} holds line {y}, expected {part.y0 + k * lines}")
        elif not part.y0 <= y <= part.y1:
            raise FileCheckError(f"{where} holds line {y}, outside the image")
        raw = None if lines is None else part.line_bytes(y, min(y + lines - 1, part.y1))
    if part.deep:
        table, packed, _unpacked = struct.unpack("<3q", _read_exact(fh, 24, where))
        if table < 0 or packed < 0 or fh.tell() + table + packed > file_size:
            raise FileCheckError(f"{where} runs past the end of the file: cut short")
        return
    (n,) = struct.unpack("<i", _read_exact(fh, 4, where))
    if n <= 0 or fh.tell() + n > file_size:
        raise FileCheckError(f"{where} runs past the end of the file: cut short")
    if raw is None:
        return
    # OpenEXR stores a chunk uncompressed whenever compressing would not make it smaller
    if n > raw or (part.compression == _EXR_NONE and n != raw):
        raise FileCheckError(f"{where} holds {n} bytes, its lines {raw}")
    if part.compression in (_EXR_ZIP, _EXR_ZIPS) and n < raw:
        inflate = zlib.decompressobj()
        got = 0
        left = n
        while left:
            piece = _read_exact(fh, min(left, _PIECE), where)
            left -= len(piece)
            got += _inflate(inflate, piece, raw)
            if got > raw:
                break
        if not inflate.eof or got != raw:
            raise FileCheckError(f"{where} inflates to {got} bytes, its lines hold {raw}")


# ---------------------------------------------------------------------------------------- npy

def npy_header(fh) -> tuple[tuple[int, ...], object, int]:
    """(shape, dtype, offset of the data) of the .npy file open as `fh`; ValueError if its
    header is not one numpy reads (formats 1.0 and 2.0)."""
    import numpy as np
    version = np.lib.format.read_magic(fh)
    read = {(1, 0): np.lib.format.read_array_header_1_0,
            (2, 0): np.lib.format.read_array_header_2_0}.get(version)
    if read is None:
        raise ValueError(f".npy format version {version} is not supported")
    shape, _fortran, dtype = read(fh)
    return tuple(shape), dtype, fh.tell()


def check_npy(path) -> tuple[int, ...]:
    """The shape of a .npy array file exactly as long as its header says, else
    FileCheckError."""
    try:
        with open(path, "rb") as fh:
            shape, dtype, offset = npy_header(fh)
    except ValueError as exc:
        raise FileCheckError(f"not a readable .npy header ({exc})") from None
    if dtype.hasobject:
        raise FileCheckError("an array of Python objects")
    count = 1
    for n in shape:
        count *= n
    need = offset + count * dtype.itemsize
    size = os.path.getsize(path)
    if size != need:
        raise FileCheckError(f"{size} bytes, the array it declares needs {need}")
    return tuple(shape)
