"""Blender's lights compiled (numba): each light as one flat row of numbers (`light_row`), its
sampling and the bounce rays that meet it as loops over rows, the numpy methods of
lights.Light kept as the reference (tests/engine/test_shading_kernels.py).

The equations are lights.py's (module docstring and Light.sample / Light.hit); this module
only lays a light out flat:
    KIND    0 point, 1 spot, 2 sun, 3 area          SHAPE  0 square or rectangle, 1 disk or
    ellipse; then colour (3), position (3), axis_x (3), axis_y (3), forward (3), the area's
    plane normal (3), radius, cos_half, smooth, cos_sun, size_x, size_y (the extent), area,
    the sun's solid angle, and whether the light has no size (a delta light).
Differences from the numpy reference: rounding only (dot products summed in another order).
"""

from __future__ import annotations

import math

import numpy as np

from ..core import jit
from .shading_kernels import basis_of

KINDS = {"POINT": 0, "SPOT": 1, "SUN": 2, "AREA": 3}
(_KIND, _SHAPE, _COL, _POS, _AX, _AY, _FWD, _NRM, _RADIUS, _COS_HALF, _SMOOTH, _COS_SUN,
 _SX, _SY, _AREA, _OMEGA, _DELTA) = (0, 1, 2, 5, 8, 11, 14, 17, 20, 21, 22, 23, 24, 25, 26,
                                     27, 28)
ROW = 29
_PI = math.pi

_njit = jit.njit(cache=True, nogil=True)
_inline = jit.njit(cache=True, nogil=True, inline="always")


def light_row(light) -> np.ndarray:
    """The flat row of a lights.Light (module docstring)."""
    row = np.zeros(ROW)
    row[_KIND] = KINDS[light.kind]
    row[_SHAPE] = 1.0 if light.shape in ("DISK", "ELLIPSE") else 0.0
    row[_COL:_COL + 3] = light.colour
    row[_POS:_POS + 3] = light.position
    row[_AX:_AX + 3] = light.axis_x
    row[_AY:_AY + 3] = light.axis_y
    row[_FWD:_FWD + 3] = light.forward
    if light.kind == "AREA":
        row[_NRM:_NRM + 3] = light.plane_normal
        row[_AREA] = light.area
    sx, sy = light._extent()
    row[_RADIUS], row[_COS_HALF], row[_SMOOTH] = light.radius, light.cos_half, light.smooth
    row[_COS_SUN], row[_SX], row[_SY] = light.cos_sun, sx, sy
    row[_OMEGA] = light.sun_solid_angle
    row[_DELTA] = 1.0 if light.is_delta else 0.0
    return row


@_inline
def _dot(L, k, x, y, z):
    return L[k] * x + L[k + 1] * y + L[k + 2] * z


@_inline
def _spot(L, wx, wy, wz):
    """Light._spot_mask for one unit direction towards the light."""
    if L[_KIND] != 1.0:
        return 1.0
    x = -_dot(L, _FWD, wx, wy, wz) - L[_COS_HALF]
    if not x > 0.0:
        return 0.0
    if L[_SMOOTH] > 0.0:
        s = min(max(x / L[_SMOOTH], 0.0), 1.0)
        return s * s * (3.0 - 2.0 * s)
    return 1.0


@_inline
def sample_one(L, px, py, pz, u1, u2, wi, dist, li, pdf, r):
    """Light.sample of the light row L at one shading point (px, py, pz) with uniforms u1, u2,
    written into row r of wi, dist, li and pdf."""
    kind = L[_KIND]
    fall = 0.0
    if kind == 2.0:                                   # sun
        ax, ay, az = -L[_FWD], -L[_FWD + 1], -L[_FWD + 2]
        if L[_COS_SUN] < 1.0:
            cos_t = 1.0 - u1 * (1.0 - L[_COS_SUN])
            sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
            t, b = basis_of(ax, ay, az)
            phi = 2.0 * _PI * u2
            c, s = sin_t * math.cos(phi), sin_t * math.sin(phi)
            wx = c * t[0] + s * b[0] + cos_t * ax
            wy = c * t[1] + s * b[1] + cos_t * ay
            wz = c * t[2] + s * b[2] + cos_t * az
            pdf[r] = 1.0 / L[_OMEGA]
        else:
            wx, wy, wz = ax, ay, az
            pdf[r] = math.inf
        wi[r, 0], wi[r, 1], wi[r, 2] = wx, wy, wz
        dist[r] = math.inf
        for c3 in range(3):
            li[r, c3] = L[_COL + c3]
        return
    if kind == 3.0:                                   # area
        if L[_SHAPE] == 1.0:
            rad = math.sqrt(u1)
            a = 0.5 * rad * math.cos(2 * _PI * u2)
            b = 0.5 * rad * math.sin(2 * _PI * u2)
        else:
            a, b = u1 - 0.5, u2 - 0.5
        a, b = a * L[_SX], b * L[_SY]
        vx = L[_POS] + a * L[_AX] + b * L[_AY] - px
        vy = L[_POS + 1] + a * L[_AX + 1] + b * L[_AY + 1] - py
        vz = L[_POS + 2] + a * L[_AX + 2] + b * L[_AY + 2] - pz
        d2 = vx * vx + vy * vy + vz * vz
        d = math.sqrt(d2)
        inv = 1.0 / max(d, 1e-12)
        wx, wy, wz = vx * inv, vy * inv, vz * inv
        cos_l = max(0.0, -_dot(L, _NRM, wx, wy, wz))
        fall = cos_l / (_PI * max(d2, 1e-12))
        pdf[r] = d2 / (L[_AREA] * max(cos_l, 1e-12)) if cos_l > 0.0 else 0.0
    else:                                             # point and spot: a disc facing p
        qx, qy, qz = L[_POS], L[_POS + 1], L[_POS + 2]
        radius = L[_RADIUS]
        if radius > 0.0:
            tx, ty, tz = px - qx, py - qy, pz - qz
            ln = max(math.sqrt(tx * tx + ty * ty + tz * tz), 1e-12)
            t, b = basis_of(tx / ln, ty / ln, tz / ln)
            rad = radius * math.sqrt(u1)
            phi = 2.0 * _PI * u2
            c, s = rad * math.cos(phi), rad * math.sin(phi)
            qx, qy, qz = qx + c * t[0] + s * b[0], qy + c * t[1] + s * b[1], \
                qz + c * t[2] + s * b[2]
        vx, vy, vz = qx - px, qy - py, qz - pz
        d2 = vx * vx + vy * vy + vz * vz
        d = math.sqrt(d2)
        inv = 1.0 / max(d, 1e-12)
        wx, wy, wz = vx * inv, vy * inv, vz * inv
        fall = _spot(L, wx, wy, wz) / (4.0 * _PI * max(d2, 1e-12))
        if radius > 0.0:
            cx, cy, cz = L[_POS] - px, L[_POS + 1] - py, L[_POS + 2] - pz
            cos_l = abs(wx * cx + wy * cy + wz * cz) / max(
                math.sqrt(cx * cx + cy * cy + cz * cz), 1e-12)
            fall = fall * cos_l
            pdf[r] = d2 / (_PI * radius * radius * max(cos_l, 1e-12))
        else:
            pdf[r] = math.inf
    wi[r, 0], wi[r, 1], wi[r, 2] = wx, wy, wz
    dist[r] = d
    for c3 in range(3):
        li[r, c3] = L[_COL + c3] * fall


@_njit
def sample(L, p, u1, u2, wi, dist, li, pdf):
    """Light.sample of the light row L at shading points p (N, 3) into wi (N, 3), dist (N,),
    li (N, 3) (Li / pdf) and pdf (N,)."""
    for r in range(p.shape[0]):
        sample_one(L, p[r, 0], p[r, 1], p[r, 2], u1[r], u2[r], wi, dist, li, pdf, r)


@_inline
def hit_one(L, ox, oy, oz, dx, dy, dz, escaped):
    """Light.hit of the light row L for one ray: (distance, inf where it misses; the
    radiance's scale of the light's colour; the density with which `sample` picks d)."""
    kind = L[_KIND]
    t, scale, dens, ok = math.inf, 0.0, 0.0, False
    if kind == 2.0:
        ok = -_dot(L, _FWD, dx, dy, dz) >= L[_COS_SUN] and escaped
        if ok:
            t, scale, dens = 1e30, 1.0 / L[_OMEGA], 1.0 / L[_OMEGA]
    elif kind == 3.0:
        den = _dot(L, _NRM, dx, dy, dz)
        tt = _dot(L, _NRM, L[_POS] - ox, L[_POS + 1] - oy, L[_POS + 2] - oz) \
            / (den if den < 0.0 else -1.0)
        qx = ox + tt * dx - L[_POS]
        qy = oy + tt * dy - L[_POS + 1]
        qz = oz + tt * dz - L[_POS + 2]
        a = _dot(L, _AX, qx, qy, qz) / _dot(L, _AX, L[_AX], L[_AX + 1], L[_AX + 2]) / L[_SX]
        b = _dot(L, _AY, qx, qy, qz) / _dot(L, _AY, L[_AY], L[_AY + 1], L[_AY + 2]) / L[_SY]
        inside = a * a + b * b <= 0.25 if L[_SHAPE] == 1.0 else \
            (abs(a) <= 0.5 and abs(b) <= 0.5)
        ok = den < 0.0 and tt > 0.0 and inside
        if ok:
            t, scale = tt, 1.0 / (_PI * L[_AREA])
            dens = tt * tt / (L[_AREA] * max(-den, 1e-12))
    else:
        tx, ty, tz = ox - L[_POS], oy - L[_POS + 1], oz - L[_POS + 2]
        dist_o = max(math.sqrt(tx * tx + ty * ty + tz * tz), 1e-12)
        den = (dx * tx + dy * ty + dz * tz) / dist_o
        tt = dist_o / max(-den, 1e-12)
        qx, qy, qz = tx + tt * dx, ty + tt * dy, tz + tt * dz
        radius = L[_RADIUS]
        ok = den < 0.0 and qx * qx + qy * qy + qz * qz <= radius * radius
        if ok:
            disc = _PI * radius * radius
            t = tt
            scale = _spot(L, dx, dy, dz) / (4.0 * _PI * disc)
            dens = tt * tt / (disc * max(-den, 1e-12))
    return t, scale, dens


@_njit
def hit(L, o, d, escaped, t_out, rad, pdf):
    """Light.hit of the light row L (a light with size, seen by bounce rays) for rays (o, d)
    into t_out (N,) (inf: missed), rad (N, 3) and pdf (N,); `escaped` (N,) for a sun."""
    for r in range(o.shape[0]):
        t, scale, dens = hit_one(L, o[r, 0], o[r, 1], o[r, 2], d[r, 0], d[r, 1], d[r, 2],
                                 escaped[r])
        t_out[r] = t
        pdf[r] = dens
        for c3 in range(3):
            rad[r, c3] = L[_COL + c3] * scale


def run_sample(row, p, u1, u2):
    k = p.shape[0]
    wi, dist, li, pdf = np.empty((k, 3)), np.empty(k), np.empty((k, 3)), np.empty(k)
    sample(row, np.ascontiguousarray(p, dtype=np.float64),
           np.ascontiguousarray(u1, dtype=np.float64),
           np.ascontiguousarray(u2, dtype=np.float64), wi, dist, li, pdf)
    return wi, dist, li, pdf


def run_hit(row, o, d, escaped):
    k = o.shape[0]
    esc = np.ones(k, dtype=np.bool_) if escaped is None else \
        np.ascontiguousarray(escaped, dtype=np.bool_)
    t, rad, pdf = np.empty(k), np.empty((k, 3)), np.empty(k)
    hit(row, np.ascontiguousarray(o, dtype=np.float64),
        np.ascontiguousarray(d, dtype=np.float64), esc, t, rad, pdf)
    return t, rad, pdf


# ---------------------------------------------------------------- emissive meshes (emitters.py)

_LUM_R, _LUM_G, _LUM_B = 0.2126, 0.7152, 0.0722     # emitters.LUMINANCE


@_inline
def emitters_sample_one(cdf, corners, emission, total, px, py, pz, u, u2, wi, dist, li, pdf,
                        r):
    """emitters.Emitters.sample at one shading point with uniforms u, u2 into row r of wi,
    dist, li (Li / p) and pdf: a triangle by power (the last CDF step at or below u), a point
    on it."""
    count = emission.shape[0]
    lo, hi = 0, cdf.shape[0]                  # first index with cdf > u, minus one
    while lo < hi:
        mid = (lo + hi) // 2
        if cdf[mid] <= u:
            lo = mid + 1
        else:
            hi = mid
    t = min(max(lo - 1, 0), count - 1)
    f = min(max((u - cdf[t]) / max(cdf[t + 1] - cdf[t], 1e-300), 0.0), 1.0)
    s = math.sqrt(f)
    wa, wb, wc = 1.0 - s, s * (1.0 - u2), s * u2
    vx = wa * corners[t, 0, 0] + wb * corners[t, 1, 0] + wc * corners[t, 2, 0] - px
    vy = wa * corners[t, 0, 1] + wb * corners[t, 1, 1] + wc * corners[t, 2, 1] - py
    vz = wa * corners[t, 0, 2] + wb * corners[t, 1, 2] + wc * corners[t, 2, 2] - pz
    d2 = vx * vx + vy * vy + vz * vz
    d = math.sqrt(d2)
    inv = 1.0 / max(d, 1e-12)
    wx, wy, wz = vx * inv, vy * inv, vz * inv
    ax, ay, az = (corners[t, 1, 0] - corners[t, 0, 0], corners[t, 1, 1] - corners[t, 0, 1],
                  corners[t, 1, 2] - corners[t, 0, 2])
    bx, by, bz = (corners[t, 2, 0] - corners[t, 0, 0], corners[t, 2, 1] - corners[t, 0, 1],
                  corners[t, 2, 2] - corners[t, 0, 2])
    nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    ln = max(math.sqrt(nx * nx + ny * ny + nz * nz), 1e-300)
    cos_l = abs(wx * nx + wy * ny + wz * nz) / ln
    p_a = max(emission[t, 0] * _LUM_R + emission[t, 1] * _LUM_G
              + emission[t, 2] * _LUM_B, 0.0) / max(total, 1e-300)
    dens = p_a * d2 / max(cos_l, 1e-12)
    ok = cos_l > 1e-9 and p_a > 0.0
    wi[r, 0], wi[r, 1], wi[r, 2] = wx, wy, wz
    dist[r] = d
    pdf[r] = dens if ok else 0.0
    for c in range(3):
        li[r, c] = emission[t, c] / dens if ok else 0.0


@_njit
def emitters_sample(cdf, corners, emission, total, p, u1, u2, wi, dist, li, pdf):
    """emitters_sample_one for shading points p (N, 3) into wi, dist, li and pdf."""
    for r in range(p.shape[0]):
        emitters_sample_one(cdf, corners, emission, total, p[r, 0], p[r, 1], p[r, 2], u1[r],
                            u2[r], wi, dist, li, pdf, r)


def run_emitters_sample(emitters, p, u1, u2):
    k = p.shape[0]
    wi, dist, li, pdf = np.empty((k, 3)), np.empty(k), np.empty((k, 3)), np.empty(k)
    emitters_sample(emitters.cdf, np.ascontiguousarray(emitters.corners),
                    np.ascontiguousarray(emitters.emission), float(emitters.total),
                    np.ascontiguousarray(p, dtype=np.float64),
                    np.ascontiguousarray(u1, dtype=np.float64),
                    np.ascontiguousarray(u2, dtype=np.float64), wi, dist, li, pdf)
    return wi, dist, li, pdf
