"""Camera samples compiled (numba): the two numpy passes of camera_rays.CameraRayGenerator
around the lens, each one loop.

sensor_rays, per camera sample: its six uniforms (pixel jitter and wavelength stratified by
the R2 and golden-ratio sequences, three aperture hashes), its film point, its wavelength(s)
and colour weights (one per channel drawn from s_c, one from the whole sensor, or the d line),
and the sensor-side ray aimed by the derived camera's sampler (core.pupil: a uniform point of
the band's occupied cells, RearPupilSampler, or of the rear element's disc, RearDiscSampler)
with its irradiance weight; with three colour rays the sample's three rows share all but the
wavelength.
to_world, per lens ray: valid where the lens passed it with a positive weight, its
illumination g V / g_0 and colour weights, and the valid rays moved from lens space (mm) to
camera and world space, written compacted in row order.
camera_rays' module docstring and core.sensor_response / core.pupil state the equations; the
numpy code there is the reference (tests/engine/test_camera_kernels.py); differences are
rounding only.
"""

from __future__ import annotations

import math

import numpy as np

from ..core import jit
from ..core.pupil import RearPupilSampler
from ..core.sensor_response import cdf_scale
from .shading_kernels import hash_one, salts

_njit = jit.njit(cache=True, nogil=True)
_inline = jit.njit(cache=True, nogil=True, inline="always")

#: sampler kinds (core.pupil)
PUPIL_GRID, REAR_DISC = 0, 1
#: wavelength modes: the d line (no dispersion), one ray from the whole sensor, one per channel
D_LINE, SENSOR, PER_CHANNEL = 0, 1, 3
_BELOW_ONE = float(np.nextafter(1.0, 0.0))


@_inline
def _frac(x):
    """np.mod(x, 1.0) of x >= 0 (exact: the integer part shares x's exponent range)."""
    return x - math.floor(x)


@_inline
def _inverse_cdf(u, knots, density, cdf, col, scale):
    """core.sensor_response.sample_linear_density of one u, density column `col`: (the
    wavelength, its knot segment j)."""
    u = 0.0 if math.isnan(u) else min(max(u, 0.0), _BELOW_ONE)
    lo, hi = 0, cdf.shape[0]
    while lo < hi:                                  # searchsorted(side="right")
        mid = (lo + hi) // 2
        if cdf[mid, col] <= u:
            lo = mid + 1
        else:
            hi = mid
    j = min(max(lo - 1, 0), knots.shape[0] - 2)
    h = knots[j + 1] - knots[j]
    a, b = density[j, col] * scale, density[j + 1, col] * scale
    r = u - cdf[j, col]
    den = a + math.sqrt(max(a * a + 2.0 * (b - a) * r / h, 0.0))
    t = 2.0 * r / den if den > 0.0 else 0.0
    return knots[j] + min(max(t, 0.0), h), j


@_inline
def _interp(x, j, knots, values, col):
    """np.interp(x, knots, values[:, col]) for x within knots j and j + 1."""
    if knots[j] == x:
        return values[j, col]
    if x >= knots[j + 1]:
        return values[j + 1, col]
    slope = (values[j + 1, col] - values[j, col]) / (knots[j + 1] - knots[j])
    return slope * (x - knots[j]) + values[j, col]


@_njit
def sensor_rays(pixel, sample, salt, dim1, film, squeeze, r2, golden, mode, knots, density,
                cdf, scale, lam_d, kind, plane, counts, offsets, flat, origin, cell, grid,
                bands, out_o, out_d, out_lam, out_w, out_spectral):
    """The sensor-side rays of camera samples (pixel, sample) (N,) into rows k i + c of out_o,
    out_d (3, k N), out_lam, out_w (k N,) and out_spectral (k N, 3), k = 3 for PER_CHANNEL
    else 1 (module docstring). salt, dim1: the hash of the jitter (x, y), wavelength and
    three aperture dimensions; film: (width_px, height_px, width_mm, height_mm, shift_x,
    shift_y); density, cdf (M, 4): the channels' responses and the sensor's, their cdf
    scales `scale` (4,); plane: (sampling plane z, sensor z, film radius, disc radius);
    counts .. bands: the RearPupilSampler's cells (unused for REAR_DISC)."""
    k = 3 if mode == PER_CHANNEL else 1
    dz = plane[0] - plane[1]
    for i in range(pixel.shape[0]):
        px, sm = pixel[i], sample[i]
        fk = np.float64(sm)
        jx = _frac(hash_one(salt[0], dim1[0], px, 0) + fk * r2[0])
        jy = _frac(hash_one(salt[1], dim1[1], px, 0) + fk * r2[1])
        uw = _frac(hash_one(salt[2], dim1[2], px, 0) + fk * golden)
        u1 = hash_one(salt[3], dim1[3], px, sm)
        u2 = hash_one(salt[4], dim1[4], px, sm)
        u3 = hash_one(salt[5], dim1[5], px, sm)
        iy, ix = px // np.int64(film[0]), px % np.int64(film[0])
        p = ((ix + jx) / film[0] - 0.5) * film[2] + film[4]
        q = ((iy + jy) / film[1] - 0.5) * film[3] + film[5]
        sx, sy = -p / squeeze, -q                   # the inverted image
        if kind == PUPIL_GRID:
            r = math.hypot(sx, sy)
            band = min(max(np.int64(r / plane[2] * bands), 0), bands - 1)
            n_occ = counts[band]
            pick = min(np.int64(u1 * n_occ), max(n_occ - 1, 0))
            c = flat[min(offsets[band] + pick, flat.shape[0] - 1)]
            cy, cx = c // grid, c % grid
            lx = origin[band, 0] + (cx + u2) * cell[band, 0]
            ly = origin[band, 1] + (cy + u3) * cell[band, 1]
            cphi, sphi = (sx / r, sy / r) if r > 0.0 else (1.0, 0.0)
            dx = cphi * lx - sphi * ly - sx
            dy = sphi * lx + cphi * ly - sy
            dist = math.sqrt(dx * dx + dy * dy + dz * dz)
            dx, dy, dzn = dx / dist, dy / dist, dz / dist
            area = max(n_occ, 1) * cell[band, 0] * cell[band, 1]
            pdf_a = 1.0 / area if (n_occ > 0 and area > 0.0) else 0.0
            w = 0.0
            if n_occ > 0 and pdf_a > 0.0:
                w = (dzn * dzn) * (dzn * dzn) / (dz * dz * pdf_a)
        else:
            rr = plane[3] * math.sqrt(u1)
            phi = 2.0 * np.pi * u2
            dx, dy = rr * math.cos(phi) - sx, rr * math.sin(phi) - sy
            dist = math.sqrt(dx * dx + dy * dy + dz * dz)
            dx, dy, dzn = dx / dist, dy / dist, dz / dist
            w = (dzn * dzn) * (dzn * dzn) / (dz * dz) * (np.pi * plane[3] * plane[3])
        for ch in range(k):
            row = k * i + ch
            out_o[0, row], out_o[1, row], out_o[2, row] = sx, sy, plane[1]
            out_d[0, row], out_d[1, row], out_d[2, row] = dx, dy, dzn
            out_w[row] = w
            if mode == PER_CHANNEL:
                out_lam[row] = _inverse_cdf(uw, knots, density, cdf, ch, scale[ch])[0]
                for c3 in range(3):
                    out_spectral[row, c3] = 1.0 if c3 == ch else 0.0
            elif mode == SENSOR:
                lam, j = _inverse_cdf(uw, knots, density, cdf, 3, scale[3])
                out_lam[row] = lam                  # within knots j and j + 1
                s0 = _interp(lam, j, knots, density, 0)
                s1 = _interp(lam, j, knots, density, 1)
                s2 = _interp(lam, j, knots, density, 2)
                total = s0 + s1 + s2
                if total > 0.0:
                    out_spectral[row, 0] = 3.0 * s0 / total
                    out_spectral[row, 1] = 3.0 * s1 / total
                    out_spectral[row, 2] = 3.0 * s2 / total
                else:
                    out_spectral[row, 0] = out_spectral[row, 1] = out_spectral[row, 2] = 1.0
            else:
                out_lam[row] = lam_d
                out_spectral[row, 0] = out_spectral[row, 1] = out_spectral[row, 2] = 1.0


@_njit
def to_world(o, d, lens_valid, sensor_weight, g0, spectral, sensor_z, per_mm, m,
             valid, illumination, weight, index, origin, direction):
    """The lens's rays (o, d (3, N) mm, lens_valid (N,)) with the sampler's weights: valid,
    illumination = g V / g_0 and weight = spectral illumination (N, 3) written for every ray,
    the valid ones' index, world origin and unit direction (m: the rigid camera matrix (4, 4),
    per_mm: scene units per mm) compacted in order; their count returned."""
    n = 0
    for r in range(o.shape[1]):
        ok = lens_valid[r] and sensor_weight[r] > 0.0
        valid[r] = ok
        ill = sensor_weight[r] / g0 if ok else 0.0
        illumination[r] = ill
        for c in range(3):
            weight[r, c] = spectral[r, c] * ill
        if not ok:
            continue
        px, py, pz = o[0, r] * per_mm, o[1, r] * per_mm, -(o[2, r] - sensor_z) * per_mm
        dx, dy, dz = d[0, r], d[1, r], -d[2, r]
        wx = dx * m[0, 0] + dy * m[0, 1] + dz * m[0, 2]
        wy = dx * m[1, 0] + dy * m[1, 1] + dz * m[1, 2]
        wz = dx * m[2, 0] + dy * m[2, 1] + dz * m[2, 2]
        ln = math.sqrt(wx * wx + wy * wy + wz * wz)
        index[n] = r
        origin[n, 0] = px * m[0, 0] + py * m[0, 1] + pz * m[0, 2] + m[0, 3]
        origin[n, 1] = px * m[1, 0] + py * m[1, 1] + pz * m[1, 2] + m[1, 3]
        origin[n, 2] = px * m[2, 0] + py * m[2, 1] + pz * m[2, 2] + m[2, 3]
        direction[n, 0], direction[n, 1], direction[n, 2] = wx / ln, wy / ln, wz / ln
        n += 1
    return n


# ---------------------------------------------------------------- array wrappers

class CameraTables:
    """What the two kernels need of one generator (camera_rays.CameraRayGenerator), made
    once: the hash salts, the film, the responses and the sampler's cells."""

    def __init__(self, seed, film, squeeze, response, mode, sampler, r2, golden, lam_d, dims):
        pairs = [salts(seed, dim) for dim in dims]
        self.salt = np.array([a for a, _ in pairs], np.uint64)
        self.dim1 = np.array([b for _, b in pairs], np.uint64)
        self.film = np.array([film.width_px, film.height_px, film.width_mm, film.height_mm,
                              film.shift_x_mm, film.shift_y_mm], np.float64)
        self.squeeze = float(squeeze)
        self.r2 = np.array(r2, np.float64)
        self.golden = float(golden)
        self.mode = int(mode)
        self.rays_per_sample = 3 if mode == PER_CHANNEL else 1
        self.lam_d = float(lam_d)
        self.knots = np.ascontiguousarray(response.knots, np.float64)
        self.density = np.ascontiguousarray(np.column_stack([response.values,
                                                             response.sensor_density]))
        self.cdf = np.ascontiguousarray(np.column_stack([response.channel_cdfs,
                                                         response.sensor_cdf]))
        self.scale = np.ascontiguousarray(cdf_scale(self.knots, self.density, self.cdf))
        if isinstance(sampler, RearPupilSampler):
            self.kind = PUPIL_GRID
            self.plane = np.array([sampler.plane_z, sampler.sensor_z, sampler.film_radius, 0.0])
            self.cells = (*(np.ascontiguousarray(a, np.int64)
                            for a in sampler.sampling_tables()),
                          np.ascontiguousarray(sampler.origin, np.float64),
                          np.ascontiguousarray(sampler.cell, np.float64),
                          int(sampler.grid), int(sampler.bands))
        else:                                       # core.pupil.RearDiscSampler
            self.kind = REAR_DISC
            self.plane = np.array([sampler.plane_z, sampler.sensor_z, 1.0, sampler.radius])
            self.cells = (np.zeros(1, np.int64), np.zeros(2, np.int64), np.zeros(1, np.int64),
                          np.zeros((1, 2)), np.ones((1, 2)), 1, 1)

    def sensor_rays(self, pixel, sample):
        """(o (3, kN), d (3, kN), wavelength (kN,), weight (kN,), spectral (kN, 3))."""
        m = pixel.shape[0] * self.rays_per_sample
        o, d = np.empty((3, m)), np.empty((3, m))
        lam, w, spectral = np.empty(m), np.empty(m), np.empty((m, 3))
        sensor_rays(np.ascontiguousarray(pixel, np.int64),
                    np.ascontiguousarray(sample, np.int64), self.salt, self.dim1, self.film,
                    self.squeeze, self.r2, self.golden, self.mode, self.knots, self.density,
                    self.cdf, self.scale, self.lam_d, self.kind, self.plane, *self.cells,
                    o, d, lam, w, spectral)
        return o, d, lam, w, spectral


def run_to_world(o, d, lens_valid, sensor_weight, g0, spectral, sensor_z, mm_per_unit,
                 matrix):
    """`to_world`: (valid, illumination, weight, index, origin, direction)."""
    n = o.shape[1]
    valid, illumination, weight = np.empty(n, np.bool_), np.empty(n), np.empty((n, 3))
    index, origin, direction = np.empty(n, np.int64), np.empty((n, 3)), np.empty((n, 3))
    f = np.ascontiguousarray
    k = to_world(f(o, np.float64), f(d, np.float64), f(lens_valid, np.bool_),
                 f(sensor_weight, np.float64), float(g0),
                 f(spectral, np.float64), float(sensor_z), 1.0 / float(mm_per_unit),
                 f(matrix, np.float64), valid, illumination, weight, index, origin, direction)
    return valid, illumination, weight, index[:k], origin[:k], direction[:k]
