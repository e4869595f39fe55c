"""The compiled twin of each surface kind's geometry: hit and normal of one ray, float64.

One function per kind, as each kind has one OSL emitter; each computes what the kind's numpy
methods compute on whole arrays (the equations are in the kind's module), for a single ray,
from the kind's row of the flat surface table (`kernel_params`: a KERNEL_* code and numbers p):
- plane (KERNEL_PLANE, standard.py): t = -s_0 / d_s; normal (0, 0, 1), unit;
- conic (KERNEL_CONIC, standard.py; p = c, c (1 + k)): `conic_root`, the nearest forward root
  of A t^2 + 2 B t + C = 0 on the cap through the vertex, both roots without cancellation
  (q = -(B + sign(B) sqrt(B^2 - AC)), t = q / A or C / q); normal (-c x, -c y,
  -(1 - c (1 + k) s));
- even asphere (KERNEL_ASPHERE, asphere.py; p = c, c (1 + k), the highest h, A_2 .. A_20):
  `asphere_hit`, Newton on f(t) = s_0 + t d_s - sag(rho(t)) from the conic's root (else from
  the vertex plane), sag and g = dsag/drho by `asphere_sag_slope` (Horner in rho); normal
  (-2 x g, -2 y g, -1);
- biconic and cylinder (KERNEL_BICONIC, anamorphic.py; p = c_u, c_v, 1 + k_u, 1 + k_v, cos r,
  sin r): `biconic_local`, S = (c_u u^2 + c_v v^2) / (1 + sqrt(1 - (1 + k_u) c_u^2 u^2 -
  (1 + k_v) c_v^2 v^2)) and its gradient;
- toroidal (KERNEL_TOROIDAL, anamorphic.py; p = c_v, 1 + k_v, R_u, sign R_u, cos r, sin r):
  `toroidal_local`, S = R_u - sign(R_u) sqrt((R_u - f(v))^2 - u^2) with the conic profile
  f(v) (`conic_profile`, shared with the asphere's base sag);
  the anamorphic kinds share their hit (`_anamorphic_kind`: Newton on
  f(t) = s_0 + t d_s - S(u(t), v(t)), f' = d_s - (s_x d_x + s_y d_y), the lens-space gradient
  turned back from (S_u, S_v)) and their normal (-s_x, -s_y, -1).
Local frame as everywhere: s = z_v - z, s_0 = z_v - o_z, d_s = -d_z. Divisions by zero and
square roots of negatives give inf / NaN as numpy's do (error_model "numpy"), and the same
tests on them (not finite, NaN comparisons false) give the same misses.

core.trace_compiled runs these per ray inside its parallel loop; numba inlines them there.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import njit
from .anamorphic import NEWTON_MAX_ITERATIONS, NEWTON_RESIDUAL_MM, NEWTON_STEP_MM
from .asphere import ASPHERE_CONVERGED_MM, ASPHERE_MAX_ITERATIONS, ASPHERE_TOLERANCE_MM
from .base import BACKWARD_TOLERANCE_MM, KERNEL_PARAMS

_DEVICE = dict(error_model="numpy", cache=False, inline="always")


@njit(**_DEVICE)
def conic_root(c, ck, ox, oy, s0, dx, dy, ds):
    """(t, miss): the nearest forward root on the conic's cap through the vertex."""
    if ck == c:
        a = c                          # sphere: c |d|^2 = c
    else:
        a = ds * ds * (ck - c) + c     # c (1 - d_s^2) + c (1 + k) d_s^2
    b = (ox * dx + oy * dy) * c + (ck * s0 - 1.0) * ds
    cc = (ox * ox + oy * oy) * c + (ck * s0 - 2.0) * s0
    disc = b * b - a * cc
    miss = disc < 0.0
    if disc < 0.0:
        disc = 0.0
    root = math.sqrt(disc)
    q = -(root + b) if b >= 0.0 else -(b - root)
    t2 = cc / q
    t1 = q / a
    # the cap through the vertex: 1 - c (1 + k) s > 0 (a ray from beyond the centre of
    # curvature meets it at its far root)
    ok1 = t1 >= -BACKWARD_TOLERANCE_MM and (1.0 - ck * (s0 + t1 * ds)) > 0.0
    ok2 = t2 >= -BACKWARD_TOLERANCE_MM and (1.0 - ck * (s0 + t2 * ds)) > 0.0
    t = t1 if ok1 and (not ok2 or t1 < t2) else t2
    miss = miss or not (ok1 or ok2) or not math.isfinite(t)
    return t, miss


@njit(**_DEVICE)
def conic_profile(c, ck, w2):
    """(sag, root q = sqrt(1 - c (1 + k) c w2)) of a conic at squared coordinate w2; NaN
    beyond the conic."""
    q = math.sqrt(1.0 - ck * c * w2)
    return c * w2 / (1.0 + q), q


@njit(**_DEVICE)
def asphere_sag_slope(p, rho):
    """(sag, g = dsag/drho) of the even asphere of row p at rho: the conic plus
    sum_h A_2h rho^h, both in Horner form."""
    c = p[0]
    sg, q = conic_profile(c, p[1], rho)
    slope = c / (2.0 * q)
    top = int(p[2])
    poly = 0.0
    dpoly = 0.0
    for h in range(top, 0, -1):
        a = p[2 + h]
        dpoly = dpoly * rho + h * a if h < top else h * a
        poly = (poly + a) * rho
    return sg + poly, slope + dpoly


@njit(**_DEVICE)
def _asphere_refine(p, ox, oy, s0, dx, dy, ds, t):
    """Newton from t on f(t) = s_0 + t d_s - sag(rho(t)); (t, not converged)."""
    if not math.isfinite(t):
        t = 0.0
    for _ in range(ASPHERE_MAX_ITERATIONS):
        x = ox + t * dx
        y = oy + t * dy
        sg, slope = asphere_sag_slope(p, x * x + y * y)
        step = (s0 + t * ds - sg) / (ds - 2.0 * slope * (x * dx + y * dy))
        t = t - step
        if not abs(step) > ASPHERE_TOLERANCE_MM:
            break
    x = ox + t * dx
    y = oy + t * dy
    sg, _slope = asphere_sag_slope(p, x * x + y * y)
    return t, not abs(s0 + t * ds - sg) <= ASPHERE_CONVERGED_MM


@njit(**_DEVICE)
def _asphere_root(p, ox, oy, s0, dx, dy, ds):
    """(t, miss, unconverged): from the base conic's root; without one, from the vertex plane,
    where a ray Newton does not bring onto the surface misses it."""
    t, miss = conic_root(p[0], p[1], ox, oy, s0, dx, dy, ds)
    if not miss:
        t, unconverged = _asphere_refine(p, ox, oy, s0, dx, dy, ds, t)
        return t, False, unconverged
    start = -s0 / ds if ds != 0.0 else 0.0
    t, unconverged = _asphere_refine(p, ox, oy, s0, dx, dy, ds, start)
    return t, unconverged or not math.isfinite(t), False


@njit(**_DEVICE)
def biconic_local(p, u, v):
    """(S, S_u, S_v) of the biconic of row p at local (u, v)."""
    cu, cv, ku1, kv1 = p[0], p[1], p[2], p[3]
    n = cu * u * u + cv * v * v
    q = math.sqrt(1.0 - ku1 * cu * cu * u * u - kv1 * cv * cv * v * v)
    den = (1.0 + q) * (1.0 + q)
    # d/du of n / (1 + q), with dq/du = -(1 + k_u) c_u^2 u / q
    su = 0.0 if u == 0.0 else (2.0 * cu * u * (1.0 + q) + n * (ku1 * cu * cu * u / q)) / den
    sv = 0.0 if v == 0.0 else (2.0 * cv * v * (1.0 + q) + n * (kv1 * cv * cv * v / q)) / den
    return n / (1.0 + q), su, sv


@njit(**_DEVICE)
def toroidal_local(p, u, v):
    """(S, S_u, S_v) of the toroid of row p at local (u, v)."""
    cv = p[0]
    f, q = conic_profile(cv, p[1] * cv, v * v)
    fp = 0.0 if v == 0.0 else cv * v / q
    ru = p[2]
    if math.isinf(ru):
        return f + 0.0 * u, 0.0, fp + 0.0 * u
    sign = p[3]
    a = ru - f
    root = math.sqrt(a * a - u * u)
    su = 0.0 if u == 0.0 else sign * u / root
    return ru - sign * root, su, sign * a * fp / root


def _anamorphic_kind(local):
    """(hit, normal, sag and lens-space gradient) of the anamorphic kind whose local sag is
    `local`: one Newton iteration and frame for all of them. (Closures over `local`, not
    `local` passed as an argument: numba then calls it directly and can cache the kernel.)"""
    @njit(**_DEVICE)
    def turned_gradient(p, x, y):
        """(s, s_x, s_y): the local sag at (u, v), its gradient turned back to lens space."""
        cr, sr = p[4], p[5]
        s, su, sv = local(p, x * cr + y * sr, -x * sr + y * cr)
        return s, su * cr - sv * sr, su * sr + sv * cr

    @njit(**_DEVICE)
    def hit(p, zv, ox, oy, oz, dx, dy, dz):
        """(t, miss, unconverged): Newton from the vertex plane, each step kept only while
        finite and above NEWTON_STEP_MM."""
        s0 = zv - oz
        ds = -dz
        t = -s0 / ds if ds != 0.0 else 0.0
        for _ in range(NEWTON_MAX_ITERATIONS):
            s, sx, sy = turned_gradient(p, ox + t * dx, oy + t * dy)
            step = (s0 + t * ds - s) / (ds - (sx * dx + sy * dy))
            if not math.isfinite(step):
                step = 0.0
            t = t - step
            if not abs(step) > NEWTON_STEP_MM:
                break
        s, _sx, _sy = turned_gradient(p, ox + t * dx, oy + t * dy)
        unconverged = not abs(s0 + t * ds - s) <= NEWTON_RESIDUAL_MM
        return t, not math.isfinite(t) or t < -BACKWARD_TOLERANCE_MM, unconverged

    @njit(**_DEVICE)
    def normal(p, zv, x, y, z, rho):
        _s, sx, sy = turned_gradient(p, x, y)
        return -sx, -sy, -1.0

    return hit, normal


# ---- each kind's hit(p, z_v, o, d) -> (t, miss, unconverged) and normal(p, z_v, x, y, z, rho)
@njit(**_DEVICE)
def plane_hit(p, zv, ox, oy, oz, dx, dy, dz):
    t = (zv - oz) / dz                 # -s_0 / d_s
    return t, not math.isfinite(t), False


@njit(**_DEVICE)
def plane_normal(p, zv, x, y, z, rho):
    return 0.0, 0.0, 1.0


@njit(**_DEVICE)
def conic_hit(p, zv, ox, oy, oz, dx, dy, dz):
    t, miss = conic_root(p[0], p[1], ox, oy, zv - oz, dx, dy, -dz)
    return t, miss, False


@njit(**_DEVICE)
def conic_normal(p, zv, x, y, z, rho):
    c = p[0]
    return -c * x, -c * y, -(1.0 - p[1] * (zv - z))


@njit(**_DEVICE)
def asphere_hit(p, zv, ox, oy, oz, dx, dy, dz):
    return _asphere_root(p, ox, oy, zv - oz, dx, dy, -dz)


@njit(**_DEVICE)
def asphere_normal(p, zv, x, y, z, rho):
    _sg, g = asphere_sag_slope(p, rho)
    return -2.0 * x * g, -2.0 * y * g, -1.0


biconic_hit, biconic_normal = _anamorphic_kind(biconic_local)
toroidal_hit, toroidal_normal = _anamorphic_kind(toroidal_local)


def table_row(shape) -> tuple[int, np.ndarray] | None:
    """(code, numbers padded to KERNEL_PARAMS) of a shape, or None without a compiled twin."""
    row = shape.kernel_params()
    if row is None:
        return None
    code, numbers = row
    out = np.zeros(KERNEL_PARAMS)
    out[:len(numbers)] = numbers
    return int(code), out
