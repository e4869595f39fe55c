"""The film: per-pixel sums of every pass, and the tile readout Blender's render result wants.

For pixel p with camera samples i = 1..n_p (valid through the lens or not):
    Combined RGB  C_p = (1/n_p) sum_i c_i         c_i = the sum over the sample's lens rays
                  (one, or three with dispersion: camera_rays) of weight * L (0 if invalid)
    alpha         1, or with a transparent film  A_p = (# valid samples hitting geometry) /
                                                       (# valid samples)
    Vignetting    V_p = (1/n_p) sum_i g_i V_i / g_0   the relative illumination: the irradiance
                  a uniform scene of radiance 1 gives the pixel through the lens, 1 at the film
                  centre (camera_rays), falling off with natural and mechanical vignetting
    Depth         mean over valid samples with a first hit of the hit's distance along the
                  camera's view axis (Blender's Z convention); 1e10 where nothing was hit
    Normal        mean world-space normal of those first hits (not renormalised: an edge pixel
                  shows the mixture), 0 where nothing was hit
    Lens Uncertainty  mean over valid samples that computed it of the learned ensemble's
                  spread (camera_rays); 0 for the exact lens and pixels without such samples
A sample of three rays adds each ray's share 1/3 to the counts, validity, illumination, hits,
depth, normal and uncertainty sums, so every other pass stays a mean over samples.
    Noisy Image   the Combined before denoising (equal to Combined when the engine does not
                  denoise); Denoising Albedo / Normal: mean base colour and normal of the first
                  hits (0 where nothing was hit), the denoiser's guides (denoise.py)
Sums are float32, sixteen a pixel (rgb 3, count, valid, illumination, hits, depth, normal 3,
albedo 3, uncertainty and its count): the render's only frame-sized memory (its size:
docs/render-engine.md). Rows run bottom to top, as in Blender.
"""

from __future__ import annotations

import numpy as np

from .plan import Tile

#: Blender's "nothing here" depth
DEPTH_FAR = 1.0e10
#: (name, channels, chan_id) of every pass the engine writes, Combined first
PASSES = (("Combined", 4, "RGBA"), ("Depth", 1, "Z"), ("Normal", 3, "XYZ"),
          ("Vignetting", 1, "X"), ("Lens Uncertainty", 1, "X"), ("Noisy Image", 4, "RGBA"),
          ("Denoising Albedo", 3, "RGB"), ("Denoising Normal", 3, "XYZ"))


class Film:
    """Accumulation buffers of a W x H frame (row-major, row 0 at the bottom)."""

    def __init__(self, width: int, height: int, transparent: bool = False):
        self.width, self.height = int(width), int(height)
        self.transparent = bool(transparent)
        n = self.width * self.height
        self.rgb = np.zeros((n, 3), np.float32)
        self.count = np.zeros(n, np.float32)       # samples taken
        self.valid = np.zeros(n, np.float32)       # samples that passed the lens
        self.illum = np.zeros(n, np.float32)       # their relative illumination g V / g_0
        self.hits = np.zeros(n, np.float32)        # valid samples with a first hit
        self.depth = np.zeros(n, np.float32)
        self.normal = np.zeros((n, 3), np.float32)
        self.albedo = np.zeros((n, 3), np.float32)
        self.unc = np.zeros(n, np.float32)
        self.unc_count = np.zeros(n, np.float32)

    def add(self, tile: Tile, local_pixel: np.ndarray, *, rgb, valid, hit, depth, normal,
            illumination, uncertainty=None, share: float = 1.0, albedo=None):
        """Accumulate a bundle's rays. local_pixel: (N,) pixel index within `tile`
        (row-major), rgb (N, 3), valid / hit (N,) bool, depth (N,), normal (N, 3),
        illumination (N,) the camera weight g V / g_0 without colour, uncertainty (N,) or
        None, share: each ray's share of its camera sample. Counted with bincount on the
        tile, then added to the frame."""
        m = tile.pixels
        lp = np.asarray(local_pixel, dtype=np.int64)
        sel = self._rows(tile)

        def acc(weights=None):
            w = np.full(lp.size, share) if weights is None else weights * share
            return np.bincount(lp, weights=w, minlength=m)

        self.count[sel] += acc().astype(np.float32)
        self.valid[sel] += acc(valid.astype(np.float64)).astype(np.float32)
        self.illum[sel] += acc(np.asarray(illumination, np.float64)).astype(np.float32)
        hitw = hit.astype(np.float64)
        self.hits[sel] += acc(hitw).astype(np.float32)
        self.depth[sel] += acc(np.where(hit, depth, 0.0)).astype(np.float32)
        for c in range(3):
            self.rgb[sel, c] += np.bincount(lp, weights=rgb[:, c], minlength=m).astype(np.float32)
            self.normal[sel, c] += acc(np.where(hit, normal[:, c], 0.0)).astype(np.float32)
            if albedo is not None:
                self.albedo[sel, c] += acc(np.where(hit, albedo[:, c], 0.0)).astype(np.float32)
        if uncertainty is not None:
            self.unc[sel] += acc(np.where(valid, uncertainty, 0.0)).astype(np.float32)
            self.unc_count[sel] += acc(valid.astype(np.float64)).astype(np.float32)

    def _rows(self, tile: Tile) -> np.ndarray:
        """Frame pixel indices of a tile, row-major from its bottom-left."""
        ys = np.arange(tile.y, tile.y + tile.h)
        xs = np.arange(tile.x, tile.x + tile.w)
        return (ys[:, None] * self.width + xs[None, :]).ravel()

    def tile_global_pixels(self, tile: Tile) -> np.ndarray:
        return self._rows(tile)

    def readout(self, tile: Tile) -> dict:
        """{pass name: (tile pixels, channels) float32} for Blender's render result."""
        sel = self._rows(tile)
        n = self.count[sel]
        inv_n = np.where(n > 0, 1.0 / np.maximum(n, 1), 0.0).astype(np.float32)
        v = self.valid[sel]
        h = self.hits[sel]
        inv_h = np.where(h > 0, 1.0 / np.maximum(h, 1), 0.0).astype(np.float32)
        comb = np.empty((sel.size, 4), np.float32)
        comb[:, :3] = self.rgb[sel] * inv_n[:, None]
        if self.transparent:
            comb[:, 3] = np.where(v > 0, h / np.maximum(v, 1), 0.0)
        else:
            comb[:, 3] = np.where(n > 0, 1.0, 0.0)
        depth = np.where(h > 0, self.depth[sel] * inv_h, DEPTH_FAR).astype(np.float32)
        uc = self.unc_count[sel]
        unc = np.where(uc > 0, self.unc[sel] / np.maximum(uc, 1), 0.0).astype(np.float32)
        normal = (self.normal[sel] * inv_h[:, None]).astype(np.float32)
        return {"Combined": comb,
                "Depth": depth[:, None],
                "Normal": normal,
                "Vignetting": (self.illum[sel] * inv_n)[:, None].astype(np.float32),
                "Lens Uncertainty": unc[:, None],
                "Noisy Image": comb,
                "Denoising Albedo": (self.albedo[sel] * inv_h[:, None]).astype(np.float32),
                "Denoising Normal": normal}

    def image(self, name: str) -> np.ndarray:
        """A whole pass as an (H, W, channels) array, row 0 at the bottom (for tests)."""
        full = Tile(0, 0, self.width, self.height)
        return self.readout(full)[name].reshape(self.height, self.width, -1)
