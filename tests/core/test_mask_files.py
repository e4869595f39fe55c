"""Aperture mask files: their size read from the header of every format Blender reads before
anything decodes them (core.image_header), a file over the pixel limit refused in one line
naming it and its size, and an accepted large mask reduced a block of rows at a time to the
same area means, with no full-size float copy (core.aperture.image_mask)."""

from __future__ import annotations

import io
import json
import os
import struct
import subprocess
import sys
import tracemalloc
import zlib
from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core.errors import ApertureError

ROOT = Path(__file__).resolve().parents[2]


def _exr_header(w, h) -> bytes:
    """An OpenEXR header with its dataWindow (and the attributes before it) for a w x h image
    whose window starts at (3, 5)."""
    def attr(name, kind, value):
        return name + b"\0" + kind + b"\0" + struct.pack("<i", len(value)) + value
    return (b"\x76\x2f\x31\x01" + struct.pack("<I", 2)
            + attr(b"channels", b"chlist", b"R\0" + struct.pack("<iBBBBii", 2, 0, 0, 0, 0, 1, 1)
                   + b"\0")
            + attr(b"compression", b"compression", b"\0")
            + attr(b"dataWindow", b"box2i", struct.pack("<iiii", 3, 5, 3 + w - 1, 5 + h - 1))
            + b"\0")


def _png_of_zeros(w: int, h: int) -> bytes:
    """A valid 8-bit grey PNG of w x h black pixels, compressed a block of rows at a time (a
    20000 x 20000 image is a 0.4 MB file)."""
    comp = zlib.compressobj(1)
    row = b"\0" * (w + 1)
    parts = [comp.compress(row * min(64, h - i)) for i in range(0, h, 64)] + [comp.flush()]

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I",
                                                                         zlib.crc32(kind + data))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", b"".join(parts)) + chunk(b"IEND", b""))


def _jpeg_header(w, h) -> bytes:
    """SOI, an APP0 segment, then a baseline SOF0 of w x h (what a JPEG's size is read from)."""
    app0 = b"JFIF\0" + bytes([1, 1, 0]) + struct.pack(">HH", 1, 1) + b"\0\0"
    sof = bytes([8]) + struct.pack(">HH", h, w) + bytes([1, 1, 0x11, 0])
    return (b"\xff\xd8" + b"\xff\xe0" + struct.pack(">H", len(app0) + 2) + app0
            + b"\xff\xc0" + struct.pack(">H", len(sof) + 2) + sof + b"\xff\xd9")


def _bmp_header(w, h) -> bytes:
    info = struct.pack("<IiiHHIIiiII", 40, w, -h, 1, 8, 1, 0, 2835, 2835, 0, 0)   # RLE8
    return b"BM" + struct.pack("<IHHI", 14 + len(info), 0, 0, 14 + len(info)) + info


def _tiff_header(w, h) -> bytes:
    entries = [(256, 4, 1, w), (257, 4, 1, h), (258, 3, 1, 8), (259, 3, 1, 1),
               (262, 3, 1, 1), (273, 4, 1, 0), (277, 3, 1, 1), (279, 4, 1, 0)]
    ifd = struct.pack("<H", len(entries)) + b"".join(
        struct.pack("<HHI", t, k, c) + (struct.pack("<HH", v, 0) if k == 3
                                        else struct.pack("<I", v)) for t, k, c, v in entries)
    return b"II*\0" + struct.pack("<I", 8) + ifd + b"\0\0\0\0"


def test_01_headers_give_the_size_of_every_format(tmp_path):
    """core.image_header reads (width, height) of PNG (8 and 16 bit), JPEG, BMP, TIFF, WebP
    (lossy and lossless), Targa and SGI files Pillow writes, and of OpenEXR and Radiance HDR
    headers; a file of no known format gives None."""
    from PIL import Image

    from neurolens_addon.core.image_header import image_size
    rng = np.random.default_rng(0)
    rgba = Image.fromarray((rng.random((37, 53, 4)) * 255).astype(np.uint8), "RGBA")
    cases = [("PNG", "png", rgba), ("PNG", "png", Image.fromarray(
                 (rng.random((37, 53)) * 65535).astype(np.uint16))),
             ("JPEG", "jpg", rgba.convert("RGB")), ("BMP", "bmp", rgba.convert("RGB")),
             ("TIFF", "tif", rgba), ("WEBP", "webp", rgba.convert("RGB")),
             ("WEBP", "webp", rgba), ("TGA", "tga", rgba), ("SGI", "rgb", rgba.convert("RGB"))]
    for i, (fmt, ext, im) in enumerate(cases):
        path = tmp_path / f"m{i}.{ext}"
        im.save(path, fmt, **({"lossless": True} if i == 6 else {}))
        with open(path, "rb") as f:
            assert image_size(f, str(path)) == (53, 37), (fmt, ext)
    assert image_size(io.BytesIO(_exr_header(4000, 3000))) == (4000, 3000)
    assert image_size(io.BytesIO(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 300 +X 400\n")) \
        == (400, 300)
    assert image_size(io.BytesIO(_jpeg_header(20000, 17000))) == (20000, 17000)
    assert image_size(io.BytesIO(b"not an image at all" * 10)) is None


@pytest.mark.parametrize("kind", ["jpg", "bmp", "tif"])
def test_02_a_huge_mask_file_is_refused_from_its_header(tmp_path, kind):
    """A JPEG, BMP or TIFF whose header declares 20000 x 17000 pixels (a few bytes on disc) is
    refused in one line naming the file and its size, and nothing the size of the image is
    allocated (Python's allocations peak under 2 MB)."""
    from neurolens_addon.core.aperture import load_mask_image
    data = {"jpg": _jpeg_header, "bmp": _bmp_header, "tif": _tiff_header}[kind](20000, 17000)
    path = tmp_path / f"huge.{kind}"
    path.write_bytes(data)
    tracemalloc.start()
    try:
        with pytest.raises(ApertureError) as err:
            load_mask_image(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    text = str(err.value)
    assert "\n" not in text and str(path) in text and "20000 x 17000 pixels" in text, text
    assert peak < 2 << 20


def test_03_reducing_a_block_of_rows_at_a_time_gives_the_whole_images_area_means():
    """reduce_rows with blocks of a few rows is area_average of the clipped image, bit for
    bit; ImageMaskAperture leaves the caller's array as it was; NaN is refused in one line."""
    from neurolens_addon.core.aperture import ImageMaskAperture
    from neurolens_addon.core.aperture.image_mask import area_average, reduce_rows
    rng = np.random.default_rng(1)
    img = rng.random((3001, 1999)) * 1.4 - 0.2            # values outside [0, 1] too
    want = area_average(np.clip(img, 0.0, 1.0))
    got = reduce_rows(3001, 1999, lambda a, b: img[a:b], block_pixels=5000)
    assert got.shape == want.shape == (1024, 682)
    np.testing.assert_array_equal(got, want)
    small = img[:40, :30].copy()
    ImageMaskAperture(small)
    np.testing.assert_array_equal(small, img[:40, :30])
    bad = img.copy()
    bad[2500, 7] = np.nan
    with pytest.raises(ApertureError, match="^aperture mask big: contains NaN or infinite"):
        ImageMaskAperture(bad, source="big")


_LOAD_CHILD = r"""
import json, sys
def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key):
            return int(line.split()[1]) * 1024
from neurolens_addon.core.aperture import ImageMaskAperture, load_mask_image
import numpy as np, PIL.Image
before = status("VmRSS")
ap = ImageMaskAperture(load_mask_image(sys.argv[1]), source="big")
rise = status("VmHWM") - before
print(json.dumps({"rise": rise, "shape": list(ap.mask.shape), "area": ap.area(),
                  "dtype": str(ap.mask.dtype)}))
"""


@pytest.mark.slow
def test_04_a_large_accepted_mask_file_costs_its_decoded_bytes_not_float_copies(tmp_path):
    """A 6000 x 6000 RGBA PNG (a disc) read as a mask in a fresh process: the process grows by
    less than 8 bytes a pixel (Pillow's 4-byte pixels and blocks of rows: 5 measured), where
    reading it as float32 and converting to float64 took 49; the mask kept is 1024 x 1024
    with the disc's area."""
    from testdata.mask_images import write_disc_png
    side = 6000
    path = tmp_path / "disc.png"
    write_disc_png(path, side)
    p = subprocess.run([sys.executable, "-c", _LOAD_CHILD, str(path)], cwd=ROOT,
                       capture_output=True, text=True, timeout=600,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert p.returncode == 0, p.stderr[-600:]
    d = json.loads(p.stdout.strip().splitlines()[-1])
    assert d["shape"] == [1024, 1024]
    assert d["area"] == pytest.approx(4 * np.pi * 0.45 ** 2, rel=1e-3)
    assert d["rise"] < 8 * side * side, d
