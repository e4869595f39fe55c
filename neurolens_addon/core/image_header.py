"""The pixel size of an image file read from its header, before anything decodes it.

`image_size(f, name)` reads (width, height) from a binary file object, as each format's
specification places it:
  PNG        IHDR, the first chunk: width, height as big-endian uint32 at bytes 16 and 20
  JPEG       the first start-of-frame segment (SOF0-SOF15 but DHT, JPG, DAC): height, width
             as big-endian uint16 at its bytes 5 and 7; segments are walked by their lengths
  BMP        BITMAPINFOHEADER (or later): int32 little-endian at 18 and 22 (the height's sign
             is the row order); the old BITMAPCOREHEADER: uint16 at 18 and 20
  TIFF       the first image file directory: tags 256 (ImageWidth) and 257 (ImageLength),
             SHORT or LONG, in the file's byte order ("II" or "MM")
  WebP       RIFF/WEBP with a VP8X (24-bit width - 1, height - 1), VP8L (14-bit fields) or
             VP8 (14-bit fields after the key frame's start code) chunk
  OpenEXR    the header's dataWindow attribute (box2i: x_min, y_min, x_max, y_max int32):
             width = x_max - x_min + 1, height = y_max - y_min + 1
  Radiance   the resolution line after the header's blank line: "-Y H +X W" (or another of
  HDR        the eight orientations)
  SGI/Iris   magic 474, then xsize, ysize as big-endian uint16 at 6 and 8
  DPX        "SDPX" / "XPDS" (byte order), pixels per line and lines per element as uint32
             at 772 and 776
  Targa      no magic: a .tga / .tpic name whose header is plausible, width and height as
             little-endian uint16 at 12 and 14
Anything else: None (the caller decides; Pillow's lazy open reads only headers too). At most
HEADER_BYTES are read, and a JPEG's walk stops after MAX_SEGMENTS segments, so a hostile file
costs a bounded read. No image is decoded here.
"""

from __future__ import annotations

import struct

#: the most bytes read while looking for a size
HEADER_BYTES = 1 << 20
#: the most JPEG segments walked before its frame header
MAX_SEGMENTS = 4096


def _png(head: bytes):
    if head[:8] == b"\x89PNG\r\n\x1a\n" and len(head) >= 24 and head[12:16] == b"IHDR":
        return struct.unpack(">II", head[16:24])
    return None


def _jpeg(f):
    f.seek(2)
    for _ in range(MAX_SEGMENTS):
        b = f.read(1)
        while b == b"\xff":                    # fill bytes before a marker
            b = f.read(1)
        if not b:
            return None
        marker = b[0]
        if marker in (0x01, *range(0xD0, 0xD8)):        # standalone markers
            continue
        if marker == 0xD9 or marker == 0xDA:           # end of image, start of scan: no frame
            return None
        raw = f.read(2)
        if len(raw) < 2:
            return None
        length = struct.unpack(">H", raw)[0]
        if length < 2:
            return None
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            seg = f.read(5)
            if len(seg) < 5:
                return None
            h, w = struct.unpack(">HH", seg[1:5])
            return w, h
        f.seek(length - 2, 1)
    return None


def _bmp(head: bytes):
    if head[:2] != b"BM" or len(head) < 26:
        return None
    size = struct.unpack("<I", head[14:18])[0]
    if size == 12:
        return struct.unpack("<HH", head[18:22])
    w, h = struct.unpack("<ii", head[18:26])
    return abs(w), abs(h)


def _tiff(f, head: bytes):
    order = {b"II": "<", b"MM": ">"}.get(head[:2])
    if order is None or struct.unpack(order + "H", head[2:4])[0] != 42:
        return None
    f.seek(struct.unpack(order + "I", head[4:8])[0])
    raw = f.read(2)
    if len(raw) < 2:
        return None
    n = min(struct.unpack(order + "H", raw)[0], 4096)
    entries = f.read(12 * n)
    found = {}
    for i in range(len(entries) // 12):
        tag, kind, _count = struct.unpack(order + "HHI", entries[12 * i:12 * i + 8])
        if tag in (256, 257):
            value = entries[12 * i + 8:12 * i + 12]
            found[tag] = (struct.unpack(order + "H", value[:2])[0] if kind == 3
                          else struct.unpack(order + "I", value)[0])
    if 256 in found and 257 in found:
        return found[256], found[257]
    return None


def _webp(head: bytes):
    if head[:4] != b"RIFF" or head[8:12] != b"WEBP" or len(head) < 30:
        return None
    kind = head[12:16]
    if kind == b"VP8X":
        w = int.from_bytes(head[24:27], "little") + 1
        h = int.from_bytes(head[27:30], "little") + 1
        return w, h
    if kind == b"VP8L" and head[20] == 0x2F:
        bits = int.from_bytes(head[21:25], "little")
        return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    if kind == b"VP8 " and head[23:26] == b"\x9d\x01\x2a":
        w, h = struct.unpack("<HH", head[26:30])
        return w & 0x3FFF, h & 0x3FFF
    return None


def _exr(head: bytes):
    if head[:4] != b"\x76\x2f\x31\x01":
        return None
    i = 8
    while i < len(head):
        end = head.find(b"\0", i)
        if end < 0 or end == i:                 # the header's end (an empty name)
            return None
        name = head[i:end]
        kind_end = head.find(b"\0", end + 1)
        if kind_end < 0 or kind_end + 5 > len(head):
            return None
        size = struct.unpack("<i", head[kind_end + 1:kind_end + 5])[0]
        value = head[kind_end + 5:kind_end + 5 + size]
        if name == b"dataWindow" and len(value) == 16:
            x0, y0, x1, y1 = struct.unpack("<iiii", value)
            return x1 - x0 + 1, y1 - y0 + 1
        if size < 0:
            return None
        i = kind_end + 5 + size
    return None


def _hdr(head: bytes):
    if not (head.startswith(b"#?RADIANCE") or head.startswith(b"#?RGBE")):
        return None
    blank = head.find(b"\n\n")
    if blank < 0:
        return None
    line = head[blank + 2:head.find(b"\n", blank + 2)].split()
    if len(line) != 4 or not (line[1].isdigit() and line[3].isdigit()):
        return None
    a, b = int(line[1]), int(line[3])
    # "-Y H +X W": rows first; "+X W -Y H" (rotated): columns first
    return (b, a) if line[0][1:2] == b"Y" else (a, b)


def _sgi(head: bytes):
    if len(head) >= 10 and struct.unpack(">H", head[:2])[0] == 474:
        return struct.unpack(">HH", head[6:10])
    return None


def _dpx(head: bytes):
    order = {b"SDPX": ">", b"XPDS": "<"}.get(head[:4])
    if order is None or len(head) < 780:
        return None
    return struct.unpack(order + "II", head[772:780])


def _tga(head: bytes, name: str):
    if not str(name).lower().endswith((".tga", ".tpic", ".icb", ".vda", ".vst")):
        return None
    if len(head) < 18 or head[1] not in (0, 1) or head[2] not in (1, 2, 3, 9, 10, 11):
        return None
    return struct.unpack("<HH", head[12:16])


def image_size(f, name: str = "") -> tuple[int, int] | None:
    """(width, height) from the header of the image in the binary file object `f` (at its
    start), or None when the format is not one of the module docstring's or its header is
    damaged. Reads at most HEADER_BYTES (a JPEG's segments are skipped by seeking)."""
    f.seek(0)
    head = f.read(HEADER_BYTES)
    for probe in (_png, _bmp, _webp, _exr, _hdr, _sgi, _dpx):
        size = probe(head)
        if size is not None:
            return int(size[0]), int(size[1])
    if head[:2] == b"\xff\xd8":
        size = _jpeg(f)
    elif head[:2] in (b"II", b"MM"):
        size = _tiff(f, head)
    else:
        size = _tga(head, name)
    return None if size is None else (int(size[0]), int(size[1]))
