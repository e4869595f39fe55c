"""Sampling camera rays that pass the lens: rear-pupil bounds per sensor radius.

A sensor point sees the lens through an exit pupil whose shape changes across the field
(a disc on axis, a cat's eye off axis, clipped by the stop shape). Sampling the whole rear
element wastes most rays at small apertures, and pbrt's bounding boxes still waste the corners
(a box round a disc keeps pi/4 of its samples). We store, per radial band of sensor radius, an
occupancy grid on the plane of the rear vertex: cells crossed by at least one valid ray traced
from any of several sensor radii in the band (corners and centres of the cells are tested, so
a cell partly inside is kept). Sampling picks an occupied cell uniformly, a point uniformly in
it, and rotates the result to the sensor point's azimuth (the lens is rotationally symmetric;
a rotated aperture shape is handled by tracing the band's grid for the rotation used at
render time, see `RearPupilSampler.sample`).

The sampling density on the rear plane is uniform over the occupied cells:
    p_A = 1 / (n_occupied * cell_area),
and a camera-ray estimate of the irradiance on the sensor E = int L cos(t) cos(t') / r^2 dA is
    L * cos(t) * cos(t') / (r^2 p_A) = L * cos^4(t) / (dz^2 p_A)
with t the angle to the axis and dz the sensor-to-plane distance (both planes are normal to z).

The centre irradiance (centre_irradiance): with L = 1 the film centre receives
    E_0 = int V(A) T(A) cos^4(t) / dz^2 dA
over the plane (V: the ray aimed at A passes the lens; T: its coating transmittance, 1 without
a coating), the projected solid angle of the passing directions whatever plane is used. Every
renderer divides its camera weights by E_0, so the film centre reads the scene's radiance at
any focus, stop and zoom. It is integrated by the midpoint rule: a coarse grid over the rear
disc finds the box of passing aim points, and CENTRE_GRID x CENTRE_GRID cells over that box
(grown by one and a half coarse cells) sum V T cos^4 / dz^2 times the cell area.

The rear disc (rear_disc, disc_rays, RearDiscSampler): a disc on the rear vertex's plane that
every ray reaching the rear surface within its semi-diameter crosses; rays aimed uniformly
over it, p_A = 1 / (pi R^2), reach every part of the rear element (ghosts, anamorphic lenses).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .lru import cache
from .prescription import WAVELENGTH_D_NM, Lens
from .rays import Rays
from .trace import trace


@dataclass
class PupilSamples:
    rays: Rays               # from the sensor point towards the rear plane (unit directions)
    weight: np.ndarray       # cos^4 / (dz^2 p_A), the irradiance estimator's weight


def sampling_plane(lens: Lens, sensor_z: float, catalog=None) -> tuple[float, float]:
    """(z, half width) of the plane to aim sensor-side rays at: the paraxial exit pupil, where
    every film point's bundle is the stop's image near the axis, or the rear vertex when the
    exit pupil lies behind the sensor; half width 1.5 x the larger of the pupil's and the rear
    element's radii."""
    from .paraxial import paraxial_data
    xp = paraxial_data(lens, catalog=catalog).exit_pupil
    if xp.z_mm > sensor_z + 0.2 * lens.total_track_mm:
        return float(xp.z_mm), 1.5 * max(0.5 * xp.diameter_mm,
                                         lens.surfaces[-1].semi_diameter_mm)
    return float(lens.rear_vertex_z), 1.5 * lens.surfaces[-1].semi_diameter_mm


def exact_passes(lens: Lens, **trace_kw):
    """Which camera rays (Rays from the sensor) pass the exact lens: the pass test of
    RearPupilSampler and centre_irradiance for a lens with a prescription."""
    def passes(rays: Rays) -> np.ndarray:
        return trace(lens, rays, from_sensor=True, **trace_kw).valid
    return passes


#: the engine's sampler: bands of sensor radius, and each band's occupancy grid side
SAMPLER_BANDS = 32
SAMPLER_GRID = 64
#: the side of the coarse grid over the wide square that finds each band's passing box
SAMPLER_COARSE_GRID = 48


class RearPupilSampler:
    """Occupancy grids of the rays that pass the whole lens, per band of sensor radius.

    The grids lie on the paraxial exit-pupil plane (where every sensor point's bundle is the
    stop's image, centred near the axis), or on the rear vertex when the exit pupil is behind
    the sensor. Each band first finds the bounding box of passing rays with a coarse grid over
    a wide square, then fills a fine grid inside that box, so the cells stay small relative to
    the bundle whatever the lens (a cover glass 1 mm from the sensor, a tiny fisheye pupil).
    """

    def __init__(self, lens: Lens | None, film_radius_mm: float, *, sensor_z: float = 0.0,
                 stop_radius: float | None = None, aperture=None, bands: int | None = None,
                 grid: int | None = None, radii_per_band: int = 3,
                 wavelength_nm: float = WAVELENGTH_D_NM, catalog=None, also_sensor_z=(),
                 passes=None, plane=None):
        """bands, grid: None = the module's SAMPLER_BANDS, SAMPLER_GRID. also_sensor_z: further
        sensor planes whose passing rays the grids must hold too (a camera whose focus moves);
        the sampler itself still starts rays at `sensor_z`. A lens known only by its learned
        model (camera.table_lens) gives `passes` (Rays -> (N,) bool: which pass) and `plane`
        ((z, half width) of the square searched) in place of `lens`."""
        self.lens = lens
        self.film_radius = float(film_radius_mm)
        self.sensor_z = float(sensor_z)
        self._planes = np.unique(np.array([self.sensor_z] + [float(z) for z in also_sensor_z]))
        self.bands = int(SAMPLER_BANDS if bands is None else bands)
        self.grid = int(SAMPLER_GRID if grid is None else grid)
        if plane is None:
            self.plane_z, wide = sampling_plane(lens, self.sensor_z, catalog)
            wide = max(wide, 1.5 * self.film_radius * float(np.max(self.plane_z - self._planes))
                       / max(lens.total_track_mm, 1e-9))
        else:
            self.plane_z, wide = float(plane[0]), float(plane[1])
        self.wide = wide
        self._passes = passes or exact_passes(lens, stop_radius=stop_radius, aperture=aperture,
                                              catalog=catalog)
        self._wl = wavelength_nm
        self.origin = np.zeros((self.bands, 2))      # lower-left corner of each band's grid
        self.cell = np.zeros((self.bands, 2))        # cell size (x, y) per band
        self.occupied = np.zeros((self.bands, self.grid, self.grid), dtype=bool)
        band_w = self.film_radius / self.bands
        for b in range(self.bands):
            radii = b * band_w + band_w * np.linspace(0.0, 1.0, radii_per_band)
            c = SAMPLER_COARSE_GRID
            box = self._passing_box(radii, -wide, -wide, 2 * wide / c, 2 * wide / c, c)
            if box is None:
                continue
            (x0, x1), (y0, y1) = box
            g = self.grid
            cx, cy = (x1 - x0) / g, (y1 - y0) / g
            self.origin[b] = (x0, y0)
            self.cell[b] = (cx, cy)
            self.occupied[b] = self._occupancy(radii, x0, y0, cx, cy, g)
        self._cells = [np.flatnonzero(self.occupied[b]) for b in range(self.bands)]
        # Sampling tables, fixed once the grids are: cells per band, each band's offset into
        # the concatenated cell list.
        self._counts = np.array([c.size for c in self._cells])
        self._offsets = np.concatenate([[0], np.cumsum(self._counts)])
        self._flat = (np.concatenate(self._cells) if self._counts.sum()
                      else np.zeros(1, dtype=np.int64))

    def sampling_tables(self):
        """(occupied cells per band (B,), each band's offset into the concatenated cell list
        (B + 1,), that list of flat cell indices): what `sample` draws from."""
        return self._counts, self._offsets, self._flat

    def _ok(self, radii, px, py):
        """Which aim points (px, py) on the plane pass, from any of the sensor radii (on any
        of the sensor planes)."""
        m = px.size
        sx = np.repeat(radii, m)
        tx, ty = np.tile(px, radii.size), np.tile(py, radii.size)
        ok = np.zeros(m, dtype=bool)
        for z in self._planes:
            o = np.stack([sx, np.zeros_like(sx), np.full_like(sx, z)])
            d = np.stack([tx - sx, ty, np.full_like(sx, self.plane_z - z)])
            d /= np.linalg.norm(d, axis=0)
            valid = self._passes(Rays(o, d, np.full(sx.size, self._wl)))
            ok |= valid.reshape(radii.size, m).any(axis=0)
        return ok

    def _occupancy(self, radii, x0, y0, cx, cy, g):
        ex, ey = np.meshgrid(x0 + cx * np.arange(g + 1), y0 + cy * np.arange(g + 1), indexing="xy")
        mx, my = np.meshgrid(x0 + cx * (np.arange(g) + 0.5), y0 + cy * (np.arange(g) + 0.5),
                             indexing="xy")
        ok = self._ok(radii, np.concatenate([ex.ravel(), mx.ravel()]),
                      np.concatenate([ey.ravel(), my.ravel()]))
        corner = ok[:(g + 1) ** 2].reshape(g + 1, g + 1)
        centre = ok[(g + 1) ** 2:].reshape(g, g)
        return (centre | corner[:-1, :-1] | corner[1:, :-1] | corner[:-1, 1:] | corner[1:, 1:])

    def _passing_box(self, radii, x0, y0, cx, cy, g):
        """Bounding box (with one coarse cell of margin) of the cells that pass."""
        occ = self._occupancy(radii, x0, y0, cx, cy, g)
        if not occ.any():
            return None
        iy, ix = np.nonzero(occ)
        return ((x0 + cx * (ix.min() - 1), x0 + cx * (ix.max() + 2)),
                (y0 + cy * (iy.min() - 1), y0 + cy * (iy.max() + 2)))

    def aim_radius(self) -> float:
        """Radius of a disc on the sampling plane, about the axis, holding every occupied cell
        of every band (bands are stored with the sensor point on +x; rotation keeps radii)."""
        best = 0.0
        for b in range(self.bands):
            occ = self.occupied[b]
            if not occ.any():
                continue
            iy, ix = np.nonzero(occ)
            for cx in (ix, ix + 1):
                for cy in (iy, iy + 1):
                    x = self.origin[b, 0] + cx * self.cell[b, 0]
                    y = self.origin[b, 1] + cy * self.cell[b, 1]
                    best = max(best, float(np.hypot(x, y).max()))
        return best

    def band_of(self, r: np.ndarray) -> np.ndarray:
        return np.clip((r / self.film_radius * self.bands).astype(np.int64), 0, self.bands - 1)

    def occupied_area(self, band: int) -> float:
        return self._cells[band].size * self.cell[band, 0] * self.cell[band, 1]

    def cell_index(self, band: int, x, y):
        """(iy, ix, inside) of band-frame points on the plane."""
        ix = np.floor((x - self.origin[band, 0]) / self.cell[band, 0]).astype(np.int64)
        iy = np.floor((y - self.origin[band, 1]) / self.cell[band, 1]).astype(np.int64)
        inside = (ix >= 0) & (ix < self.grid) & (iy >= 0) & (iy < self.grid)
        return np.clip(iy, 0, self.grid - 1), np.clip(ix, 0, self.grid - 1), inside

    def sample(self, sensor_x, sensor_y, u1, u2, u3, wavelength_nm) -> PupilSamples:
        """One ray per sensor point, aimed at a uniform point of its band's occupied cells."""
        sx = np.asarray(sensor_x, dtype=np.float64)
        sy = np.asarray(sensor_y, dtype=np.float64)
        r = np.hypot(sx, sy)
        band = self.band_of(r)
        n_occ = self._counts[band]
        pick = np.minimum((np.asarray(u1) * n_occ).astype(np.int64), np.maximum(n_occ - 1, 0))
        # Flat index of the chosen cell in the bands' concatenated cell lists.
        flat = self._flat
        cell = flat[np.minimum(self._offsets[band] + pick, flat.size - 1)]
        iy, ix = np.divmod(cell, self.grid)
        # Point in the band's frame (sensor point on +x), then rotate to the point's azimuth.
        cx, cy = self.cell[band, 0], self.cell[band, 1]
        lx = self.origin[band, 0] + (ix + np.asarray(u2)) * cx
        ly = self.origin[band, 1] + (iy + np.asarray(u3)) * cy
        with np.errstate(invalid="ignore", divide="ignore"):
            cphi = np.where(r > 0, sx / np.where(r > 0, r, 1.0), 1.0)
            sphi = np.where(r > 0, sy / np.where(r > 0, r, 1.0), 0.0)
        tx = cphi * lx - sphi * ly
        ty = sphi * lx + cphi * ly
        dz = self.plane_z - self.sensor_z
        d = np.stack([tx - sx, ty - sy, np.full_like(sx, dz)])
        dist = np.linalg.norm(d, axis=0)
        d /= dist
        area = np.maximum(n_occ, 1) * cx * cy
        pdf_a = np.where(n_occ > 0, 1.0 / np.where(area > 0, area, 1.0), 0.0)
        cos4 = d[2] ** 4
        weight = np.where(n_occ > 0, cos4 / (dz * dz * np.where(pdf_a > 0, pdf_a, 1.0)), 0.0)
        o = np.stack([sx, sy, np.full_like(sx, self.sensor_z)])
        return PupilSamples(Rays(o, d, np.broadcast_to(np.asarray(wavelength_nm, dtype=np.float64),
                                                       sx.shape).copy()), weight)


def valid_fraction(lens: Lens, sampler: RearPupilSampler, sensor_x: float, sensor_y: float,
                   n: int = 20000, *, stop_radius=None, aperture=None, seed: int = 0,
                   wavelength_nm: float = WAVELENGTH_D_NM) -> float:
    """Fraction of rays sampled for one sensor point that leave the lens valid."""
    rng = np.random.default_rng(seed)
    u = rng.random((3, n))
    s = sampler.sample(np.full(n, sensor_x), np.full(n, sensor_y), u[0], u[1], u[2], wavelength_nm)
    res = trace(lens, s.rays, from_sensor=True, stop_radius=stop_radius, aperture=aperture)
    return res.valid_fraction


def rear_disc(lens: Lens) -> tuple[float, float]:
    """(z, radius) of a disc on the rear vertex's plane that every ray reaching the rear
    surface within its semi-diameter crosses from a sensor point behind it (the surface's
    sag at its rim added to its semi-diameter, with a margin)."""
    sd = lens.surfaces[-1].semi_diameter_mm
    rim = float(np.nan_to_num(np.abs(lens.surfaces[-1].shape.sag(0.0, sd, clamp=True))))
    return float(lens.rear_vertex_z), 1.05 * (sd + 2.0 * rim)


def disc_rays(lens: Lens, x, y, sensor_z: float, u1, u2, wavelength_nm):
    """Camera rays from sensor points (x, y) aimed at the uniform point (R sqrt(u1), angle
    2 pi u2) of rear_disc, and their irradiance weights cos^4(t) / (dz^2 p_A), p_A =
    1 / (pi R^2) (module docstring)."""
    z_p, rad = rear_disc(lens)
    r = rad * np.sqrt(np.asarray(u1, dtype=np.float64))
    phi = 2.0 * np.pi * np.asarray(u2, dtype=np.float64)
    n = r.shape[0]
    dz = z_p - sensor_z
    d = np.stack([r * np.cos(phi) - x, r * np.sin(phi) - y, np.full(n, dz)])
    d /= np.linalg.norm(d, axis=0)
    o = np.stack([np.asarray(x, float) * np.ones(n), np.asarray(y, float) * np.ones(n),
                  np.full(n, float(sensor_z))])
    weight = d[2] ** 4 / (dz * dz) * (np.pi * rad * rad)
    return Rays(o, d, np.asarray(wavelength_nm, dtype=np.float64) * np.ones(n)), weight


#: cells per side of the grid the centre irradiance is summed over (module docstring)
CENTRE_GRID = 160
#: cells per side of the coarse grid that finds the box of passing aim points
_COARSE_GRID = 48


def _centre_sum(transmitted, sensor_z, z_p, x0, x1, y0, y1, g):
    """(sum of V T cos^4 / dz^2 times the cell area, passing cell centres (2, M)) over a
    g x g midpoint grid of [x0, x1] x [y0, y1] on the plane z_p; `transmitted(Rays)` gives
    each ray's V T."""
    cx, cy = (x1 - x0) / g, (y1 - y0) / g
    gx, gy = np.meshgrid(x0 + cx * (np.arange(g) + 0.5), y0 + cy * (np.arange(g) + 0.5))
    px, py = gx.ravel(), gy.ravel()
    dz = z_p - sensor_z
    d = np.stack([px, py, np.full(px.size, dz)])
    d /= np.linalg.norm(d, axis=0)
    o = np.stack([np.zeros(px.size), np.zeros(px.size), np.full(px.size, float(sensor_z))])
    t = transmitted(Rays(o, d, np.full(px.size, WAVELENGTH_D_NM)))
    total = float(np.sum(t * d[2] ** 4)) / (dz * dz) * cx * cy
    return total, np.stack([px[t > 0], py[t > 0]])


def _exact_transmitted(lens, **trace_kw):
    def transmitted(rays):
        res = trace(lens, rays, from_sensor=True, **trace_kw)
        return res.weight if res.weight is not None else res.valid.astype(np.float64)
    return transmitted


def centre_irradiance(lens: Lens | None, *, sensor_z: float, stop_radius: float | None = None,
                      aperture=None, coating=None, grid: int = CENTRE_GRID, passes=None,
                      disc=None, name: str | None = None) -> float:
    """E_0: the irradiance (L = 1) the lens puts on the film centre from the sensor plane
    `sensor_z` at stop radius `stop_radius` with the stop shape `aperture`, weighted by the
    coating's transmittance when given (module docstring). A lens known only by its learned
    model gives `passes` (RearPupilSampler's), `disc` ((z, radius) searched) and its `name`
    in place of `lens`. Raises LensError when no ray from the centre passes."""
    from .errors import LensError
    if passes is None:
        z_p, rad = rear_disc(lens)
        kw = dict(stop_radius=stop_radius, aperture=aperture, threads=1)
        search = _exact_transmitted(lens, **kw)
        transmitted = _exact_transmitted(lens, coating=coating, **kw)
    else:
        z_p, rad = disc

        def search(rays):
            return passes(rays).astype(np.float64)
        transmitted = search
    half = rad
    for _ in range(4):           # a pupil smaller than a coarse cell: look closer to the axis
        _, hits = _centre_sum(search, sensor_z, z_p, -half, half, -half, half, _COARSE_GRID)
        if hits.size:
            break
        half /= 8.0
    else:
        stop = "" if lens is None else (
            f" and stop radius {lens.stop_radius_mm if stop_radius is None else stop_radius:g} mm")
        raise LensError(f"lens '{name if lens is None else lens.name}': no ray from the film "
                        f"centre passes the lens at sensor z = {sensor_z:g} mm{stop}",
                        path=None if lens is None else lens.path)
    margin = 1.5 * 2.0 * half / _COARSE_GRID
    x0, x1 = hits[0].min() - margin, hits[0].max() + margin
    y0, y1 = hits[1].min() - margin, hits[1].max() + margin
    total, _ = _centre_sum(transmitted, sensor_z, z_p, x0, x1, y0, y1, grid)
    return total


_CENTRE = cache(256)


def cached_centre_irradiance(lens: Lens, *, sensor_z: float, stop_radius: float, aperture,
                             coating=None) -> float:
    """centre_irradiance, cached by value (lens content, sensor plane, stop, shape, coating):
    the frames of an animation and both renderers share it."""
    from .aperture import aperture_key
    key = (lens.content_hash(), round(float(sensor_z), 9), round(float(stop_radius), 9),
           aperture_key(aperture), repr(coating))
    hit = _CENTRE.get_lru(key)
    if hit is None:
        hit = _CENTRE.put(key, centre_irradiance(lens, sensor_z=sensor_z,
                                                 stop_radius=stop_radius, aperture=aperture,
                                                 coating=coating))
    return hit


class RearDiscSampler:
    """Rays aimed uniformly over rear_disc, with the irradiance weight cos^4 / (dz^2 p_A):
    unbiased for any lens, rotationally symmetric or not (the occupancy grids of
    RearPupilSampler rotate one band to every azimuth, which an anamorphic lens does not
    allow), at the cost of the rays that miss the pupil (a fifth to a half pass)."""

    def __init__(self, lens: Lens, sensor_z: float = 0.0):
        self.lens = lens
        self.sensor_z = float(sensor_z)
        self.plane_z, self.radius = rear_disc(lens)

    def sample(self, sensor_x, sensor_y, u1, u2, u3, wavelength_nm) -> PupilSamples:
        x = np.asarray(sensor_x, dtype=np.float64)
        wl = np.broadcast_to(np.asarray(wavelength_nm, dtype=np.float64), x.shape)
        rays, weight = disc_rays(self.lens, x, np.asarray(sensor_y, dtype=np.float64),
                                 self.sensor_z, u1, u2, wl)
        return PupilSamples(rays, weight)


def camera_ray_sampler(lens: Lens, film_radius_mm: float, *, sensor_z: float = 0.0, **grids):
    """The sampler of a lens's camera rays: RearPupilSampler (its radial grids, `grids` its
    keyword options) for a lens of revolution, RearDiscSampler for an anamorphic lens (the
    grids rotate one band to every azimuth, which such a lens does not allow)."""
    if lens.anamorphic:
        return RearDiscSampler(lens, sensor_z)
    return RearPupilSampler(lens, film_radius_mm, sensor_z=sensor_z, **grids)
