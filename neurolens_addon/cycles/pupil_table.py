"""Pupil-aware camera-ray sampling for the shader: per sensor-radius band, where rays pass.

core.pupil.RearPupilSampler finds, for each band of sensor radius (the sensor point on +x), the
cells of a grid on its sampling plane z_p crossed by rays that pass the whole lens. The shader
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
only rays aimed at a slab's corners are wasted. The weight is divided by its mean over the
rays that pass at the image centre (W_ref), so the centre has throughput 1 at any f-number, as
Blender's cameras do; vignetting and the cos^4 fall-off off axis stay real.
A band that no ray passes (beyond a fisheye's image circle) has zero-area slabs: weight 0.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from ..core.errors import LensError
from ..core.prescription import WAVELENGTH_D_NM
from ..core.pupil import RearPupilSampler
from ..core.rays import Rays
from ..core.trace import trace
from ..core.oslfmt import float_array, flt, indent

BANDS = 32
GRID = 64
SLABS = 32
REFERENCE_SAMPLES = 64          # per axis, on-axis normalisation


@dataclass(frozen=True)
class PupilTable:
    plane_z: float              # lens-space z of the sampling plane (mm)
    sensor_z: float
    film_radius: float          # sensor radius the bands cover (mm)
    y: np.ndarray               # (bands, slabs + 1) slab edges in the band frame
    x_lo: np.ndarray            # (bands, slabs)
    x_hi: np.ndarray            # (bands, slabs)
    inv_w_ref: float            # 1 / mean on-axis weight of passing rays

    @property
    def bands(self) -> int:
        return self.y.shape[0]

    @property
    def slabs(self) -> int:
        return self.x_lo.shape[1]


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


def sample(table: PupilTable, sx, sy, u1, u2, sensor_z: float | None = None,
           normalised: bool = True):
    """numpy twin of the shader's nl_pupil_sample: (unit directions (3, N), weight (N,)).
    sensor_z: the sensor plane the rays start on (None: the table's); normalised: times the
    table's on-axis normalisation (a camera that follows its focus normalises by itself)."""
    sx, sy, u1, u2 = (np.asarray(a, dtype=np.float64) for a in (sx, sy, u1, u2))
    r = np.hypot(sx, sy)
    band = np.clip((r * (table.bands / table.film_radius)).astype(np.int64), 0, table.bands - 1)
    s = np.clip(u2, 0.0, np.nextafter(1.0, 0.0)) * table.slabs
    k = np.minimum(s.astype(np.int64), table.slabs - 1)
    ya, yb = table.y[band, k], table.y[band, k + 1]
    xa, xb = table.x_lo[band, k], table.x_hi[band, k]
    ly = ya + (s - k) * (yb - ya)
    lx = xa + u1 * (xb - xa)
    area = table.slabs * (yb - ya) * (xb - xa)
    safe = np.where(r > 0, r, 1.0)
    c = np.where(r > 0, sx / safe, 1.0)
    sn = np.where(r > 0, sy / safe, 0.0)
    dz = table.plane_z - (table.sensor_z if sensor_z is None else float(sensor_z))
    d = np.stack([c * lx - sn * ly - sx, sn * lx + c * ly - sy, np.full_like(sx, dz)])
    d /= np.linalg.norm(d, axis=0)
    w = area * d[2] ** 4 / (dz * dz) * (table.inv_w_ref if normalised else 1.0)
    return d, w


def aperture_key(aperture):
    """A value key of an aperture shape (the cache must not depend on object identity)."""
    from ..core.aperture import ImageMaskAperture, PolygonAperture
    if aperture is None:
        return ("circle",)
    if isinstance(aperture, PolygonAperture):
        return ("polygon", aperture.blades, aperture.rotation_deg, aperture.curvature)
    if isinstance(aperture, ImageMaskAperture):
        m = np.ascontiguousarray(aperture.mask)
        return ("mask", m.shape, hashlib.sha256(m.tobytes()).hexdigest())
    return (aperture.kind,)


_CACHE: dict = {}
_CACHE_SIZE = 16


def build_pupil_table(lens, sensor_z: float, film_radius: float, stop_radius: float,
                      aperture=None, *, bands: int | None = None, grid: int | None = None,
                      slabs: int | None = None, also_sensor_z=()) -> PupilTable:
    """The slab table of a lens at one focus and stop (cached by value: the same inputs reuse
    it). The occupancy is traced with the circle bounding the aperture shape (rotating the
    band to a sensor point's azimuth must not rotate the blades); the on-axis normalisation
    with the shape itself. bands, grid, slabs: None = the module's BANDS, GRID, SLABS.
    also_sensor_z: further sensor planes the slabs must cover (a focus that moves)."""
    bands = BANDS if bands is None else bands
    grid = GRID if grid is None else grid
    slabs = SLABS if slabs is None else slabs
    bound = 1.0 if aperture is None else float(aperture.bounding_radius())
    extra = tuple(float(z) for z in also_sensor_z)
    key = (lens, float(sensor_z), float(film_radius), float(stop_radius), bound,
           aperture_key(aperture), int(bands), int(grid), int(slabs), extra)
    table = _CACHE.get(key)
    if table is None:
        table = _build(lens, float(sensor_z), float(film_radius), float(stop_radius), bound,
                       aperture, int(bands), int(grid), int(slabs), extra)
        if len(_CACHE) >= _CACHE_SIZE:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = table
    return table


def _build(lens, sensor_z: float, film_radius: float, stop_radius: float, bound: float,
           aperture, bands: int, grid: int, slabs: int, extra=()) -> PupilTable:
    sampler = RearPupilSampler(lens, film_radius, sensor_z=sensor_z,
                               stop_radius=stop_radius * bound, aperture=None, bands=bands,
                               grid=grid, radii_per_band=3, also_sensor_z=extra)
    y = np.zeros((bands, slabs + 1))
    lo = np.zeros((bands, slabs))
    hi = np.zeros((bands, slabs))
    for b in range(bands):
        y[b], lo[b], hi[b] = _slabs(sampler.occupied[b], sampler.origin[b], sampler.cell[b], slabs)
    table = PupilTable(float(sampler.plane_z), float(sensor_z), float(film_radius), y, lo, hi, 1.0)
    mean = centre_weight(table, lens, sensor_z, stop_radius, aperture)
    return PupilTable(table.plane_z, table.sensor_z, table.film_radius, y, lo, hi, 1.0 / mean)


def centre_weight(table: PupilTable, lens, sensor_z: float, stop_radius: float,
                  aperture=None) -> float:
    """Mean un-normalised weight of the rays that pass from the image centre, on the sensor
    plane `sensor_z` at stop radius `stop_radius`: its inverse makes the centre's throughput 1."""
    n = REFERENCE_SAMPLES
    g = (np.arange(n) + 0.5) / n
    u1, u2 = (a.ravel() for a in np.meshgrid(g, g))
    zeros = np.zeros_like(u1)
    d, w = sample(table, zeros, zeros, u1, u2, sensor_z=sensor_z, normalised=False)
    o = np.stack([zeros, zeros, np.full_like(u1, sensor_z)])
    res = trace(lens, Rays(o, d, np.full(u1.size, WAVELENGTH_D_NM)), from_sensor=True,
                stop_radius=stop_radius, aperture=aperture, threads=1)
    mean = float(np.mean(w * res.valid))
    if not mean > 0.0:
        raise LensError(f"lens '{lens.name}': no ray from the sensor centre passes the lens at "
                        f"sensor z = {sensor_z:g} mm and stop radius {stop_radius:g} mm",
                        path=lens.path)
    return mean


def pupil_osl(table: PupilTable, follow: bool = False) -> list[str]:
    """OSL: the slab tables and `nl_pupil_sample(sx, sy, u1, u2, dir, weight)`; with `follow`
    the sensor plane is an argument, `nl_pupil_sample(sx, sy, z_s, u1, u2, dir, weight)`, and
    the weight is not normalised (the caller does it for its focus and stop)."""
    B, S = table.bands, table.slabs
    dz = table.plane_z - table.sensor_z
    tables = float_array("NL_PUPIL_Y", table.y, f"slab edges y_0..y_{S} per band ({B} bands "
                                                f"of sensor radius, mm on the plane z = "
                                                f"{table.plane_z:.6g})")
    tables += float_array("NL_PUPIL_X0", table.x_lo, "slab x extent, low (mm)")
    tables += float_array("NL_PUPIL_X1", table.x_hi, "slab x extent, high (mm)")
    return [
        "// Direction from the sensor point (sx, sy) to a point of its band's slabs, and the",
        "// irradiance weight cos^4(theta) A_k / dz^2, normalised to 1 at the image centre.",
        ("int nl_pupil_sample(float sx, float sy, float z_s, float u1, float u2, output vector dir,"
         if follow else
         "int nl_pupil_sample(float sx, float sy, float u1, float u2, output vector dir,"),
        "                    output float weight)",
        "{",
    ] + indent(tables) + [
        "    float r = sqrt(sx * sx + sy * sy);",
        f"    int band = min((int)(r * {flt(B / table.film_radius)}), {B - 1});",
        f"    float s = clamp(u2, 0.0, 0.99999994) * {flt(S)};",
        f"    int k = min((int)s, {S - 1});",
        f"    int row = band * {S + 1} + k;",
        "    float ya = NL_PUPIL_Y[row];",
        "    float yb = NL_PUPIL_Y[row + 1];",
        "    float xa = NL_PUPIL_X0[row - band];",
        "    float xb = NL_PUPIL_X1[row - band];",
        f"    float area = {flt(S)} * (yb - ya) * (xb - xa);",
        "    if (area <= 0.0) return 0;",
        "    float ly = ya + (s - k) * (yb - ya);",
        "    float lx = xa + u1 * (xb - xa);",
        "    // rotate the band frame (sensor point on +x) to the sensor point's azimuth",
        "    float c = 1.0;",
        "    float sn = 0.0;",
        "    if (r > 0.0) { float inv_r = 1.0 / r; c = sx * inv_r; sn = sy * inv_r; }",
    ] + ([f"    float dz = {flt(table.plane_z)} - z_s;",
          "    vector v = vector(c * lx - sn * ly - sx, sn * lx + c * ly - sy, dz);",
          "    float inv_len = 1.0 / sqrt(dot(v, v));",
          "    dir = v * inv_len;",
          "    float cz2 = dz * dz * inv_len * inv_len;",
          "    weight = area * cz2 * cz2 / (dz * dz);"] if follow else [
        f"    vector v = vector(c * lx - sn * ly - sx, sn * lx + c * ly - sy, {flt(dz)});",
        "    float inv_len = 1.0 / sqrt(dot(v, v));",
        "    dir = v * inv_len;",
        f"    float cz2 = {flt(dz * dz)} * inv_len * inv_len;",
        f"    weight = area * cz2 * cz2 * {flt(table.inv_w_ref / (dz * dz))};"]) + [
        "    return 1;",
        "}",
    ]
