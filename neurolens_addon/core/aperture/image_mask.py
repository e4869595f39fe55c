"""A stop drawn as an image (`ImageMaskAperture`), and reading one from a PNG.

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
`load_mask_image` reads a PNG as an (H, W) transmittance in [0, 1]: RGB(A) is converted to
Rec.709 luminance 0.2126 R + 0.7152 G + 0.0722 B, times alpha when present (transparent =
opaque blade); integer images are scaled by their type's maximum.

Size bounds: an image with more than MAX_MASK_PIXELS pixels is refused before it is decoded
(its header says its size); a mask larger than MAX_MASK_SIDE on a side is area-averaged down to
it (each new pixel the mean of the old ones it covers), which keeps the stop's area and shape
to a pixel of 1/MAX_MASK_SIDE of the aperture, finer than any render resolves.
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
        where = f"aperture mask {source}: " if source else "aperture mask: "
        m = np.asarray(mask_2d_array)
        if m.ndim != 2 or m.shape[0] < 1 or m.shape[1] < 1:
            raise ApertureError(f"{where}expected a 2-D image, got shape {m.shape}")
        if m.size > MAX_MASK_PIXELS:
            raise ApertureError(f"{where}{m.shape[1]} x {m.shape[0]} pixels is over the limit of "
                                f"{MAX_MASK_PIXELS} pixels (8192 x 8192): use a smaller image")
        m = m.astype(np.float64)
        if not np.all(np.isfinite(m)):
            raise ApertureError(f"{where}contains NaN or infinite values")
        m = area_average(np.clip(m, 0.0, 1.0))
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


def load_mask_image(path) -> np.ndarray:
    """Read a PNG (matplotlib.image.imread) as an (H, W) transmittance in [0, 1].

    RGB(A) is converted to Rec.709 luminance 0.2126 R + 0.7152 G + 0.0722 B, times alpha when
    present (transparent = opaque blade). Integer images are scaled by their type's maximum.
    """
    import io
    import struct

    import matplotlib.image as mpimg  # imported lazily: only image masks need matplotlib

    from ..safe_io import UnreadableFile, read_regular
    try:
        data = read_regular(path, MAX_MASK_FILE_BYTES, "aperture mask image")
    except UnreadableFile as exc:
        raise ApertureError(str(exc)) from None
    if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 24:
        w, h = struct.unpack(">II", data[16:24])
        if w * h > MAX_MASK_PIXELS:
            raise ApertureError(f"aperture mask {path}: {w} x {h} pixels is over the limit of "
                                f"{MAX_MASK_PIXELS} pixels (8192 x 8192): use a smaller image")
    try:
        img = np.asarray(mpimg.imread(io.BytesIO(data), format="png"))
    except Exception as exc:  # not an image, unsupported format
        raise ApertureError(f"aperture mask {path}: cannot read image ({exc})") from None
    if np.issubdtype(img.dtype, np.integer):
        img = img.astype(np.float64) / np.iinfo(img.dtype).max
    img = img.astype(np.float64)
    if img.ndim == 2:
        lum = img
    elif img.ndim == 3 and img.shape[2] in (1, 2, 3, 4):
        c = img.shape[2]
        if c in (1, 2):
            lum = img[..., 0]
        else:
            lum = img[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
        if c in (2, 4):
            lum = lum * img[..., -1]
    else:
        raise ApertureError(f"aperture mask {path}: expected a grey, RGB or RGBA image, "
                            f"got array shape {img.shape}")
    return lum
