"""The exact sequential trace compiled (numba): core.trace_kernel's steps in a parallel loop
over blocks of rays; the numpy trace (trace_kernel) stays the reference it is tested against
(tests/core/test_trace_compiled.py).

Three kernels, each a parallel loop:
- `prepare` (core.trace._prepare and _advance_to_safe_plane per ray): directions normalised,
  bad input rays flagged, far origins moved along their rays to the safe plane;
- `trace_chunk`: blocks of BLOCK rays, each block through the steps of the path (core.trace:
  the image's, or a ghost's) in travel order, exactly as trace_kernel describes: at surface i
  the kind's hit (surfaces/kernels.py, from the flat table below), death where it misses,
  does not converge (aspheres, anamorphic kinds) or meets the surface more than
  BACKWARD_TOLERANCE_MM behind its start; the move to o + t d; clipping where
  rho = x^2 + y^2 > sd_i^2 and, at the stop of radius R, where rho > R^2 (circular stop);
  then, unless both sides have the same index and the step does not reflect, the normal N
  (normalised, oriented so that cos_i = -N.d > 0) and Snell's law in vector form
      d' = eta d + (eta cos_i - sqrt(1 - eta^2 (1 - cos_i^2))) N,   eta = n1 / n2,
  death by total internal reflection where the root's argument is negative, or at a
  reflecting step (a ghost's) the mirror d' = d + 2 cos_i N. A ray keeps the first reason it
  died (RayStatus) and the surface; a dead ray stays where it died. From the scene, a living
  ray finally moves to the sensor plane: t = (z_sensor - o_z) / d_z, invalid where t is not
  finite;
- `finish` (core.trace._finish per ray): invalid where dead, not finite or (a ghost's path)
  leaving backwards; invalid rays zeroed.

What stays numpy, between them, in chunks of CHUNK rays:
- the refractive indices: each distinct medium's index at each ray's wavelength (one value
  per medium when all rays share a wavelength); a ray whose wavelength or index is not
  finite dies (BAD_WAVELENGTH) before the lens;
- an aperture shape other than the plain circle: the kernel records where each ray crosses
  the stop ((x, y) per crossing: a ghost's path crosses it up to three times) and the
  shape's own `inside(x / R, y / R)` decides afterwards, crossing by crossing; a ray outside
  at a crossing it reached died there (CLIPPED_STOP), whatever the kernel found after;
- a coating: the kernel records cos_i at each step, and the path's weight is the product over
  the steps of the coating's R (reflecting) or 1 - R (refracting) at (n1, n2, cos_i, lambda).
The surface table: per prescription surface its kind code, vertex z, semi-diameter^2 and its
kernel_params numbers (surfaces/base.py); the path: per step the surface, the media rows
before and after, whether it reflects and which stop crossing it is (-1: none).

Differences from the numpy reference (measured in docs/measurements.md): none to the last bit
for lenses of spheres, planes and anamorphic surfaces; with even aspheres, rounding (the
Newton iteration stops for each ray at its own converged step where the numpy one steps the
whole array until every ray has; the residual's terms in Horner form), positions within
~3e-13 mm; and given a wavelength per ray the numpy trace refracts between equal media with
eta = 1 (rounding) where this one goes straight. A ray within rounding of a clipping edge may
be kept by one and clipped by the other (the tests bound how rarely).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from .jit import KERNEL_LOCK, njit, prange_or_range, set_threads
from .prescription import WAVELENGTH_D_NM
from .rays import RayStatus
from .surfaces import BACKWARD_TOLERANCE_MM
from .surfaces.base import KERNEL_ASPHERE, KERNEL_BICONIC, KERNEL_CONIC, KERNEL_PLANE
from .surfaces.kernels import (asphere_hit, asphere_normal, biconic_hit, biconic_normal,
                               conic_hit, conic_normal, plane_hit, plane_normal, table_row,
                               toroidal_hit, toroidal_normal)

prange = prange_or_range()

CHUNK = 1 << 16
#: rays a thread takes through the whole path at a time (its arrays stay in the core's cache)
BLOCK = 256

_OK = int(RayStatus.OK)
_MISSED = int(RayStatus.MISSED_SURFACE)
_CLIPPED_APERTURE = int(RayStatus.CLIPPED_APERTURE)
_CLIPPED_STOP = int(RayStatus.CLIPPED_STOP)
_TIR = int(RayStatus.TOTAL_INTERNAL_REFLECTION)
_NO_CONVERGENCE = int(RayStatus.NO_CONVERGENCE)
_BAD_WAVELENGTH = int(RayStatus.BAD_WAVELENGTH)
_BAD_INPUT = int(RayStatus.BAD_INPUT)


def _surface_step(hit, normal):
    """The step of a kind (its compiled hit and normal): rays lo..hi-1 (columns lo - c0 ..
    hi - c0 of the chunk's arrays) through surface si. Every ray is computed and the results
    selected by whether it is alive, so that the loop has no early exit or branching store and
    compiles to vector code; the loop runs over slices from 0 (an index from an offset may be
    negative to numba, whose wrap-around test stops the vectoriser). (A closure per kind, not
    the kind's functions as arguments: numba then calls them directly, inlines them, and can
    cache the kernel.)"""
    @njit(error_model="numpy", cache=False)
    def step_of_kind(p, zv, sd2, si, crossing, circle_r2, n1, n2, mirror, cos_row, o, d, lo,
                     hi, c0, status, died, record, stop_xy, cos_out):
        clip = crossing >= 0 and circle_r2 >= 0.0      # the plain circle, clipped here
        a0, b0 = lo - c0, hi - c0
        xs, ys, zs = o[0, lo:hi], o[1, lo:hi], o[2, lo:hi]
        us, vs, ws = d[0, lo:hi], d[1, lo:hi], d[2, lo:hi]
        st, da = status[lo:hi], died[lo:hi]
        na, nb = n1[a0:b0], n2[a0:b0]
        cs = cos_out[cos_row, a0:b0]
        for i in range(hi - lo):
            ox, oy, oz = xs[i], ys[i], zs[i]
            dx, dy, dz = us[i], vs[i], ws[i]
            t, miss, unconverged = hit(p, zv, ox, oy, oz, dx, dy, dz)
            # a hit behind the ray's start is a miss, not a failure to converge (every kind's
            # numpy `hit` counts it in its miss)
            miss = miss or t < -BACKWARD_TOLERANCE_MM
            code = _OK
            if unconverged and not miss:
                code = _NO_CONVERGENCE
            elif miss:
                code = _MISSED
            x = ox + t * dx
            y = oy + t * dy
            z = oz + t * dz
            rho = x * x + y * y
            if code == _OK and not rho <= sd2:
                code = _CLIPPED_APERTURE
            if clip and code == _OK and not rho <= circle_r2:
                code = _CLIPPED_STOP
            a = na[i]
            b = nb[i]
            nx, ny, nz = normal(p, zv, x, y, z, rho)
            inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
            nx *= inv
            ny *= inv
            nz *= inv
            cosi = -(nx * dx + ny * dy + nz * dz)
            # orient N against the incoming ray so that cos_i > 0
            flip = -1.0 if cosi < 0.0 else 1.0
            cosi *= flip
            if mirror:
                fac = 2.0 * cosi * flip
                ex, ey, ez = dx + fac * nx, dy + fac * ny, dz + fac * nz
            else:
                eta = a / b
                k2 = (cosi * cosi - 1.0) * (eta * eta) + 1.0
                if code == _OK and k2 < 0.0 and a != b:
                    code = _TIR
                fac = (eta * cosi - math.sqrt(max(k2, 0.0))) * flip
                ex, ey, ez = dx * eta + fac * nx, dy * eta + fac * ny, dz * eta + fac * nz
            # where both sides have the same index and nothing reflects (the stop, a flat in
            # air) the ray goes straight on
            bend = mirror or a != b
            alive = st[i] == _OK
            ok = alive and code == _OK
            st[i] = code if alive else st[i]
            da[i] = si if alive and code != _OK else da[i]
            xs[i] = x if ok else ox
            ys[i] = y if ok else oy
            zs[i] = z if ok else oz
            us[i] = ex if ok and bend else dx
            vs[i] = ey if ok and bend else dy
            ws[i] = ez if ok and bend else dz
            cs[i] = cosi if ok and bend else math.nan
        if record and crossing >= 0:
            # where the living rays crossed the stop (a loop of its own: a store under a
            # condition inside the loop above would keep it from vectorising)
            sx, sy = stop_xy[crossing, 0, a0:b0], stop_xy[crossing, 1, a0:b0]
            for i in range(hi - lo):
                live = st[i] == _OK
                sx[i] = xs[i] if live else math.nan
                sy[i] = ys[i] if live else math.nan
    return step_of_kind


_PLANE_STEP = _surface_step(plane_hit, plane_normal)
_CONIC_STEP = _surface_step(conic_hit, conic_normal)
_ASPHERE_STEP = _surface_step(asphere_hit, asphere_normal)
_BICONIC_STEP = _surface_step(biconic_hit, biconic_normal)
_TOROIDAL_STEP = _surface_step(toroidal_hit, toroidal_normal)


@njit(error_model="numpy", cache=False)
def _block(o, d, wl, lo, hi, c0, idx, codes, zv, sd2, par, order, m1, m2, reflect, crossing,
           circle_r2, record, stop_xy, keep_cos, cos_out, propagate, sensor_z, status, died):
    """Rays lo..hi-1 through the whole path, step after step. cos_i goes to row `step` of
    cos_out with a coating, else to its row 0, a scratch row."""
    for i in range(lo, hi):
        good = math.isfinite(wl[i])
        for m in range(idx.shape[0]):
            good = good and math.isfinite(idx[m, i - c0])
        if not good and status[i] == _OK:
            status[i] = _BAD_WAVELENGTH
    for step in range(order.shape[0]):
        si = order[step]
        args = (par[si], zv[si], sd2[si], si, crossing[step], circle_r2, idx[m1[step]],
                idx[m2[step]], reflect[step], step if keep_cos else 0, o, d, lo, hi, c0, status,
                died, record, stop_xy, cos_out)
        code = codes[si]
        if code == KERNEL_PLANE:
            _PLANE_STEP(*args)
        elif code == KERNEL_CONIC:
            _CONIC_STEP(*args)
        elif code == KERNEL_ASPHERE:
            _ASPHERE_STEP(*args)
        elif code == KERNEL_BICONIC:
            _BICONIC_STEP(*args)
        else:
            _TOROIDAL_STEP(*args)
    if propagate:
        for i in range(lo, hi):
            t = (sensor_z - o[2, i]) / d[2, i]
            if status[i] == _OK and not math.isfinite(t):
                status[i] = _MISSED            # read as "missed", surface -1
            o[0, i] += t * d[0, i]
            o[1, i] += t * d[1, i]
            o[2, i] = sensor_z


@njit(parallel=True, nogil=True, error_model="numpy", cache=True)
def trace_chunk(o, d, wl, lo, hi, idx, codes, zv, sd2, par, order, m1, m2, reflect, crossing,
                circle_r2, record, stop_xy, keep_cos, cos_out, propagate, sensor_z, status,
                died):
    """Rays lo..hi-1 (the chunk whose per-ray arrays idx, stop_xy, cos_out start at ray lo) in
    blocks of BLOCK rays, the blocks in parallel."""
    blocks = (hi - lo + BLOCK - 1) // BLOCK
    for b in prange(blocks):
        a = lo + b * BLOCK
        _block(o, d, wl, a, min(a + BLOCK, hi), lo, idx, codes, zv, sd2, par, order, m1, m2,
               reflect, crossing, circle_r2, record, stop_xy, keep_cos, cos_out, propagate,
               sensor_z, status, died)


@njit(parallel=True, nogil=True, error_model="numpy", cache=True)
def prepare(o, d, wl, from_sensor, z_safe, status, bad_wl):
    """core.trace._prepare and _advance_to_safe_plane, per ray, in place: directions
    normalised; a ray with a non-finite or zero-length component, or travelling the wrong way,
    is BAD_INPUT (origin 0, direction (0, 0, +-1), wavelength bad_wl); an origin beyond z_safe
    (NaN: none) moves along its ray onto it."""
    for i in prange(o.shape[1]):
        ox, oy, oz = o[0, i], o[1, i], o[2, i]
        dx, dy, dz = d[0, i], d[1, i], d[2, i]
        norm = math.sqrt(dx * dx + dy * dy + dz * dz)
        bad = not (math.isfinite(ox) and math.isfinite(oy) and math.isfinite(oz)
                   and math.isfinite(dx) and math.isfinite(dy) and math.isfinite(dz)
                   and norm > 0.0 and math.isfinite(norm))
        if not bad:
            dx /= norm
            dy /= norm
            dz /= norm
        if not (dz > 0.0 if from_sensor else dz < 0.0):
            bad = True
        if bad:
            ox, oy, oz = 0.0, 0.0, 0.0
            dx, dy, dz = 0.0, 0.0, 1.0 if from_sensor else -1.0
            wl[i] = bad_wl
            status[i] = _BAD_INPUT
        if oz < z_safe if from_sensor else oz > z_safe:
            t = (z_safe - oz) / dz
            ox += t * dx
            oy += t * dy
            oz = z_safe
        o[0, i], o[1, i], o[2, i] = ox, oy, oz
        d[0, i], d[1, i], d[2, i] = dx, dy, dz


@njit(parallel=True, nogil=True, error_model="numpy", cache=True)
def finish(o, d, wl, status, ghost_way, valid, weight, weighted):
    """core.trace._finish per ray, in place: valid where nothing killed the ray, its result
    is finite and (a ghost's path) it leaves the way it must (ghost_way 1: +z from the front,
    -1: -z onto the sensor, 0: the image's path); invalid rays zeroed (weight too), a living
    ray made invalid here counted as MISSED_SURFACE."""
    for i in prange(o.shape[1]):
        ok = status[i] == _OK
        if ghost_way != 0:
            ok = ok and d[2, i] * ghost_way > 0.0    # a ghost's path may turn a ray back
        for c in range(3):
            ok = ok and math.isfinite(o[c, i]) and math.isfinite(d[c, i])
        if not ok and status[i] == _OK:
            status[i] = _MISSED
        valid[i] = ok
        if not ok:
            for c in range(3):
                o[c, i] = 0.0
                d[c, i] = 0.0
            wl[i] = 0.0
            if weighted:
                weight[i] = 0.0


@lru_cache(maxsize=64)
def surface_table(placed):
    """(codes, z_v, sd^2, params, stop flags) of placed surfaces (trace_kernel.PlacedSurface),
    or None where a kind has no compiled twin."""
    rows = [table_row(g.shape) for g in placed]
    if any(r is None for r in rows):
        return None
    return (np.array([r[0] for r in rows], dtype=np.int64),
            np.array([g.z for g in placed], dtype=np.float64),
            np.array([g.sd2 for g in placed], dtype=np.float64),
            np.ascontiguousarray(np.stack([r[1] for r in rows])),
            tuple(g.stop for g in placed))


def _media_rows(media, pairs):
    """The distinct media (by identity: air is shared) and each step's (before, after) rows."""
    rows, slot = [], {}
    for m in media:
        if id(m) not in slot:
            slot[id(m)] = len(rows)
            rows.append(m)
    row_of = [slot[id(m)] for m in media]
    m1 = np.array([row_of[a] for a, _ in pairs], dtype=np.int64)
    m2 = np.array([row_of[b] for _, b in pairs], dtype=np.int64)
    return rows, m1, m2


def _indices(rows, wl):
    """(media, rays or 1) indices: one column when every ray has the same wavelength."""
    if wl.size and wl.min() == wl.max():
        w = np.array([wl[0]])
        return np.ascontiguousarray(np.stack([np.asarray(m.index(w), dtype=np.float64)
                                              for m in rows]).reshape(len(rows), 1))
    return np.ascontiguousarray(np.stack([np.asarray(m.index(wl), dtype=np.float64)
                                          for m in rows]))


def run(table, order, pairs, reflect, media, o, d, wl, *, from_sensor, z_safe, stop_radius,
        aperture, coating, sensor_z, ghost_way, threads=None, chunk=None):
    """Trace the copied rays (core.trace._copy_rays) in place through the path (order, media
    pairs, reflect flags): prepare, the chunks, finish. (status, died_at, valid, weight or
    None); the arrays hold the result."""
    codes, zv, sd2, par, stops = table
    chunk = chunk or CHUNK
    n = o.shape[1]
    steps = len(order)
    order_a = np.array(order, dtype=np.int64)
    reflect_a = np.array(reflect if reflect is not None else (False,) * steps, dtype=np.bool_)
    crossing = np.full(steps, -1, dtype=np.int64)
    crossings = [s for s, si in enumerate(order) if stops[si]]
    crossing[crossings] = np.arange(len(crossings))
    rows, m1, m2 = _media_rows(media, pairs)
    r = float(stop_radius)
    circle_r2 = r * r if aperture is None else -1.0
    record = aperture is not None and len(crossings) > 0
    propagate = sensor_z is not None
    z_sensor = float(sensor_z) if propagate else 0.0
    keep_cos = coating is not None

    status = np.zeros(n, dtype=np.uint8)
    died = np.full(n, -1, dtype=np.int16)
    valid = np.zeros(n, dtype=np.bool_)
    weight = np.ones(n if keep_cos else 1)
    # stand-ins where nothing is recorded: the kernel never reads no_xy; without a coating it
    # writes cos_i to one scratch row
    no_xy = np.full((1, 2, 1), np.nan)
    no_cos = np.empty((1, max(1, min(chunk, n))))
    before = set_threads(threads)
    try:
        with KERNEL_LOCK:
            prepare(o, d, wl, from_sensor, float(z_safe), status, WAVELENGTH_D_NM)
        uniform = _indices(rows, wl[:1]) if n and wl.min() == wl.max() else None
        for lo in range(0, n, chunk):
            hi = min(lo + chunk, n)
            idx = (np.repeat(uniform, hi - lo, axis=1) if uniform is not None
                   else _indices(rows, wl[lo:hi]))
            stop_xy = np.full((len(crossings), 2, hi - lo), np.nan) if record else no_xy
            cos_out = np.empty((steps, hi - lo)) if keep_cos else no_cos
            with KERNEL_LOCK:
                trace_chunk(o, d, wl, lo, hi, idx, codes, zv, sd2, par, order_a, m1, m2,
                            reflect_a, crossing, circle_r2, record, stop_xy, keep_cos, cos_out,
                            propagate, z_sensor, status, died)
            if record:
                _clip_at_stop(aperture, r, stop_xy, [order[s] for s in crossings],
                              status[lo:hi], died[lo:hi])
            if keep_cos:
                _coating_weight(coating, idx, m1, m2, reflect_a, cos_out, wl[lo:hi],
                                weight[lo:hi], status[lo:hi] == _OK)
        with KERNEL_LOCK:
            finish(o, d, wl, status, ghost_way, valid, weight, keep_cos)
    finally:
        set_threads(before)
    return status, died, valid, weight if keep_cos else None


def _clip_at_stop(aperture, r, stop_xy, stop_surfaces, status, died) -> None:
    """Rays outside the aperture shape at a stop crossing they reached die there (in place)."""
    clipped = np.zeros(status.shape, dtype=bool)
    for k, si in enumerate(stop_surfaces):
        x, y = stop_xy[k, 0], stop_xy[k, 1]
        reached = ~np.isnan(x)
        with np.errstate(invalid="ignore"):
            outside = reached & ~aperture.inside(x / r, y / r) & ~clipped
        clipped |= outside
        status[outside] = _CLIPPED_STOP
        died[outside] = si


def _coating_weight(coating, idx, m1, m2, reflect, cos_out, wl, weight, live) -> None:
    """weight *= prod over steps of R (reflecting) or 1 - R (refracting); a step a ray did not
    bend at (equal indices, or not reached) counts 1. The reflectances of every step come
    from one call over the (steps, rays) arrays (a call a step cost a ghost render more than
    its trace: thousands of small calls), then multiply in step order as before. Compiled,
    only the rays still `live` are weighed (finish zeroes the others' weights: most of a
    ghost path's rays die on the way)."""
    if coating.path_weight(idx, m1, m2, reflect, cos_out, wl, weight, live):
        return                       # compiled: every step of a ray in one loop
    done = ~np.isnan(cos_out)
    if not done.any():
        return
    with np.errstate(invalid="ignore", divide="ignore"):
        rr = coating.reflectance(idx[m1], idx[m2], np.where(done, cos_out, 1.0), wl)
    for s in range(cos_out.shape[0]):
        if done[s].any():
            weight *= np.where(done[s], rr[s] if reflect[s] else 1.0 - rr[s], 1.0)
