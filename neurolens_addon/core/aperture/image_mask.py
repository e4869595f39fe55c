"""A stop drawn as an image (`ImageMaskAperture`), and reading one from an image file.

ImageMaskAperture(mask): an (H, W) transmittance image in [0, 1] stretched over [-1, 1]^2,
row 0 at the top (y = +1), column 0 at the left (x = -1), pixel centres at
    x_j = -1 + (2 j + 1) / W,   y_i = 1 - (2 i + 1) / H.
transmittance(x, y) is the bilinear interpolation of the pixel values (edge pixels extended up
to the image border, 0 outside the square); inside iff transmittance > 0.5.
area = sum(mask) * 4 / (H W) (the integral of the pixelwise-constant transmittance).
`sample` draws from the piecewise-constant density proportional to the pixel values by a 2-D
inverse CDF (u2 picks the row from the marginal, u1 the column from that row's conditional,
continuous inside the pixel). For a binary mask this is uniform over the lit pixels; for a
soft mask, weighting each sample by area() gives the transmittance-weighted integral. The
pixel footprint and the bilinear "> 0.5" region agree for a binary mask except within half a
pixel of a corner of the lit region, where bilinear interpolation rounds the corner.
`load_mask_image` reads an image file (PNG, or any format Pillow reads) as a transmittance in
[0, 1]: RGB(A) is converted to Rec.709 luminance 0.2126 R + 0.7152 G + 0.0722 B, times alpha
when present (transparent = opaque blade); integer images are scaled by their type's maximum.

Size bounds: an image with more than MAX_MASK_PIXELS pixels is refused before it is decoded
(its header says its size: core.image_header, else Pillow's lazy open, which reads headers
only); a mask larger than MAX_MASK_SIDE on a side is area-averaged down to it (each new pixel
the mean of the old ones it covers), which keeps the stop's area and shape to a pixel of
1/MAX_MASK_SIDE of the aperture, finer than any render resolves (the Cycles shader's and the
diffraction pattern's grids are that size or smaller).

Memory: the reduction runs a block of REDUCE_BLOCK_PIXELS source pixels at a time (luminance,
clip and sums in float64 per block, the same sums in the same order as over the whole image),
so a large mask costs its decoded pixels (Pillow's 1-4 bytes a pixel, Blender's float32
pixels for a Blender image) and no full-size float64 copy; only the reduced mask is kept.
"""

from __future__ import annotations

import hashlib

import numpy as np

from ..errors import ApertureError
from .base import Aperture, as_uv, as_xy

#: masks are used at most this many pixels on a side (area-averaged down)
MAX_MASK_SIDE = 1024
#: images with more pixels than this are refused before decoding (8192 x 8192)
MAX_MASK_PIXELS = 8192 * 8192
#: mask files larger than this are refused before reading
MAX_MASK_FILE_BYTES = 256 << 20
#: source pixels reduced at once (bounds the float64 temporaries of a large mask)
REDUCE_BLOCK_PIXELS = 1 << 18
#: Rec. 709 luminance of linear RGB
LUMINANCE = (0.2126, 0.7152, 0.0722)


def check_mask_size(width: int, height: int, where: str) -> None:
    """Refuse (ApertureError, one line naming `where` and the size) an image over the pixel
    limit, or one without pixels, before anything decodes it."""
    if width < 1 or height < 1:
        raise ApertureError(f"{where}: the image has no pixels ({width} x {height})")
    if width * height > MAX_MASK_PIXELS:
        raise ApertureError(f"{where}: {width} x {height} pixels is over the limit of "
                            f"{MAX_MASK_PIXELS} pixels (8192 x 8192): use a smaller image")


def reduce_rows(height: int, width: int, rows_of, where: str = "aperture mask",
                side: int = MAX_MASK_SIDE, block_pixels: int = REDUCE_BLOCK_PIXELS
                ) -> np.ndarray:
    """The (height, width) transmittance whose rows [a, b) `rows_of(a, b)` gives (any real
    dtype, row 0 at the top), clipped to [0, 1] and area-averaged to at most `side` pixels a
    side (area_average's sums, about `block_pixels` source pixels at a time): float64."""
    def block(a, b):
        m = np.array(rows_of(a, b), dtype=np.float64)      # a copy: clipped in place below
        if not np.all(np.isfinite(m)):
            raise ApertureError(f"{where}: contains NaN or infinite values")
        return np.clip(m, 0.0, 1.0, out=m)

    if max(height, width) <= side:
        return block(0, height)
    k = max(height, width) / side
    nh, nw = max(1, round(height / k)), max(1, round(width / k))
    rows = np.linspace(0, height, nh + 1).round().astype(int)
    cols = np.linspace(0, width, nw + 1).round().astype(int)
    area = np.diff(rows)[:, None] * np.diff(cols)[None, :]
    out = np.empty((nh, nw))
    per = max(1, block_pixels // width)                 # source rows a block
    i0 = 0
    while i0 < nh:
        i1 = i0 + 1
        while i1 < nh and rows[i1 + 1] - rows[i0] <= per:
            i1 += 1
        m = block(rows[i0], rows[i1])
        sums = np.add.reduceat(np.add.reduceat(m, rows[i0:i1] - rows[i0], axis=0),
                               cols[:-1], axis=1)
        out[i0:i1] = sums / area[i0:i1]
        i0 = i1
    return out


def area_average(m: np.ndarray, side: int = MAX_MASK_SIDE) -> np.ndarray:
    """`m` resampled so that neither side exceeds `side`, by exact area means."""
    h, w = m.shape
    if max(h, w) <= side:
        return m
    k = max(h, w) / side
    nh, nw = max(1, round(h / k)), max(1, round(w / k))
    rows = np.linspace(0, h, nh + 1).round().astype(int)
    cols = np.linspace(0, w, nw + 1).round().astype(int)
    sums = np.add.reduceat(np.add.reduceat(m, rows[:-1], axis=0), cols[:-1], axis=1)
    return sums / (np.diff(rows)[:, None] * np.diff(cols)[None, :])


class ImageMaskAperture(Aperture):
    """A transmittance image over [-1, 1]^2 (row 0 at the top). Values are clipped to [0, 1]."""

    kind = "image"

    def __init__(self, mask_2d_array, source: str | None = None):
        where = f"aperture mask {source}" if source else "aperture mask"
        m = np.asarray(mask_2d_array)
        if m.ndim != 2 or m.shape[0] < 1 or m.shape[1] < 1:
            raise ApertureError(f"{where}: expected a 2-D image, got shape {m.shape}")
        if m.size > MAX_MASK_PIXELS:
            raise ApertureError(f"{where}: {m.shape[1]} x {m.shape[0]} pixels is over the limit "
                                f"of {MAX_MASK_PIXELS} pixels (8192 x 8192): use a smaller image")
        self._build(reduce_rows(m.shape[0], m.shape[1], lambda a, b: m[a:b], where), source)

    @classmethod
    def from_rows(cls, height: int, width: int, rows_of, source: str | None = None
                  ) -> "ImageMaskAperture":
        """A mask of height x width pixels read a block of rows at a time: rows_of(a, b)
        gives rows [a, b) (row 0 at the top), so a large image is reduced without a
        full-size float copy (reduce_rows)."""
        where = f"aperture mask {source}" if source else "aperture mask"
        check_mask_size(int(width), int(height), where)
        self = cls.__new__(cls)
        self._build(reduce_rows(int(height), int(width), rows_of, where), source)
        return self

    def _build(self, m: np.ndarray, source) -> None:
        """Everything the shape keeps, from its (reduced, clipped) float64 mask."""
        where = f"aperture mask {source}: " if source else "aperture mask: "
        if not np.any(m > 0.0):
            raise ApertureError(f"{where}is completely black: it would block all light")
        self.source = source
        self.mask = m
        self.mask.setflags(write=False)
        self._key = ("mask", m.shape[0], m.shape[1],
                     hashlib.sha256(np.ascontiguousarray(m).tobytes()).hexdigest()[:32])
        h, w = m.shape
        self._h, self._w = h, w
        # 2-D piecewise-constant distribution: marginal over rows, conditional over columns
        row_sum = m.sum(axis=1)
        total = row_sum.sum()
        self._row_cdf = np.concatenate([[0.0], np.cumsum(row_sum) / total])
        self._row_cdf[-1] = 1.0
        safe = np.where(row_sum[:, None] > 0, m, 1.0)
        cond = np.cumsum(safe, axis=1) / safe.sum(axis=1, keepdims=True)
        self._col_cdf = np.concatenate([np.zeros((h, 1)), cond], axis=1)
        self._col_cdf[:, -1] = 1.0
        self._flat_cdf = (self._col_cdf + np.arange(h)[:, None]).ravel()
        self._area = float(total * 4.0 / (h * w))
        # conservative bounding radius: farthest corner of any pixel with light
        ii, jj = np.nonzero(m > 0.0)
        xs = np.stack([-1.0 + 2.0 * jj / w, -1.0 + 2.0 * (jj + 1) / w])
        ys = np.stack([1.0 - 2.0 * ii / h, 1.0 - 2.0 * (ii + 1) / h])
        self._bound = float(np.sqrt(np.max(np.abs(xs), axis=0) ** 2
                                    + np.max(np.abs(ys), axis=0) ** 2).max())

    def transmittance(self, x, y) -> np.ndarray:
        x, y, ok = as_xy(x, y)
        h, w = self._h, self._w
        inbox = ok & (np.abs(x) <= 1.0) & (np.abs(y) <= 1.0)
        fx = np.clip((x + 1.0) * 0.5 * w - 0.5, 0.0, w - 1.0)
        fy = np.clip((1.0 - y) * 0.5 * h - 0.5, 0.0, h - 1.0)
        j0 = np.minimum(np.floor(fx).astype(np.intp), max(w - 2, 0))
        i0 = np.minimum(np.floor(fy).astype(np.intp), max(h - 2, 0))
        j1 = np.minimum(j0 + 1, w - 1)
        i1 = np.minimum(i0 + 1, h - 1)
        tx = fx - j0
        ty = fy - i0
        m = self.mask
        v = ((1 - ty) * ((1 - tx) * m[i0, j0] + tx * m[i0, j1])
             + ty * ((1 - tx) * m[i1, j0] + tx * m[i1, j1]))
        return np.where(inbox, v, 0.0)

    def inside(self, x, y) -> np.ndarray:
        return self.transmittance(x, y) > 0.5

    def sample(self, u1, u2) -> tuple[np.ndarray, np.ndarray]:
        u1, u2 = as_uv(u1, u2)
        h, w = self._h, self._w
        rc = self._row_cdf
        i = np.clip(np.searchsorted(rc, u2, side="right") - 1, 0, h - 1)
        fy = i + np.clip((u2 - rc[i]) / (rc[i + 1] - rc[i]), 0.0, 1.0)
        idx = np.searchsorted(self._flat_cdf, i + u1, side="right") - 1
        j = np.clip(idx - i * (w + 1), 0, w - 1)
        cc = self._col_cdf
        lo, hi = cc[i, j], cc[i, j + 1]
        fx = j + np.clip((u1 - lo) / np.where(hi > lo, hi - lo, 1.0), 0.0, 1.0)
        return -1.0 + 2.0 * fx / w, 1.0 - 2.0 * fy / h

    def area(self) -> float:
        return self._area

    def bounding_radius(self) -> float:
        return self._bound

    def reduced(self, side: int) -> "ImageMaskAperture":
        """The mask area-averaged to at most `side` pixels a side (itself when it fits);
        ApertureError when nothing stays open (transmittance > 0.5) at that size."""
        if max(self.mask.shape) <= side:
            return self
        small = area_average(np.asarray(self.mask), side)
        if not np.any(small > 0.5):
            raise ApertureError(f"aperture mask {self.source or ''}: nothing stays open after "
                                f"reducing it to {side} pixels per side")
        return ImageMaskAperture(small, source=self.source)

    @property
    def key(self) -> tuple:
        return self._key

    def __repr__(self) -> str:
        src = f", source={self.source!r}" if self.source else ""
        return f"ImageMaskAperture(shape={self.mask.shape}{src})"


#: Pillow modes converted before reading (palette, bilevel, premultiplied, other colour spaces)
_CONVERT = {"P": "RGBA", "PA": "RGBA", "1": "L", "RGBa": "RGBA", "La": "LA", "RGBX": "RGB",
            "CMYK": "RGB", "YCbCr": "RGB", "LAB": "RGB", "HSV": "RGB"}


def transmittance_rows(px: np.ndarray, scale: float) -> np.ndarray:
    """(rows, W, C) or (rows, W) pixel values -> (rows, W) float64 transmittance: values
    times `scale`, luminance of RGB, times alpha when present (module docstring)."""
    x = np.asarray(px, dtype=np.float64) * scale
    if x.ndim == 2:
        return x
    c = x.shape[2]
    lum = x[..., 0] if c in (1, 2) else x[..., :3] @ np.array(LUMINANCE)
    return lum * x[..., -1] if c in (2, 4) else lum


def load_mask_image(path) -> np.ndarray:
    """Read an image file (PNG, or another format Pillow reads) as a transmittance in [0, 1],
    area-averaged to at most MAX_MASK_SIDE pixels a side (reduce_rows: the float64 mask an
    ImageMaskAperture keeps, never a full-size float copy).

    The size is read from the header and an image over MAX_MASK_PIXELS refused (one line
    naming the file and its size) before anything is decoded. RGB(A) is converted to
    Rec.709 luminance 0.2126 R + 0.7152 G + 0.0722 B, times alpha when present (transparent =
    opaque blade). Integer images are scaled by their type's maximum (16-bit by 65535).
    """
    import io
    import warnings

    from PIL import Image  # imported lazily: only image masks need Pillow

    from ..image_header import image_size
    from ..safe_io import UnreadableFile, read_regular
    where = f"aperture mask {path}"
    try:
        data = read_regular(path, MAX_MASK_FILE_BYTES, "aperture mask image")
    except UnreadableFile as exc:
        raise ApertureError(str(exc)) from None
    size = image_size(io.BytesIO(data), str(path))
    if size is not None:
        check_mask_size(size[0], size[1], where)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(io.BytesIO(data))       # lazy: the header only
            check_mask_size(im.size[0], im.size[1], where)
            if im.mode in _CONVERT:
                im = im.convert(_CONVERT[im.mode])
            im.load()                               # decoded once, in Pillow's own layout
    except ApertureError:
        raise
    except Image.DecompressionBombError as exc:     # a header only Pillow reads, far too big
        raise ApertureError(f"{where}: over the limit of {MAX_MASK_PIXELS} pixels "
                            f"(8192 x 8192): {exc}") from None
    except Exception as exc:  # noqa: BLE001 - not an image, unsupported or damaged
        raise ApertureError(f"{where}: cannot read image ({exc})") from None
    if im.mode.startswith("I;16") or im.mode == "I":
        scale = 1.0 / 65535.0
    elif im.mode == "F":
        scale = 1.0
    else:
        scale = 1.0 / 255.0
    w, h = im.size

    def rows_of(a, b):
        return transmittance_rows(np.asarray(im.crop((0, a, w, b))), scale)

    return reduce_rows(h, w, rows_of, where)
