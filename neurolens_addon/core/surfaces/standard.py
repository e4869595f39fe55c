"""The standard surface: sphere, plane and conic of revolution (kind "standard").

Parameters: radius R (mm, signed: > 0 when the centre of curvature lies on the sensor side of
the vertex; inf: a plane), conic constant k; c = 1 / R, rho = x^2 + y^2. In the local frame
(s = z_v - z) the surface is the quadric through the vertex
    c rho + c (1 + k) s^2 - 2 s = 0,
i.e. s = sag(rho) = c rho / (1 + sqrt(1 - (1 + k) c^2 rho)), real for (1 + k) c^2 rho <= 1
(k = 0 sphere, -1 < k < 0 prolate ellipse, k = -1 paraboloid, k < -1 hyperbola, k > 0 oblate).

Intersection with o + t d (s_0 = z_v - o_z, d_s = -d_z): A t^2 + 2 B t + C = 0 with
    A = c (d_x^2 + d_y^2) + c (1 + k) d_s^2  (= c for a sphere, d unit),
    B = c (o_x d_x + o_y d_y) + (c (1 + k) s_0 - 1) d_s,
    C = c (o_x^2 + o_y^2) + (c (1 + k) s_0 - 2) s_0;
both roots without cancellation, q / A and C / q with q = -(B + sign(B) sqrt(B^2 - AC)), and
the nearest forward root on the cap through the vertex (1 - c (1 + k) s > 0) is taken; a ray
starting beyond the centre of curvature meets that cap at its far root. A plane (c = 0):
t = -s_0 / d_s.
Normal (lens space): (-c x, -c y, -(1 - c (1 + k) s)); a plane's (0, 0, 1) is already unit.
Paraxial curvature: c.
Compiled trace (surfaces/kernels.py: conic_root, conic_normal): the same root and normal per
ray, from the row (c, c (1 + k)).

Lens file keys: `radius` (mm; "flat", "inf", "infinity" or +-inf for a plane; 0 is refused),
`conic` (k, default 0). Checks: R != 0, k finite, and the semi-diameter within the surface:
1 - (1 + k) c^2 sd^2 >= 0 (to 1e-12).

OSL: nl_conic_root solves the quadratic above in float32; spheres that refract (k = 0, not the
stop) use one fused call: with |R| <= SPHERE_CENTRE_FORM_MAX_MM the centre form
    oc = o - (0, 0, z_v - R),   t = -oc.d -/+ sqrt((oc.d)^2 - |oc|^2 + R^2)
(no division; its float32 rounding error grows like eps |R|, so flatter spheres keep the
cancellation-free quadratic), then the unit normal (-c x, -c y, c s - 1) for refraction (why
the centre form: docs/measurements.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import numpy as np

from ..lensfields import describe, toml_float
from ..oslfmt import flt as osl_flt
from .base import (BACKWARD_TOLERANCE_MM, KERNEL_CONIC, KERNEL_PLANE,
                   OSL_BACKWARD_TOLERANCE_MM, SurfaceShape)
from .registry import register

#: spheres up to this |radius| are intersected in the centre form in OSL (no division; its
#: float32 error grows like 1e-7 |R| mm), flatter ones with the cancellation-free quadratic
SPHERE_CENTRE_FORM_MAX_MM = 200.0




@register
@dataclass(frozen=True)
class StandardSurface(SurfaceShape):
    """Sphere, plane (radius_mm = inf) or conic of revolution (conic = k)."""

    radius_mm: float
    conic: float = 0.0

    kind = "standard"
    required_keys = ("radius",)
    optional_keys = ("conic",)
    implied = True

    @property
    def is_plane(self) -> bool:
        return math.isinf(self.radius_mm) and not self.aspheric

    @property
    def label(self) -> str:
        return "plane" if self.is_plane else ("conic" if self.conic else "sphere")

    # ---- geometry --------------------------------------------------------------------------
    def hit(self, zv, ox, oy, oz, dx, dy, dz):
        # Local frame s = z_vertex - z: s grows towards the sensor, the patent's direction.
        s0 = zv - oz
        ds = -dz
        t, miss, unconverged = self._root(ox, oy, s0, dx, dy, ds)
        miss |= t < -BACKWARD_TOLERANCE_MM
        return t, miss, unconverged

    def _root(self, ox, oy, s0, dx, dy, ds):
        if self.is_plane:
            with np.errstate(divide="ignore", invalid="ignore"):
                t = -s0 / ds
            return t, ~np.isfinite(t), None
        t, miss = self._conic_root(ox, oy, s0, dx, dy, ds)
        return t, miss, None

    def _conic_root(self, ox, oy, s0, dx, dy, ds):
        """(t, miss): the nearest forward root on the cap through the vertex."""
        c = self.curvature
        ck = c * (1.0 + self.conic)
        if ck == c:
            a = c                        # sphere: c (dx^2 + dy^2 + dz^2) = c, d is unit
        else:
            a = ds * ds
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
        return t, miss

    def normal(self, zv, x, y, z, rho):
        if self.is_plane:
            nx = np.zeros_like(x)
            return nx, nx, np.ones_like(x)
        c = self.curvature
        s_hit = zv - z
        return -c * x, -c * y, -(1.0 - c * (1.0 + self.conic) * s_hit)

    @property
    def normal_is_unit(self) -> bool:
        return self.is_plane

    def kernel_params(self):
        """A plane: nothing; a conic: (c, c (1 + k))."""
        if self.is_plane:
            return KERNEL_PLANE, ()
        c = self.curvature
        return KERNEL_CONIC, (c, c * (1.0 + self.conic))

    def sag(self, x, y, *, clamp=False):
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        return self.sag_rho(x * x + y * y, clamp=clamp)

    def sag_rho(self, rho, *, clamp=False):
        """sag at squared radius rho: NaN outside the conic (or, with clamp, its rim value)."""
        c = self.curvature
        with np.errstate(invalid="ignore", over="ignore"):
            arg = 1.0 - c * (1.0 + self.conic) * c * rho
            q = np.sqrt(np.maximum(arg, 0.0) if clamp else arg)
            return c * rho / (1.0 + q)

    @property
    def paraxial_curvature(self) -> float:
        return self.curvature

    # ---- lens file -------------------------------------------------------------------------
    @classmethod
    def from_table(cls, table, fields):
        radius = _read_radius(table["radius"], fields)
        conic = fields.number(table.get("conic", 0.0), "conic")
        terms = cls._read_terms(table, fields)
        scale = fields.scale
        if math.isfinite(radius) and math.isinf(radius * scale):
            raise fields.error(f"radius {radius:g} is out of range after scale = {scale:g}",
                               "radius")
        return cls._build(radius * scale, conic + 0.0, terms)

    @classmethod
    def _read_terms(cls, table, fields) -> tuple:
        return ()

    @classmethod
    def _build(cls, radius_mm, conic, terms):
        return StandardSurface(radius_mm, conic)

    def check(self, semi_diameter_mm, fields):
        r = self.radius_mm
        if math.isnan(r) or r == 0.0:
            raise fields.error(f"radius must be non-zero (\"flat\" for a plane), got {r:g}",
                               "radius")
        if not math.isfinite(self.conic):
            raise fields.error(f"conic must be finite, got {self.conic:g}", "conic")
        self._check_terms(fields)
        c = self.curvature
        sd = semi_diameter_mm
        if 1.0 - (1.0 + self.conic) * c * c * sd * sd < -1e-12:
            r_max = 1.0 / (abs(c) * math.sqrt(1.0 + self.conic))
            shape = (f"a sphere of radius {abs(r):g} mm" if self.conic == 0.0
                     else f"a conic with radius {r:g} mm and k = {self.conic:g}")
            raise fields.error(f"semi_diameter {sd:g} mm is larger than the surface allows: "
                               f"{shape} has no points beyond r = {r_max:g} mm "
                               "(1 - (1+k) c^2 r^2 < 0)", "semi_diameter", scaled=True)

    def _check_terms(self, fields) -> None:
        pass

    def toml_items(self):
        r = float(self.radius_mm)
        items = [("radius", '"flat"' if math.isinf(r) else toml_float(r))]
        if self.conic != 0.0:
            items.append(("conic", toml_float(self.conic)))
        return items

    # ---- OSL -------------------------------------------------------------------------------
    @classmethod
    def osl_library(cls):
        return list(_osl_library())

    def osl_hit(self, index, zv, sd2):
        flt = osl_flt
        if self.is_plane:
            return [], [f"if (!nl_plane(p, d, {flt(zv)}, {sd2})) return;"], \
                "vector(0.0, 0.0, 1.0)"
        c = self.curvature
        ck = c * (1.0 + self.conic)
        return ([], [f"if (!nl_conic(p, d, {flt(zv)}, {flt(c)}, {flt(ck)}, {sd2})) return;"],
                f"vector({flt(-c)} * p[0], {flt(-c)} * p[1], {flt(ck)} * ({flt(zv)} - p[2]) "
                "- 1.0)")

    def osl_fused(self, zv, sd2, eta):
        if self.is_plane or self.conic != 0.0:
            return None
        flt = osl_flt
        c = self.curvature
        if abs(self.radius_mm) <= SPHERE_CENTRE_FORM_MAX_MM:
            return [f"if (!nl_sphere(p, d, {flt(zv)}, {flt(c)}, {flt(self.radius_mm)}, "
                    f"{sd2}, {eta})) return;"]
        return [f"if (!nl_sphere_shallow(p, d, {flt(zv)}, {flt(c)}, {sd2}, {eta})) return;"]


def _read_radius(value, fields) -> float:
    if isinstance(value, str):
        if value.strip().lower() in ("flat", "inf", "infinity"):
            return math.inf
        raise fields.error(f"expected a number (mm) or \"flat\", got {describe(value)}",
                           "radius")
    r = fields.number(value, "radius", allow_inf=True)
    if r == 0.0:
        raise fields.error("radius 0 is not allowed: write radius = \"flat\" for a plane",
                           "radius")
    return math.inf if math.isinf(r) else r


@cache
def _osl_library() -> tuple[str, ...]:
    tol = osl_flt(-OSL_BACKWARD_TOLERANCE_MM)
    return tuple(f"""
// Nearest forward root of the conic through the vertex z_v (local s = z_v - z); 0 if none.
int nl_conic_root(point p, vector d, float zv, float c, float ck, output float t)
{{
    float s0 = zv - p[2];
    float ds = -d[2];
    float a = c + (ck - c) * ds * ds;
    float b = c * (p[0] * d[0] + p[1] * d[1]) + (ck * s0 - 1.0) * ds;
    float cc = c * (p[0] * p[0] + p[1] * p[1]) + (ck * s0 - 2.0) * s0;
    float disc = b * b - a * cc;
    if (disc < 0.0) return 0;
    float q = b >= 0.0 ? -(b + sqrt(disc)) : -(b - sqrt(disc));
    if (q == 0.0) return 0;
    float t2 = cc / q;
    int ok2 = t2 >= {tol} && 1.0 - ck * (s0 + t2 * ds) > 0.0;
    if (a != 0.0) {{
        float t1 = q / a;
        if (t1 >= {tol} && 1.0 - ck * (s0 + t1 * ds) > 0.0
            && (!ok2 || t1 < t2)) {{
            t = t1;
            return 1;
        }}
    }}
    t = t2;
    return ok2;
}}

// Move to a spherical or conic surface; 0 if missed or beyond the semi-diameter.
int nl_conic(output point p, output vector d, float zv, float c, float ck, float sd2)
{{
    float t = 0.0;
    if (!nl_conic_root(p, d, zv, c, ck, t)) return 0;
    p += t * d;
    return p[0] * p[0] + p[1] * p[1] <= sd2;
}}

// Through a sphere (radius R = 1/c, |R| <= SPHERE_CENTRE_FORM_MAX_MM) at z_v: intersect in the
// centre form (oc = p - (0, 0, z_v - R): t = -oc.d -/+ sqrt((oc.d)^2 - |oc|^2 + R^2), no
// division), take the nearer forward root on the cap, clip at the semi-diameter, refract with
// eta. The normal (-c x, -c y, c s - 1) is unit.
int nl_sphere(output point p, output vector d, float zv, float c, float r, float sd2,
              float eta)
{{
    vector oc = vector(p[0], p[1], p[2] - (zv - r));
    float b = dot(oc, d);
    float disc = b * b - (dot(oc, oc) - r * r);
    if (disc < 0.0) return 0;
    float sq = sqrt(disc);
    float t = -b - sq;
    if (!(t >= {tol} && 1.0 - c * (zv - p[2] - t * d[2]) > 0.0)) {{
        t = sq - b;
        if (!(t >= {tol} && 1.0 - c * (zv - p[2] - t * d[2]) > 0.0))
            return 0;
    }}
    p += t * d;
    if (p[0] * p[0] + p[1] * p[1] > sd2) return 0;
    return nl_refract_unit(d, vector(-c * p[0], -c * p[1], c * (zv - p[2]) - 1.0), eta);
}}

// The same for shallow spheres (|R| large: the centre form would lose float32 precision):
// the conic root without cancellation (nl_conic_root), then refraction.
int nl_sphere_shallow(output point p, output vector d, float zv, float c, float sd2, float eta)
{{
    float t = 0.0;
    if (!nl_conic_root(p, d, zv, c, c, t)) return 0;
    p += t * d;
    if (p[0] * p[0] + p[1] * p[1] > sd2) return 0;
    return nl_refract_unit(d, vector(-c * p[0], -c * p[1], c * (zv - p[2]) - 1.0), eta);
}}

// Move to a plane z = z_v; 0 if behind the ray or beyond the semi-diameter.
int nl_plane(output point p, vector d, float zv, float sd2)
{{
    if (!(d[2] > 0.0)) return 0;
    p += ((zv - p[2]) / d[2]) * d;
    return p[0] * p[0] + p[1] * p[1] <= sd2;
}}
""".strip().splitlines())
