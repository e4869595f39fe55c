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
    Vector, Position, UV  the data passes, when a frame asks for them (data_passes.py: their
                  sums and readout; Position and UV means over the hits, Vector over the
                  samples the lens placed)
Sums are float32, sixteen a pixel (rgb 3, count, valid, illumination, hits, depth, normal 3,
albedo 3, uncertainty and its count: 64 bytes), and the data passes' columns (Vector 5,
Position 3, UV 2) when asked for. Rows run bottom to top, as in Blender.

Two layouts of the sums (the image is the same in both, bit for bit: a pixel's sums see the
same additions in the same order):
  frame     one set of sums for the W x H frame (64 W H bytes), for the progressive order
            (plan.bundles) and the viewport, which read any tile at any time;
  streamed  sums only for the tiles in progress (tile by tile order: one tile at a time), made
            when a tile's first bundle arrives and dropped when `finish` says its last pass is
            done; the passes the frame's post-processing needs (`keep`: the denoiser's colour
            and guides, the diffraction's colour) are copied then into frame-sized stores
            (4 bytes a channel a pixel), the rest of the frame lives only in the sink
            (Blender's render result).
`frame(name)` gives a whole pass in either layout; in the frame layout it reads the sums a
block of rows at a time, so no frame-sized temporary beyond the pass itself is made. Memory of
each layout: docs/render-engine.md.
"""

from __future__ import annotations

import numpy as np

from . import film_kernels, shading_kernels
from .data_passes import DATA_PASSES, DataLayout
from .plan import Tile

#: Blender's "nothing here" depth
DEPTH_FAR = 1.0e10
#: (name, channels, chan_id) of every pass the engine writes, Combined first
PASSES = (("Combined", 4, "RGBA"), ("Depth", 1, "Z"), ("Normal", 3, "XYZ"),
          ("Vignetting", 1, "X"), ("Lens Uncertainty", 1, "X"), ("Noisy Image", 4, "RGBA"),
          ("Denoising Albedo", 3, "RGB"), ("Denoising Normal", 3, "XYZ"))


def _inverse(count: np.ndarray) -> np.ndarray:
    """1 / count where count > 0, else 0 (float32)."""
    return np.where(count > 0, 1.0 / np.where(count > 0, count, 1.0), 0.0).astype(np.float32)


#: channels of each pass (the data passes' too, written when a frame asks for them)
CHANNELS = {name: channels for name, channels, _chan in PASSES + DATA_PASSES}
#: bytes of the sums a pixel
SUM_BYTES = 64


class _Sums:
    """The sixteen float32 sums of n pixels (module docstring)."""

    def __init__(self, n: int, data_width: int = 0):
        self.data = np.zeros((n, data_width), np.float32) if data_width else None
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


class Film:
    """Accumulation buffers of a W x H frame (row-major, row 0 at the bottom): the whole
    frame's sums, or with `streamed` the sums of the tiles in progress and frame-sized copies
    of the passes named in `keep` (module docstring)."""

    def __init__(self, width: int, height: int, transparent: bool = False, *,
                 streamed: bool = False, keep=(), data: DataLayout | None = None):
        self.width, self.height = int(width), int(height)
        #: the data passes (data_passes: Vector, Position, UV) this film sums, or None
        self.data = data if data is not None and data.passes else None
        self._data_width = self.data.width if self.data is not None else 0
        self.transparent = bool(transparent)
        self.streamed = bool(streamed)
        n = self.width * self.height
        unknown = set(keep) - set(CHANNELS)
        if unknown:
            raise ValueError(f"no such pass: {', '.join(sorted(unknown))}")
        self.keep = tuple(keep) if self.streamed else ()
        self._frame = None if self.streamed else _Sums(n, self._data_width)
        self._tiles: dict = {}              # streamed: tile -> its _Sums while in progress
        # np.zeros: pages are taken as tiles are written; an unfinished tile reads 0
        self._kept = {name: np.zeros((n, CHANNELS[name]), np.float32) for name in self.keep}

    def _sums(self, tile: Tile, create: bool = False):
        """(sums, index of the tile's pixels in them)."""
        if not self.streamed:
            return self._frame, self._rows(tile)
        sums = self._tiles.get(tile)
        if sums is None:
            if not create:
                raise KeyError(f"tile {tile} is not in progress on this streamed film")
            sums = self._tiles[tile] = _Sums(tile.pixels, self._data_width)
        return sums, slice(None)

    @property
    def tiles_in_progress(self) -> int:
        return len(self._tiles)

    def add(self, tile: Tile, local_pixel: np.ndarray, *, rgb, valid, hit, depth, normal,
            illumination, uncertainty=None, share: float = 1.0, albedo=None, data=None):
        """Accumulate a bundle's rays. local_pixel: (N,) pixel index within `tile`
        (row-major), rgb (N, 3), valid / hit (N,) bool, depth (N,), normal (N, 3),
        illumination (N,) the camera weight g V / g_0 without colour, uncertainty (N,) or
        None, share: each ray's share of its camera sample, data (N, D) the data passes' sums
        or None. Counted with bincount on the tile, then added to the frame."""
        m = tile.pixels
        lp = np.asarray(local_pixel, dtype=np.int64)
        f, sel = self._sums(tile, create=True)
        if f.data is not None and data is not None:
            for c in range(f.data.shape[1]):
                f.data[sel, c] += np.bincount(lp, weights=data[:, c] * share,
                                              minlength=m).astype(np.float32)
        if shading_kernels.active():
            rows = np.arange(m) if isinstance(sel, slice) else sel
            film_kernels.run_add(f, rows, lp, share, rgb, valid, hit, depth, normal,
                                 illumination, uncertainty, albedo)
            return

        def acc(weights=None):
            w = np.full(lp.size, share) if weights is None else weights * share
            return np.bincount(lp, weights=w, minlength=m)

        f.count[sel] += acc().astype(np.float32)
        f.valid[sel] += acc(valid.astype(np.float64)).astype(np.float32)
        f.illum[sel] += acc(np.asarray(illumination, np.float64)).astype(np.float32)
        hitw = hit.astype(np.float64)
        f.hits[sel] += acc(hitw).astype(np.float32)
        f.depth[sel] += acc(np.where(hit, depth, 0.0)).astype(np.float32)
        for c in range(3):
            f.rgb[sel, c] += np.bincount(lp, weights=rgb[:, c], minlength=m).astype(np.float32)
            f.normal[sel, c] += acc(np.where(hit, normal[:, c], 0.0)).astype(np.float32)
            if albedo is not None:
                f.albedo[sel, c] += acc(np.where(hit, albedo[:, c], 0.0)).astype(np.float32)
        if uncertainty is not None:
            f.unc[sel] += acc(np.where(valid, uncertainty, 0.0)).astype(np.float32)
            f.unc_count[sel] += acc(valid.astype(np.float64)).astype(np.float32)

    def finish(self, tile: Tile, passes: dict) -> None:
        """The tile's last pass is done and `passes` is its readout: a streamed film keeps the
        passes named in `keep` and drops the tile's sums (nothing to do on a frame film)."""
        if not self.streamed:
            return
        rows = self._rows(tile)
        for name, store in self._kept.items():
            store[rows] = passes[name]
        self._tiles.pop(tile, None)

    def _rows(self, tile: Tile) -> np.ndarray:
        """Frame pixel indices of a tile, row-major from its bottom-left."""
        ys = np.arange(tile.y, tile.y + tile.h)
        xs = np.arange(tile.x, tile.x + tile.w)
        return (ys[:, None] * self.width + xs[None, :]).ravel()

    def tile_global_pixels(self, tile: Tile) -> np.ndarray:
        return self._rows(tile)

    def readout(self, tile: Tile) -> dict:
        """{pass name: (tile pixels, channels) float32} for Blender's render result. A count
        may be a fraction (a sample of three rays adds a third a ray): means divide by it
        wherever it is above 0."""
        f, sel = self._sums(tile)
        n = f.count[sel]
        inv_n = _inverse(n)
        v = f.valid[sel]
        h = f.hits[sel]
        inv_h = _inverse(h)
        comb = np.empty((n.size, 4), np.float32)
        comb[:, :3] = f.rgb[sel] * inv_n[:, None]
        if self.transparent:
            comb[:, 3] = h * _inverse(v)
        else:
            comb[:, 3] = np.where(n > 0, 1.0, 0.0)
        depth = np.where(h > 0, f.depth[sel] * inv_h, DEPTH_FAR).astype(np.float32)
        unc = (f.unc[sel] * _inverse(f.unc_count[sel])).astype(np.float32)
        normal = (f.normal[sel] * inv_h[:, None]).astype(np.float32)
        data = {} if f.data is None else self.data.readout(f.data[sel])
        return data | {"Combined": comb,
                "Depth": depth[:, None],
                "Normal": normal,
                "Vignetting": (f.illum[sel] * inv_n)[:, None].astype(np.float32),
                "Lens Uncertainty": unc[:, None],
                "Noisy Image": comb,
                "Denoising Albedo": (f.albedo[sel] * inv_h[:, None]).astype(np.float32),
                "Denoising Normal": normal}

    #: rows of the frame read at once by `frame` (bounds its temporaries)
    FRAME_BLOCK_PIXELS = 1 << 18

    def frame(self, name: str) -> np.ndarray:
        """A whole pass, (W H, channels) float32, rows from the bottom: a streamed film's kept
        store (a pass it does not keep: KeyError), or read from the frame's sums a block of
        rows at a time."""
        if self.streamed:
            if name not in self._kept:
                raise KeyError(f"the streamed film keeps {', '.join(self.keep) or 'no pass'}, "
                               f"not {name}")
            return self._kept[name]
        out = np.empty((self.width * self.height, CHANNELS[name]), np.float32)
        rows = max(1, self.FRAME_BLOCK_PIXELS // self.width)
        for y in range(0, self.height, rows):
            t = Tile(0, y, self.width, min(rows, self.height - y))
            out[y * self.width:(y + t.h) * self.width] = self.readout(t)[name]
        return out

    def image(self, name: str) -> np.ndarray:
        """A whole pass as an (H, W, channels) array, row 0 at the bottom (for tests and the
        viewport)."""
        return self.frame(name).reshape(self.height, self.width, -1)
