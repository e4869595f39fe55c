"""Image textures as linear float arrays, looked up by UV.

An image is read once into a linear (H, W, 3) float32 array, row 0 at the bottom (Blender's
order); 8-bit images in the sRGB colour space are decoded with the sRGB transfer function, as
Blender's colour management does (float images are taken as linear, with a note where one is
tagged sRGB):
    linear(c) = c / 12.92                       for c <= 0.04045
              = ((c + 0.055) / 1.055)^2.4       otherwise
A lookup at (u, v) reads texel coordinates (u W, v H):
  Closest   the texel containing the point;
  Linear    bilinear between the four texels around (u W - 1/2, v H - 1/2) (also used for
            Cubic and Smart).
Texel indices outside the image follow the extension mode: Repeat (modulo the size), Mirror
(modulo twice the size, reflected), Extend (clamped to the edge) or Clip (black outside).
"""

from __future__ import annotations

import numpy as np


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, dtype=np.float32)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


class Texture:
    """An image as a linear (H, W, 3) float32 array, row 0 at the bottom (Blender's order)."""

    def __init__(self, pixels: np.ndarray, interpolation: str = "Linear",
                 extension: str = "REPEAT", name: str = ""):
        self.pixels = np.ascontiguousarray(pixels, dtype=np.float32)
        self.h, self.w = self.pixels.shape[:2]
        self.closest = interpolation == "Closest"
        self.extension = extension
        self.name = name

    @classmethod
    def from_image(cls, image, interpolation="Linear", extension="REPEAT", notes=None):
        """The image's pixels in linear RGB; a float image tagged with a display colour space
        is read as linear, and `notes` is told (Cycles converts it)."""
        w, h = (int(s) for s in image.size)
        if w == 0 or h == 0:
            return None
        buf = np.empty(w * h * image.channels, dtype=np.float32)
        image.pixels.foreach_get(buf)
        px = buf.reshape(h, w, image.channels)
        rgb = px[..., :3] if image.channels >= 3 else np.repeat(px[..., :1], 3, axis=2)
        space = image.colorspace_settings.name
        if not image.is_float and space in ("sRGB", "sRGB EOTF"):
            rgb = srgb_to_linear(rgb)
        elif image.is_float and space in ("sRGB", "sRGB EOTF") and notes is not None:
            notes.append(f"image '{image.name}' holds float pixels tagged '{space}': read as "
                         "linear (set its colour space to Linear Rec.709 for Cycles' reading)")
        return cls(rgb, interpolation, extension, image.name)

    def _wrap(self, x: np.ndarray, n: int):
        """Integer texel indices under the extension mode, and an inside mask (Clip)."""
        inside = np.ones(x.shape, dtype=bool)
        if self.extension == "REPEAT":
            x = np.mod(x, n)
        elif self.extension == "MIRROR":
            x = np.mod(x, 2 * n)
            x = np.where(x >= n, 2 * n - 1 - x, x)
        else:
            if self.extension == "CLIP":
                inside = (x >= 0) & (x < n)
            x = np.clip(x, 0, n - 1)
        return x, inside

    def lookup(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) UVs -> (N, 3) linear RGB."""
        u = uv[:, 0] * self.w
        v = uv[:, 1] * self.h
        if self.closest:
            x, okx = self._wrap(np.floor(u).astype(np.int64), self.w)
            y, oky = self._wrap(np.floor(v).astype(np.int64), self.h)
            return np.where((okx & oky)[:, None], self.pixels[y, x], 0.0)
        u, v = u - 0.5, v - 0.5
        x0, y0 = np.floor(u), np.floor(v)
        fx, fy = (u - x0)[:, None], (v - y0)[:, None]
        x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
        xa, oka = self._wrap(x0, self.w)
        xb, okb = self._wrap(x0 + 1, self.w)
        ya, okc = self._wrap(y0, self.h)
        yb, okd = self._wrap(y0 + 1, self.h)
        p = self.pixels
        return ((1 - fy) * ((1 - fx) * p[ya, xa] * (oka & okc)[:, None]
                            + fx * p[ya, xb] * (okb & okc)[:, None])
                + fy * ((1 - fx) * p[yb, xa] * (oka & okd)[:, None]
                        + fx * p[yb, xb] * (okb & okd)[:, None]))
