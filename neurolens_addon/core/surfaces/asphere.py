"""The even asphere (kind "even_asphere"): a standard surface plus even polynomial terms.

With c = 1 / R, conic k, rho = x^2 + y^2 and coefficients A_2h of r^2h (h = 1..10):
    sag(rho) = c rho / (1 + sqrt(1 - (1 + k) c^2 rho)) + sum_h A_2h rho^h,
    g(rho) = dsag/drho = c / (2 sqrt(1 - (1 + k) c^2 rho)) + sum_h h A_2h rho^(h-1).
Intersection with o + t d (s_0 = z_v - o_z, d_s = -d_z; x, y, rho at o + t d): Newton's
method on
    f(t) = s_0 + t d_s - sag(rho(t)),   f'(t) = d_s - 2 g (x d_x + y d_y),   t <- t - f / f',
for at most ASPHERE_MAX_ITERATIONS steps, stopping once every step is below
ASPHERE_TOLERANCE_MM. It starts from
    t_0 = the base conic's forward root on its cap (standard.py), where it has one;
    t_0 = -s_0 / d_s, the vertex plane s = 0 (0 where d_s = 0), where it has none:
the polynomial terms can carry the surface past a ray's start (a resin layer's asphere just
behind the glass: the conic's root lies behind the ray) or onto a ray that passes beside the
conic (a negative discriminant). A final |f| above ASPHERE_CONVERGED_MM (1e-7 mm): from the
conic's root, the ray has not converged; from the vertex plane, it misses the surface (no root
found), as does a root behind the ray's start. The trace keeps a hit only within the semi-diameter.
Normal (lens space): grad(s - sag) = (-2 x g, -2 y g, -1).
Paraxial curvature: c + 2 A_2 (the r^2 term adds to the vertex curvature).
Compiled trace (surfaces/kernels.py: asphere_hit, asphere_sag_slope): the same iteration per
ray, each ray stopping at its own converged step (here the whole array steps on until every
ray has: the extra steps move t by less than the tolerance), sag and g in Horner form.

Lens file: the standard keys plus `aspheric = { a4 = ..., a6 = ... }` (even terms a2..a20, the
coefficient of r^n in mm^(1-n); zero terms are dropped). Under `scale` s, a_n becomes
a_n s^(1-n), so that the scaled surface is the original magnified: sag'(s r) = s sag(r).
A [[surface]] table without `kind` is read as this kind; without terms it is a
StandardSurface. Checks: the standard ones, powers 2..20 with finite coefficients, and a finite
sag over the semi-diameter.

OSL: one specialised function per surface, the Newton iteration above in float32 with sag and
g in Horner form and the constants folded in, from the same t_0 (nl_conic_root's root, else
(z_v - p_z) / d_z); it drops the ray unless the final |f| <= ASPHERE_RESIDUAL_MM.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..lensfields import describe, toml_float
from .base import CHECK_SAMPLES, KERNEL_ASPHERE, OSL_BACKWARD_TOLERANCE_MM
from .registry import register
from .standard import StandardSurface, osl_flt

ASPHERE_MAX_ITERATIONS = 16
ASPHERE_TOLERANCE_MM = 1e-10
#: a final |f| above this (float64) has not converged (or, from the vertex plane, misses)
ASPHERE_CONVERGED_MM = 1e-7
#: float32 (OSL): Newton stops below this step, and a hit must satisfy |f| <= the residual
ASPHERE_STEP_TOLERANCE_MM = 1e-6
ASPHERE_RESIDUAL_MM = 1e-4

ASPHERIC_POWERS = tuple(range(2, 21, 2))
_ASPHERIC_KEYS = tuple(f"a{p}" for p in ASPHERIC_POWERS)


def rotational(radius_mm: float, conic: float = 0.0, aspheric=()):
    """The shape of a rotationally symmetric prescription row (radius, conic, even terms as
    (power, coefficient) pairs): an EvenAsphere where it has terms, else a StandardSurface."""
    if aspheric:
        return EvenAsphere(radius_mm, conic, aspheric)
    return StandardSurface(radius_mm, conic)


@register
@dataclass(frozen=True)
class EvenAsphere(StandardSurface):
    """A StandardSurface plus even terms `aspheric`: ((power, coefficient), ...)."""

    radius_mm: float
    conic: float = 0.0
    aspheric: tuple = ()

    kind = "even_asphere"
    optional_keys = ("conic", "aspheric")

    @property
    def label(self) -> str:
        return "asphere" if self.aspheric else super().label

    # ---- geometry --------------------------------------------------------------------------
    def _root(self, ox, oy, s0, dx, dy, ds):
        t, miss, unconverged = super()._root(ox, oy, s0, dx, dy, ds)
        if not self.aspheric:
            return t, miss, unconverged
        t, unconverged = self._refine(ox, oy, s0, dx, dy, ds, t, ~miss)
        if np.any(miss):
            # No forward root of the base conic (the polynomial terms move the surface across
            # the ray's start, or onto a ray that passes outside the conic): Newton from the
            # vertex plane s = 0 instead; a ray it does not bring onto the surface still misses.
            m = np.nonzero(miss)[0]
            s0m, dsm = s0[m], ds[m]
            with np.errstate(invalid="ignore", divide="ignore"):
                start = np.where(dsm != 0.0, -s0m / np.where(dsm != 0.0, dsm, 1.0), 0.0)
            tm, um = self._refine(ox[m], oy[m], s0m, dx[m], dy[m], dsm, start,
                                  np.ones(m.size, dtype=bool))
            t[m] = tm
            miss[m] = um | ~np.isfinite(tm)
            unconverged[m] = False
        return t, miss, unconverged

    def _refine(self, ox, oy, s0, dx, dy, ds, t, watch):
        """Newton steps on f(t) = s(t) - sag(rho(t)) from the starting t; stops as soon as
        every ray in `watch` (the rays worth refining) has converged. (t, unconverged)."""
        t = np.where(np.isfinite(t), t, 0.0)
        watch = watch.copy()
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            for _ in range(ASPHERE_MAX_ITERATIONS):
                x = ox + t * dx
                y = oy + t * dy
                rho = x * x + y * y
                sg, slope = self._sag_and_slope(rho)
                f = s0 + t * ds - sg
                fp = ds - 2.0 * slope * (x * dx + y * dy)
                step = f / fp
                t = t - step
                watch &= np.abs(step) > ASPHERE_TOLERANCE_MM
                if not watch.any():
                    break
            x = ox + t * dx
            y = oy + t * dy
            resid = np.abs(s0 + t * ds - self.sag_rho(x * x + y * y))
        unconverged = ~(resid <= ASPHERE_CONVERGED_MM)
        return t, unconverged

    def _sag_and_slope(self, rho):
        """sag(rho) and d sag / d rho together: one square root, Horner in rho for the terms."""
        c = self.curvature
        with np.errstate(invalid="ignore", divide="ignore"):
            q = np.sqrt(1.0 - c * (1.0 + self.conic) * c * rho)
            sg = c * rho / (1.0 + q)
            slope = c / (2.0 * q)
        if self.aspheric:
            # sum_h A_2h rho^h and its derivative sum_h h A_2h rho^(h-1), h = power / 2
            coef = {p // 2: a for p, a in self.aspheric}
            top = max(coef)
            poly = np.zeros_like(rho)
            dpoly = np.zeros_like(rho)
            for h in range(top, 0, -1):
                a = coef.get(h, 0.0)
                dpoly = dpoly * rho + h * a if h < top else np.full_like(rho, h * a)
                poly = (poly + a) * rho
            sg = sg + poly
            slope = slope + dpoly
        return sg, slope

    def _slope(self, rho):
        """d sag / d rho: c / (2 sqrt(1 - (1+k) c^2 rho)) + sum_n A_n (n/2) rho^(n/2 - 1)."""
        c = self.curvature
        with np.errstate(invalid="ignore", divide="ignore"):
            out = c / (2.0 * np.sqrt(1.0 - c * (1.0 + self.conic) * c * rho))
        for p, a in self.aspheric:
            h = p // 2
            out = out + (a * h) * (rho ** (h - 1) if h > 1 else 1.0)
        return out

    def normal(self, zv, x, y, z, rho):
        if not self.aspheric:
            return super().normal(zv, x, y, z, rho)
        g = self._slope(rho)
        return -2.0 * x * g, -2.0 * y * g, np.full_like(x, -1.0)

    def kernel_params(self):
        """(c, c (1 + k), the highest h, A_2, A_4, ..., A_20): the terms by h = power / 2."""
        if not self.aspheric:
            return super().kernel_params()
        c = self.curvature
        coef = [0.0] * len(ASPHERIC_POWERS)
        for p, a in self.aspheric:
            coef[p // 2 - 1] = float(a)
        return KERNEL_ASPHERE, (c, c * (1.0 + self.conic), float(max(p for p, _ in self.aspheric)
                                                                // 2), *coef)

    def sag_rho(self, rho, *, clamp=False):
        out = super().sag_rho(rho, clamp=clamp)
        with np.errstate(invalid="ignore", over="ignore"):
            for p, a in self.aspheric:
                out = out + a * rho ** (p // 2)
        return out

    @property
    def paraxial_curvature(self) -> float:
        return self.curvature + 2.0 * dict(self.aspheric).get(2, 0.0)

    # ---- lens file -------------------------------------------------------------------------
    @classmethod
    def _read_terms(cls, table, fields):
        value = table.get("aspheric", {})
        if not isinstance(value, dict):
            raise fields.error(f"expected a table like {{ a4 = 1e-5, a6 = -3e-8 }}, got "
                               f"{describe(value)}", "aspheric")
        scale = fields.scale
        terms = []
        for key, coeff in value.items():
            if key not in _ASPHERIC_KEYS:
                raise fields.error(f"unknown aspheric term '{key}': expected even terms "
                                   f"{', '.join(_ASPHERIC_KEYS)} (coefficient of r^n)",
                                   "aspheric")
            a = fields.number(coeff, "aspheric")
            p = int(key[1:])
            if a != 0.0:
                # a_n r^n has units mm^(1-n): scaling every length by s gives a_n s^(1-n).
                try:
                    a_scaled = a * scale ** (1 - p)
                except OverflowError:
                    a_scaled = math.inf
                if not math.isfinite(a_scaled) or a_scaled == 0.0:
                    raise fields.error(f"coefficient {key} = {a:g} is out of range after "
                                       f"scale = {scale:g}", "aspheric")
                terms.append((p, a_scaled))
        return tuple(sorted(terms))

    @classmethod
    def _build(cls, radius_mm, conic, terms):
        return rotational(radius_mm, conic, terms)

    def _check_terms(self, fields):
        for p, a in self.aspheric:
            if p not in ASPHERIC_POWERS or not math.isfinite(a):
                raise fields.error(f"aspheric term a{p} = {a:g}: expected even powers 2..20 "
                                   "with finite coefficients", "aspheric")

    def check(self, semi_diameter_mm, fields):
        super().check(semi_diameter_mm, fields)
        if self.aspheric:
            r = np.linspace(0.0, semi_diameter_mm, CHECK_SAMPLES)
            if not np.all(np.isfinite(self.sag(0.0, r, clamp=True))):
                raise fields.error("aspheric sag is not finite within the semi_diameter: "
                                   "coefficients too large", "aspheric")

    def toml_items(self):
        items = super().toml_items()
        if self.aspheric:
            terms = ", ".join(f"a{int(p)} = {toml_float(a)}" for p, a in self.aspheric)
            items.append(("aspheric", f"{{ {terms} }}"))
        return items

    # ---- OSL -------------------------------------------------------------------------------
    def osl_hit(self, index, zv, sd2):
        if not self.aspheric:
            return super().osl_hit(index, zv, sd2)
        g = f"g{index}"
        return (self._osl_function(index, zv) + [""],
                [f"float {g} = 0.0;", f"if (!nl_asphere_{index}(p, d, {sd2}, {g})) return;"],
                f"vector(-2.0 * p[0] * {g}, -2.0 * p[1] * {g}, -1.0)")

    def osl_fused(self, zv, sd2, eta):
        return None if self.aspheric else super().osl_fused(zv, sd2, eta)

    def _osl_function(self, i: int, zv: float) -> list[str]:
        """A specialised `nl_asphere_i(p, d, g)`: Newton on the sag, g = dsag/drho at the hit."""
        flt = osl_flt
        c = self.curvature
        ck = c * (1.0 + self.conic)
        coef = {p // 2: a for p, a in self.aspheric}
        top = max(coef) if coef else 0
        # Horner in rho for sum_h A_h rho^h and its derivative sum_h h A_h rho^(h-1).
        poly = "0.0"
        dpoly = "0.0"
        for h in range(top, 0, -1):
            a = coef.get(h, 0.0)
            poly = f"({poly} + {flt(a)}) * rho" if h < top else f"{flt(a)} * rho"
            dpoly = f"({dpoly}) * rho + {flt(h * a)}" if h < top else flt(h * a)
        terms = ", ".join(f"A{2 * h} {coef[h]:.6g}" for h in sorted(coef))
        sag_and_slope = [
            f"    float arg = 1.0 - {flt(ck * c)} * rho;",
            "    if (arg <= 0.0) return 0;",
            "    float root = sqrt(arg);",
            f"    float sag = {flt(c)} * rho / (1.0 + root) + {poly};",
            f"    g = {flt(0.5 * c)} / root + {dpoly};",
        ]
        return [
            f"// Surface {i + 1}: even asphere (c {c:.6g}, k {self.conic:g}, {terms}).",
            f"int nl_asphere_{i}(output point p, vector d, float sd2, output float g)",
            "{",
            "    float t = 0.0;",
            "    // Start from the base conic's root; without one, from the vertex plane.",
            f"    if (!nl_conic_root(p, d, {flt(zv)}, {flt(c)}, {flt(ck)}, t))",
            f"        t = d[2] == 0.0 ? 0.0 : ({flt(zv)} - p[2]) / d[2];",
            f"    float s0 = {flt(zv)} - p[2];",
            "    float ds = -d[2];",
            "    float f = 1.0;",
            f"    for (int it = 0; it < {ASPHERE_MAX_ITERATIONS}; ++it) {{",
            "        float x = p[0] + t * d[0];",
            "        float y = p[1] + t * d[1];",
            "        float rho = x * x + y * y;",
        ] + ["    " + ln for ln in sag_and_slope] + [
            "        f = s0 + t * ds - sag;",
            "        float fp = ds - 2.0 * g * (x * d[0] + y * d[1]);",
            "        if (fp == 0.0) return 0;",
            "        float step = f / fp;",
            "        t -= step;",
            f"        if (abs(step) < {flt(ASPHERE_STEP_TOLERANCE_MM)}) break;",
            "    }",
            f"    if (!(t >= {flt(-OSL_BACKWARD_TOLERANCE_MM)})) return 0;",
            "    p += t * d;",
            "    float rho = p[0] * p[0] + p[1] * p[1];",
        ] + sag_and_slope + [
            f"    if (abs(s0 + t * ds - sag) > {flt(ASPHERE_RESIDUAL_MM)}) return 0;",
            "    return rho <= sd2;",
            "}",
        ]
