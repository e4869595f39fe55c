"""Exact sequential ray trace through a lens prescription, whole ray arrays at once, float64.

Each surface, in its local frame (vertex at the origin, s = z_vertex - z measured along the
patent's propagation direction), is the conic
    c (x^2 + y^2) + c (1 + k) s^2 - 2 s = 0            (sphere: k = 0; plane: c = 0)
plus, for an even asphere, s = sag(rho) with rho = x^2 + y^2 and
    sag(rho) = c rho / (1 + sqrt(1 - (1 + k) c^2 rho)) + sum_n A_n rho^(n/2).
A ray o + t d meets the conic where A t^2 + 2 B t + C = 0 with
    A = c (dx^2 + dy^2) + c (1 + k) ds^2,   B = c (ox dx + oy dy) + c (1 + k) s0 ds - ds,
    C = c (ox^2 + oy^2) + c (1 + k) s0^2 - 2 s0,
and we take the nearest forward root on the cap through the vertex (1 - c (1 + k) s > 0),
both roots computed without cancellation as q / A and C / q, q = -(B + sign(B) sqrt(B^2 - AC)). Aspheres refine that
conic root with at most ASPHERE_MAX_ITERATIONS Newton steps on f(t) = s(t) - sag(rho(t)).
The surface normal is grad(s - sag) = (-2 x g, -2 y g, 1) in (x, y, s), g = dsag/drho
(= c / (2 (1 - c (1 + k) s)) on a conic).
Refraction is Snell's law in vector form with eta = n1 / n2 and cos_i = -N.d > 0:
    d' = eta d + (eta cos_i - sqrt(1 - eta^2 (1 - cos_i^2))) N,
and a negative radicand is total internal reflection. A ray is clipped when its hit point lies
beyond the surface's semi-diameter, or outside the aperture-stop shape at the stop.

Speed: rays go through in cache-sized chunks (CHUNK rays), in-place numpy arithmetic, and the
chunks are shared among threads (numpy releases the GIL inside its loops).
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .prescription import Lens
from .rays import Rays, RayStatus, TraceResult

CHUNK = 32768
ASPHERE_MAX_ITERATIONS = 16
ASPHERE_TOLERANCE_MM = 1e-10
#: a ray may start this far "behind" a surface (it starts on the previous one) and still hit it
BACKWARD_TOLERANCE_MM = 1e-9


@dataclass(frozen=True)
class _SurfaceGeometry:
    z: float            # vertex z in lens space
    c: float            # curvature 1/R (0 for flat)
    ck: float           # c (1 + k)
    sd2: float          # semi-diameter squared
    asph_powers: tuple  # even powers n of the r^n terms
    asph_coeffs: tuple
    stop: bool

    @property
    def is_plane(self) -> bool:
        return self.c == 0.0 and not self.asph_powers


@lru_cache(maxsize=64)
def _geometry(lens: Lens) -> tuple[_SurfaceGeometry, ...]:
    zs = lens.vertex_z
    out = []
    for s, z in zip(lens.surfaces, zs):
        c = s.curvature
        out.append(_SurfaceGeometry(float(z), c, c * (1.0 + s.conic), s.semi_diameter_mm ** 2,
                                    tuple(p for p, _ in s.aspheric),
                                    tuple(a for _, a in s.aspheric), s.stop))
    return tuple(out)


def _resolve_media(lens: Lens, catalog):
    from .glass import resolve_medium
    return [resolve_medium(m, catalog) for m in lens.media()]


class _Kernel:
    """Traces one chunk of rays through the surfaces in a given order (no allocation per surface
    beyond numpy temporaries); mutates the chunk's arrays in place."""

    def __init__(self, geometry, order, media_index_pairs, stop_radius, aperture):
        self.geometry = geometry
        self.order = order                      # surface indices in travel order
        self.media_index_pairs = media_index_pairs  # per step: (medium before, medium after)
        self.stop_radius = stop_radius
        self.aperture = aperture

    def run(self, ox, oy, oz, dx, dy, dz, wl, media, path=None):
        m = ox.shape[0]
        status = np.zeros(m, dtype=np.uint8)
        died_at = np.full(m, -1, dtype=np.int16)
        alive = np.ones(m, dtype=bool)

        # Indices per medium for this chunk: one scalar when all rays share a wavelength.
        if m and wl.min() == wl.max():
            idx = [float(np.asarray(med.index(np.array([wl[0]])))[0]) for med in media]
        else:
            idx = [med.index(wl) for med in media]
        bad_wl = ~np.isfinite(wl)
        for n in idx:
            if isinstance(n, float):
                if not math.isfinite(n):
                    bad_wl[:] = True
            else:
                bad_wl |= ~np.isfinite(n)
        if bad_wl.any():
            self._kill(alive, status, died_at, bad_wl, RayStatus.BAD_WAVELENGTH, -1)

        for step, si in enumerate(self.order):
            g = self.geometry[si]
            n1 = idx[self.media_index_pairs[step][0]]
            n2 = idx[self.media_index_pairs[step][1]]
            self._surface(g, si, ox, oy, oz, dx, dy, dz, n1, n2, alive, status, died_at)
            if path is not None:
                path.append((np.stack([ox, oy, oz]), alive.copy()))
        return status, died_at, alive

    @staticmethod
    def _kill(alive, status, died_at, mask, code, surface):
        newly = mask & alive
        np.copyto(status, np.uint8(code), where=newly)
        np.copyto(died_at, np.int16(surface), where=newly)
        alive &= ~newly

    def _surface(self, g, si, ox, oy, oz, dx, dy, dz, n1, n2, alive, status, died_at):
        t, miss, unconverged = _intersect(g, ox, oy, oz, dx, dy, dz)
        if unconverged is not None:
            self._kill(alive, status, died_at, unconverged & ~miss, RayStatus.NO_CONVERGENCE, si)
        miss |= t < -BACKWARD_TOLERANCE_MM
        self._kill(alive, status, died_at, miss, RayStatus.MISSED_SURFACE, si)
        np.copyto(t, 0.0, where=~alive)

        # Move to the hit point.
        ox += t * dx
        oy += t * dy
        oz += t * dz
        rho = ox * ox
        rho += oy * oy
        self._kill(alive, status, died_at, ~(rho <= g.sd2), RayStatus.CLIPPED_APERTURE, si)
        if g.stop and self.stop_radius is not None:
            r = self.stop_radius
            if self.aperture is None:
                outside = ~(rho <= r * r)
            else:
                outside = ~self.aperture.inside(ox / r, oy / r)
            self._kill(alive, status, died_at, outside, RayStatus.CLIPPED_STOP, si)

        # Refract, unless both sides have the same index (the stop, a flat in air).
        if isinstance(n1, float) and isinstance(n2, float) and n1 == n2:
            return
        if g.is_plane:
            nx = np.zeros_like(ox)
            ny = nx
            nz = np.ones_like(ox)
            cosi = dz.copy()               # N = +z; orient against the ray below
        else:
            if g.asph_powers:
                gr = _sag_slope(g, rho)
                nx = -2.0 * ox * gr
                ny = -2.0 * oy * gr
                nz = np.full_like(ox, -1.0)
            else:
                s_hit = g.z - oz
                nx = -g.c * ox
                ny = -g.c * oy
                nz = -(1.0 - g.ck * s_hit)
            inv = nx * nx
            inv += ny * ny
            inv += nz * nz
            np.sqrt(inv, out=inv)
            with np.errstate(divide="ignore", invalid="ignore"):
                np.divide(1.0, inv, out=inv)
            nx = nx * inv
            ny = ny * inv
            nz *= inv
            cosi = nx * dx
            cosi += ny * dy
            cosi += nz * dz
            np.negative(cosi, out=cosi)
        if g.is_plane:
            np.negative(cosi, out=cosi)     # cos_i = -N.d with N = +z
        # Orient N against the incoming ray so that cos_i > 0.
        flip = np.where(cosi < 0.0, -1.0, 1.0)
        cosi *= flip
        eta = n1 / n2
        eta2 = eta * eta
        k = cosi * cosi
        k -= 1.0
        k *= eta2
        k += 1.0
        tir = k < 0.0
        self._kill(alive, status, died_at, tir, RayStatus.TOTAL_INTERNAL_REFLECTION, si)
        np.maximum(k, 0.0, out=k)
        np.sqrt(k, out=k)
        # factor = (eta cos_i - sqrt(k)) * flip, applied to the unflipped normal
        fac = eta * cosi
        fac -= k
        fac *= flip
        dx *= eta
        dx += fac * nx
        dy *= eta
        dy += fac * ny
        dz *= eta
        dz += fac * nz

    @staticmethod
    def _refine_asphere(g, ox, oy, s0, dx, dy, ds, t, valid=None):
        """Newton steps on f(t) = s(t) - sag(rho(t)), starting from the conic root; stops as
        soon as every ray still worth refining has converged."""
        t = np.where(np.isfinite(t), t, s0 / np.where(ds == 0.0, 1e-300, ds))
        watch = np.ones(t.shape, dtype=bool) if valid is None else valid.copy()
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            for _ in range(ASPHERE_MAX_ITERATIONS):
                x = ox + t * dx
                y = oy + t * dy
                rho = x * x + y * y
                sg, slope = _sag_and_slope(g, rho)
                f = s0 + t * ds - sg
                fp = ds - 2.0 * slope * (x * dx + y * dy)
                step = f / fp
                t = t - step
                watch &= np.abs(step) > ASPHERE_TOLERANCE_MM
                if not watch.any():
                    break
            x = ox + t * dx
            y = oy + t * dy
            resid = np.abs(s0 + t * ds - _sag(g, x * x + y * y))
        unconverged = ~(resid <= 1e-7)
        return t, unconverged


def _intersect(g: _SurfaceGeometry, ox, oy, oz, dx, dy, dz):
    """Ray parameter t of the hit with one surface; (t, miss mask, unconverged mask or None)."""
    # Local frame s = z_vertex - z: s grows towards the sensor, the patent's direction.
    s0 = g.z - oz
    ds = -dz
    unconverged = None
    if g.is_plane:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -s0 / ds
        miss = ~np.isfinite(t)
    else:
        c, ck = g.c, g.ck
        if ck == c:
            a = c                        # sphere: c (dx^2 + dy^2 + dz^2) = c, d is unit
        else:
            a = dz * dz
            a *= ck - c
            a += c                       # c (1 - dz^2) + c (1 + k) dz^2
        b = ox * dx
        b += oy * dy
        b *= c
        b += (ck * s0 - 1.0) * ds
        cc = ox * ox
        cc += oy * oy
        cc *= c
        cc += (ck * s0 - 2.0) * s0
        disc = b * b
        disc -= a * cc
        miss = disc < 0.0
        np.maximum(disc, 0.0, out=disc)
        np.sqrt(disc, out=disc)
        # Both roots without cancellation: q = -(B + sign(B) sqrt(D)), t1 = q / A, t2 = C / q.
        disc *= np.where(b >= 0.0, 1.0, -1.0)
        disc += b
        q = np.negative(disc, out=disc)
        with np.errstate(divide="ignore", invalid="ignore"):
            t2 = cc / q
            t1 = q / a
        # Keep the nearest forward hit on the cap through the vertex (1 - c(1+k) s > 0);
        # a ray starting beyond the centre of curvature has its cap hit at the far root.
        ok1 = (t1 >= -BACKWARD_TOLERANCE_MM) & ((1.0 - ck * (s0 + t1 * ds)) > 0.0)
        ok2 = (t2 >= -BACKWARD_TOLERANCE_MM) & ((1.0 - ck * (s0 + t2 * ds)) > 0.0)
        take1 = ok1 & (~ok2 | (t1 < t2))
        t = np.where(take1, t1, t2)
        miss |= ~(ok1 | ok2)
        miss |= ~np.isfinite(t)
        if g.asph_powers:
            t, unconverged = _Kernel._refine_asphere(g, ox, oy, s0, dx, dy, ds, t, ~miss)
    miss |= t < -BACKWARD_TOLERANCE_MM
    return t, miss, unconverged


def intersect(lens: Lens, surface_index: int, rays: Rays):
    """Ray parameter of each ray's hit with one surface of the lens, and whether it hits the
    surface's cap (the semi-diameter is not checked)."""
    g = _geometry(lens)[surface_index]
    o = np.asarray(rays.o, dtype=np.float64)
    d = np.asarray(rays.d, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        t, miss, unconverged = _intersect(g, o[0], o[1], o[2], d[0], d[1], d[2])
    hit = ~miss if unconverged is None else ~miss & ~unconverged
    return np.where(hit, t, 0.0), hit


def _sag(g: _SurfaceGeometry, rho):
    """Sag along the propagation direction at squared radius rho (NaN outside the conic)."""
    with np.errstate(invalid="ignore"):
        q = np.sqrt(1.0 - g.ck * g.c * rho)
    out = g.c * rho / (1.0 + q)
    for p, a in zip(g.asph_powers, g.asph_coeffs):
        out = out + a * rho ** (p // 2)
    return out


def _sag_and_slope(g: _SurfaceGeometry, rho):
    """sag(rho) and d sag / d rho together: one square root, Horner in rho for the terms."""
    with np.errstate(invalid="ignore", divide="ignore"):
        q = np.sqrt(1.0 - g.ck * g.c * rho)
        sg = g.c * rho / (1.0 + q)
        slope = g.c / (2.0 * q)
    if g.asph_powers:
        # sum_h A_2h rho^h and its derivative sum_h h A_2h rho^(h-1), h = power / 2
        hs = [p // 2 for p in g.asph_powers]
        coef = dict(zip(hs, g.asph_coeffs))
        top = max(hs)
        poly = np.zeros_like(rho)
        dpoly = np.zeros_like(rho)
        for h in range(top, 0, -1):
            a = coef.get(h, 0.0)
            dpoly = dpoly * rho + h * a if h < top else np.full_like(rho, h * a)
            poly = (poly + a) * rho
        sg = sg + poly
        slope = slope + dpoly
    return sg, slope


def _sag_slope(g: _SurfaceGeometry, rho):
    """d sag / d rho: c / (2 sqrt(1 - (1+k) c^2 rho)) + sum_n A_n (n/2) rho^(n/2 - 1)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        out = g.c / (2.0 * np.sqrt(1.0 - g.ck * g.c * rho))
    for p, a in zip(g.asph_powers, g.asph_coeffs):
        h = p // 2
        out = out + (a * h) * (rho ** (h - 1) if h > 1 else 1.0)
    return out


def sag(lens: Lens, surface_index: int, r) -> np.ndarray:
    """Sag (mm, along the propagation direction) of one surface at radius r."""
    r = np.asarray(r, dtype=np.float64)
    return _sag(_geometry(lens)[surface_index], r * r)


def _prepare(rays: Rays, from_sensor: bool):
    """Copy, normalise directions and flag bad input rays."""
    o = np.array(rays.o, dtype=np.float64, copy=True)
    d = np.array(rays.d, dtype=np.float64, copy=True)
    wl = np.array(rays.wavelength, dtype=np.float64, copy=True).reshape(-1)
    if o.ndim != 2 or o.shape[0] != 3 or d.shape != o.shape or wl.shape[0] != o.shape[1]:
        raise ValueError(f"inconsistent ray arrays: o {o.shape}, d {d.shape}, wavelength {wl.shape}")
    with np.errstate(invalid="ignore", over="ignore"):
        norm = np.sqrt((d * d).sum(axis=0))
        bad = ~np.isfinite(o).all(axis=0) | ~np.isfinite(d).all(axis=0) | ~(norm > 0) | ~np.isfinite(norm)
        d /= np.where(bad, 1.0, norm)
    bad |= ~(d[2] > 0.0) if from_sensor else ~(d[2] < 0.0)
    o[:, bad] = 0.0
    d[:, bad] = 0.0
    d[2, bad] = 1.0 if from_sensor else -1.0
    wl[bad] = 587.5618
    return o, d, wl, bad


def trace_path(lens: Lens, rays: Rays, *, from_sensor: bool = True, stop_radius=None,
               aperture=None, catalog=None):
    """Hit points of a (small) ray set at every surface, in travel order, for drawings.

    Returns a list of (points (3, N), alive (N,)) after each surface; rays start where given.
    """
    geometry = _geometry(lens)
    nsurf = len(geometry)
    order = list(range(nsurf - 1, -1, -1)) if from_sensor else list(range(nsurf))
    pairs = [(i + 1, i) for i in order] if from_sensor else [(i, i + 1) for i in order]
    kernel = _Kernel(geometry, order, pairs,
                     float(lens.stop_radius_mm if stop_radius is None else stop_radius), aperture)
    o, d, wl, bad = _prepare(rays, from_sensor)
    path = [(o.copy(), ~bad)]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        kernel.run(o[0], o[1], o[2], d[0], d[1], d[2], wl, _resolve_media(lens, catalog), path)
    return [(p, a & ~bad) for p, a in path], d


def _advance_to_safe_plane(lens: Lens, o, d, from_sensor: bool, margin_mm: float = 1.0) -> None:
    """Move far-away origins along their rays to a plane just clear of the first surface met.

    Solving the intersection quadratic from a distant origin cancels catastrophically
    (B^2 and AC both grow as the distance squared); starting 1 mm from the surface's extreme
    point keeps full precision and changes no ray.
    """
    idx = len(lens.surfaces) - 1 if from_sensor else 0
    surf = lens.surfaces[idx]
    r = np.linspace(0.0, surf.semi_diameter_mm, 33)
    with np.errstate(invalid="ignore"):
        sg = sag(lens, idx, r)
    sg = sg[np.isfinite(sg)]
    z_v = float(lens.vertex_z[idx])
    if from_sensor:
        z_safe = z_v - max(0.0, float(sg.max(initial=0.0))) - margin_mm
        far = o[2] < z_safe
    else:
        z_safe = z_v + max(0.0, float(-sg.min(initial=0.0))) + margin_mm
        far = o[2] > z_safe
    if far.any():
        t = (z_safe - o[2, far]) / d[2, far]
        o[0, far] += t * d[0, far]
        o[1, far] += t * d[1, far]
        o[2, far] = z_safe


def trace(lens: Lens, rays: Rays, *, from_sensor: bool = True, stop_radius: float | None = None,
          aperture=None, sensor_z: float | None = 0.0, catalog=None, threads: int | None = None,
          chunk: int = CHUNK, surfaces: tuple[int, int] | None = None) -> TraceResult:
    """Trace rays through the lens.

    from_sensor=True: rays start near the sensor travelling +z; the result is each ray leaving
    the front surface (origin on that surface). from_sensor=False: rays start in the scene
    travelling -z; the result is each ray arriving on the sensor plane z = sensor_z.
    stop_radius: the aperture-stop radius in mm (None: the design's full aperture);
    aperture: a shape from core.aperture with inside(x, y) in stop-normalised coordinates
    (None: circular).
    surfaces=(lo, hi): trace only prescription surfaces lo..hi-1 (a lens group, e.g. the part
    behind the stop); the result is on the last surface traced, and sensor_z=None skips the
    final propagation for scene rays.
    """
    geometry = _geometry(lens)
    lo_s, hi_s = (0, len(geometry)) if surfaces is None else surfaces
    if not 0 <= lo_s < hi_s <= len(geometry):
        raise ValueError(f"surface range {surfaces} outside 0..{len(geometry)}")
    if from_sensor:
        order = list(range(hi_s - 1, lo_s - 1, -1))
        pairs = [(i + 1, i) for i in order]       # medium index: after surface i is media[i+1]
    else:
        order = list(range(lo_s, hi_s))
        pairs = [(i, i + 1) for i in order]
    if stop_radius is None:
        stop_radius = lens.stop_radius_mm
    kernel = _Kernel(geometry, order, pairs, float(stop_radius), aperture)
    media = _resolve_media(lens, catalog)

    o, d, wl, bad = _prepare(rays, from_sensor)
    if surfaces is None:
        _advance_to_safe_plane(lens, o, d, from_sensor)
    n = o.shape[1]
    status = np.zeros(n, dtype=np.uint8)
    died_at = np.full(n, -1, dtype=np.int16)
    valid = np.zeros(n, dtype=bool)

    def work(lo: int) -> None:
        hi = min(lo + chunk, n)
        ox, oy, oz = o[0, lo:hi].copy(), o[1, lo:hi].copy(), o[2, lo:hi].copy()
        dx, dy, dz = d[0, lo:hi].copy(), d[1, lo:hi].copy(), d[2, lo:hi].copy()
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            st, da, alive = kernel.run(ox, oy, oz, dx, dy, dz, wl[lo:hi], media)
            if not from_sensor and sensor_z is not None and hi_s == len(geometry):
                # Propagate to the sensor plane.
                t = (sensor_z - oz) / dz
                alive &= np.isfinite(t)
                ox += t * dx
                oy += t * dy
                oz[:] = sensor_z
        o[0, lo:hi], o[1, lo:hi], o[2, lo:hi] = ox, oy, oz
        d[0, lo:hi], d[1, lo:hi], d[2, lo:hi] = dx, dy, dz
        status[lo:hi] = st
        died_at[lo:hi] = da
        valid[lo:hi] = alive

    starts = range(0, n, chunk)
    workers = threads or min(os.cpu_count() or 1, 8)
    if workers > 1 and n > chunk:
        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(work, starts))
    else:
        for lo in starts:
            work(lo)

    status[bad] = RayStatus.BAD_INPUT
    died_at[bad] = -1
    valid &= ~bad
    valid &= np.isfinite(o).all(axis=0) & np.isfinite(d).all(axis=0)
    status[~valid & (status == 0)] = RayStatus.MISSED_SURFACE
    o[:, ~valid] = 0.0
    d[:, ~valid] = 0.0
    wl = np.where(valid, wl, 0.0)
    return TraceResult(Rays(o, d, wl), valid, status, died_at)
