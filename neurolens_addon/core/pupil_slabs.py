"""The rear pupil as slabs: the sampler the Cycles camera's shader runs (cycles.pupil_osl).

core.pupil.RearPupilSampler finds, for each band of sensor radius (the sensor point on +x), the
cells of a grid on its sampling plane z_p crossed by rays that pass the whole lens. A shader
cannot hold every cell list, so each band becomes S horizontal slabs: the slab edges y_0..y_S
are quantiles of the occupied area over y, and slab k covers [x_lo_k, x_hi_k], the x-extent of
the occupied cells it overlaps, widened by half a cell. A camera ray picks its slab and point
from the aperture sample (u1, u2) (stratification survives):
    s = S u2, k = floor(s), y = y_k + (s - k)(y_{k+1} - y_k), x = x_lo_k + u1 (x_hi_k - x_lo_k),
rotated to the sensor point's azimuth, so the sampling density on the plane is
    p_A = 1 / A_k,  A_k = S (y_{k+1} - y_k)(x_hi_k - x_lo_k).
The irradiance estimate of a ray from the sensor point towards it is (core.pupil)
    L cos^4(theta) A_k / dz^2,   dz = z_p - z_sensor,
whatever the slabs (they only need to cover the passing rays), so the image is unbiased and
only rays aimed at a slab's corners are wasted. The occupancy is traced with the circle
bounding the stop shape: rotating a band to a sensor point's azimuth must not rotate the
blades. A band that no ray passes (beyond a fisheye's image circle) has zero-area slabs:
weight 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .aperture import aperture_key
from .lru import cache
from .pupil import PupilSamples, RearPupilSampler
from .rays import Rays

BANDS = 32
GRID = 64
SLABS = 32


@dataclass(frozen=True)
class SlabPupil:
    """Slab tables per band of sensor radius (module docstring)."""

    plane_z: float              # lens-space z of the sampling plane (mm)
    sensor_z: float             # the sensor plane rays start on
    film_radius: float          # sensor radius the bands cover (mm)
    y: np.ndarray               # (bands, slabs + 1) slab edges in the band frame
    x_lo: np.ndarray            # (bands, slabs)
    x_hi: np.ndarray            # (bands, slabs)

    @property
    def bands(self) -> int:
        return self.y.shape[0]

    @property
    def slabs(self) -> int:
        return self.x_lo.shape[1]

    def directions(self, sx, sy, u1, u2, sensor_z: float | None = None):
        """(unit directions (3, N), weight cos^4 A_k / dz^2 (N,)) from sensor points (sx, sy)
        on the plane `sensor_z` (None: the table's), as the shader's nl_pupil_sample."""
        sx, sy, u1, u2 = (np.asarray(a, dtype=np.float64) for a in (sx, sy, u1, u2))
        r = np.hypot(sx, sy)
        band = np.clip((r * (self.bands / self.film_radius)).astype(np.int64), 0,
                       self.bands - 1)
        s = np.clip(u2, 0.0, np.nextafter(1.0, 0.0)) * self.slabs
        k = np.minimum(s.astype(np.int64), self.slabs - 1)
        ya, yb = self.y[band, k], self.y[band, k + 1]
        xa, xb = self.x_lo[band, k], self.x_hi[band, k]
        ly = ya + (s - k) * (yb - ya)
        lx = xa + u1 * (xb - xa)
        area = self.slabs * (yb - ya) * (xb - xa)
        safe = np.where(r > 0, r, 1.0)
        c = np.where(r > 0, sx / safe, 1.0)
        sn = np.where(r > 0, sy / safe, 0.0)
        dz = self.plane_z - (self.sensor_z if sensor_z is None else float(sensor_z))
        d = np.stack([c * lx - sn * ly - sx, sn * lx + c * ly - sy, np.full_like(sx, dz)])
        d /= np.linalg.norm(d, axis=0)
        return d, area * d[2] ** 4 / (dz * dz)

    def sample(self, sensor_x, sensor_y, u1, u2, u3, wavelength_nm) -> PupilSamples:
        """The samplers' interface (core.pupil): one ray per sensor point (u3 unused)."""
        sx = np.asarray(sensor_x, dtype=np.float64)
        d, w = self.directions(sx, sensor_y, u1, u2)
        o = np.stack([sx, np.asarray(sensor_y, dtype=np.float64) * np.ones_like(sx),
                      np.full_like(sx, self.sensor_z)])
        wl = np.broadcast_to(np.asarray(wavelength_nm, dtype=np.float64), sx.shape).copy()
        return PupilSamples(Rays(o, d, wl), w)


def _slabs(occ: np.ndarray, origin, cell, slabs: int):
    """Slab edges and x-extents of one band's occupancy grid (occ[iy, ix])."""
    rows = np.flatnonzero(occ.any(axis=1))
    if rows.size == 0:
        return np.zeros(slabs + 1), np.zeros(slabs), np.zeros(slabs)
    x0, y0 = origin
    cx, cy = cell
    # Occupied area per grid row, over the continuous y of the grid's row edges.
    counts = occ.sum(axis=1).astype(np.float64)
    edges = y0 + cy * np.arange(occ.shape[0] + 1)
    cdf = np.concatenate([[0.0], np.cumsum(counts)])
    cdf /= cdf[-1]
    y = np.interp(np.linspace(0.0, 1.0, slabs + 1), cdf, edges)
    y[0], y[-1] = edges[rows[0]], edges[rows[-1] + 1]
    lo = np.empty(slabs)
    hi = np.empty(slabs)
    for k in range(slabs):
        r0 = int(np.clip(np.floor((y[k] - y0) / cy), 0, occ.shape[0] - 1))
        r1 = int(np.clip(np.ceil((y[k + 1] - y0) / cy) - 1, r0, occ.shape[0] - 1))
        cols = np.flatnonzero(occ[r0:r1 + 1].any(axis=0))
        if cols.size == 0:           # a slab between occupied rows (never for convex pupils)
            lo[k] = hi[k] = 0.0
            continue
        lo[k] = x0 + cx * (cols[0] - 0.5)
        hi[k] = x0 + cx * (cols[-1] + 1.5)
    return y, lo, hi


_CACHE = cache(16)


def slab_pupil(lens, sensor_z: float, film_radius: float, stop_radius: float, aperture=None,
               *, bands: int | None = None, grid: int | None = None, slabs: int | None = None,
               also_sensor_z=(), passes=None, plane=None) -> SlabPupil:
    """The slab tables of a lens at one sensor plane and stop (cached by value). bands, grid,
    slabs: None = the module's BANDS, GRID, SLABS. also_sensor_z: further sensor planes the
    slabs must cover (a camera whose focus moves). passes, plane: a lens known only by its
    learned model (RearPupilSampler's)."""
    bands = BANDS if bands is None else bands
    grid = GRID if grid is None else grid
    slabs = SLABS if slabs is None else slabs
    bound = 1.0 if aperture is None else float(aperture.bounding_radius())
    extra = tuple(float(z) for z in also_sensor_z)
    key = (lens.content_hash(), float(sensor_z), float(film_radius), float(stop_radius), bound,
           aperture_key(aperture), int(bands), int(grid), int(slabs), extra)
    table = _CACHE.get_lru(key)
    if table is None:
        sampler = RearPupilSampler(lens, film_radius, sensor_z=sensor_z,
                                   stop_radius=stop_radius * bound, aperture=None, bands=bands,
                                   grid=grid, radii_per_band=3, also_sensor_z=extra,
                                   passes=passes, plane=plane)
        y = np.zeros((bands, slabs + 1))
        lo = np.zeros((bands, slabs))
        hi = np.zeros((bands, slabs))
        for b in range(bands):
            y[b], lo[b], hi[b] = _slabs(sampler.occupied[b], sampler.origin[b],
                                        sampler.cell[b], slabs)
        table = _CACHE.put(key, SlabPupil(float(sampler.plane_z), float(sensor_z),
                                          float(film_radius), y, lo, hi))
    return table
