"""Surfaces without rotational symmetry (anamorphic optics): biconic, cylinder, toroidal.

Each is described in its own frame turned by `rotation` (degrees, about the optical axis):
    u = x cos r + y sin r,   v = -x sin r + y cos r,
with its sag s = S(u, v) (mm along the propagation direction, as every kind's) and the
gradient (S_u, S_v), turned back to lens space by
    s_x = S_u cos r - S_v sin r,   s_y = S_u sin r + S_v cos r.
Kinds (c = 1 / R; R = inf is flat):
- "biconic" (Zemax's BICONIC): S = (c_u u^2 + c_v v^2) / (1 + sqrt(1 - (1 + k_u) c_u^2 u^2
  - (1 + k_v) c_v^2 v^2)), two curvatures and two conic constants;
- "cylinder": a biconic flat along its axis, `axis = "x"` (curved in v, power in y) or "y"
  (curved in u, power in x), radius R and conic k in the curved direction;
- "toroidal" (Zemax's TOROIDAL): the conic curve f(v) = c_v v^2 / (1 + sqrt(1 - (1 + k) c_v^2
  v^2)) swept about an axis parallel to u at distance R_u from the vertex:
  S = R_u - sign(R_u) sqrt((R_u - f(v))^2 - u^2) (R_u = inf: the cylinder S = f(v)).
Vertex curvatures: c_u and c_v (a toroid's c_u = 1 / R_u), so near the axis S ~ (c_u u^2 +
c_v v^2) / 2 and the vertex curvature tensor (the paraxial trace's, core.paraxial) is
    c_y = d^2 s / dy^2 = c_u sin^2 r + c_v cos^2 r,   c_x = d^2 s / dx^2 = c_u cos^2 r +
    c_v sin^2 r,   c_xy = d^2 s / dx dy = (c_u - c_v) cos r sin r:
a surface turned by other than a multiple of 90 degrees couples the x and y meridians
(core.paraxial: `meridian` for each meridian, `first_order` for the coupled system).
Intersection: Newton on f(t) = s_0 + t d_s - S(u(t), v(t)), f' = d_s - (s_x d_x + s_y d_y),
from the vertex plane (s = 0), at most NEWTON_MAX_ITERATIONS steps; a ray whose final
|f| > NEWTON_RESIDUAL_MM, or that leaves the surface's domain (the square roots' arguments
negative), has not converged. Normal (lens space): (-s_x, -s_y, -1).
Compiled trace (surfaces/kernels.py: anamorphic_hit over biconic_local / toroidal_local): the
same Newton iteration per ray, from the row kernel_params gives.
Lens file keys (lengths scale with `scale`; `rotation` in degrees): biconic radius_x, radius_y,
conic_x, conic_y, rotation; cylinder radius, axis, conic, rotation; toroidal radius_y (the
curve), radius_x (the sweep), conic_y, rotation. Checks: finite sag over the semi-diameter's
disc. OSL (the Cycles exact camera): a specialised Newton function per surface, float32.
Not in the learned lens yet (the trainer says so by name).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..lensfields import describe, toml_float
from .base import (BACKWARD_TOLERANCE_MM, CHECK_SAMPLES, KERNEL_BICONIC, KERNEL_TOROIDAL,
                   SurfaceShape)
from .registry import register
from .standard import _read_radius

NEWTON_MAX_ITERATIONS = 32
NEWTON_STEP_MM = 1e-12
NEWTON_RESIDUAL_MM = 1e-9


def _curv(r: float) -> float:
    return 0.0 if math.isinf(r) else 1.0 / r


def _conic_sag(c, k, w2, clamp):
    """(sag, root sqrt(1 - (1 + k) c^2 w2)) of a conic profile at squared coordinate w2."""
    with np.errstate(invalid="ignore", divide="ignore"):
        arg = 1.0 - (1.0 + k) * c * c * w2
        q = np.sqrt(np.maximum(arg, 0.0) if clamp else arg)
        return c * w2 / (1.0 + q), q


class AnamorphicSurface(SurfaceShape):
    """Common frame, Newton intersection, normal and checks (module docstring); subclasses
    give the local sag and gradient and their vertex curvatures."""

    rotationally_symmetric = False
    rotation_deg: float = 0.0

    # ---- the local frame ---------------------------------------------------------------------
    def _cs(self):
        r = math.radians(self.rotation_deg)
        return math.cos(r), math.sin(r)

    def _local(self, x, y):
        c, s = self._cs()
        return x * c + y * s, -x * s + y * c

    def _local_sag(self, u, v, clamp=False):
        """(S, S_u, S_v) at local (u, v): NaN where the surface has no point."""
        raise NotImplementedError

    def _vertex_curvatures(self) -> tuple[float, float]:
        raise NotImplementedError

    def _meridians(self) -> list[tuple[str, str | None, float, float]]:
        """(radius key, conic key or None, curvature, conic) of each curved profile, for
        shader_constants."""
        raise NotImplementedError

    def shader_constants(self, semi_diameter_mm):
        out = []
        for radius_key, conic_key, c, k in self._meridians():
            out.append((radius_key, c))
            if conic_key is not None:
                out += [(conic_key, c * (1.0 + k)), (conic_key, c * c * (1.0 + k))]
        return out

    def sag_and_gradient(self, x, y, clamp=False):
        """(s, s_x, s_y) in lens space."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        u, v = self._local(x, y)
        s, su, sv = self._local_sag(u, v, clamp)
        c, sn = self._cs()
        return s, su * c - sv * sn, su * sn + sv * c

    def sag(self, x, y, *, clamp=False):
        return self.sag_and_gradient(x, y, clamp)[0]

    @property
    def paraxial_curvature(self) -> float:
        cu, cv = self._vertex_curvatures()
        c, s = self._cs()
        return cu * s * s + cv * c * c

    @property
    def paraxial_curvature_x(self) -> float:
        cu, cv = self._vertex_curvatures()
        c, s = self._cs()
        return cu * c * c + cv * s * s

    @property
    def paraxial_curvature_xy(self) -> float:
        cu, cv = self._vertex_curvatures()
        c, s = self._cs()
        return (cu - cv) * c * s

    # ---- geometry --------------------------------------------------------------------------
    def hit(self, zv, ox, oy, oz, dx, dy, dz):
        s0 = zv - oz
        ds = -dz
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            t = np.where(ds != 0.0, -s0 / np.where(ds != 0.0, ds, 1.0), 0.0)
            watch = np.ones(t.shape, dtype=bool)
            for _ in range(NEWTON_MAX_ITERATIONS):
                s, sx, sy = self.sag_and_gradient(ox + t * dx, oy + t * dy)
                f = s0 + t * ds - s
                fp = ds - (sx * dx + sy * dy)
                step = f / fp
                step = np.where(np.isfinite(step), step, 0.0)
                t = t - np.where(watch, step, 0.0)
                watch &= np.abs(step) > NEWTON_STEP_MM
                if not watch.any():
                    break
            s = self.sag(ox + t * dx, oy + t * dy)
            resid = np.abs(s0 + t * ds - s)
        unconverged = ~(resid <= NEWTON_RESIDUAL_MM)
        miss = ~np.isfinite(t) | (t < -BACKWARD_TOLERANCE_MM)
        return t, miss, unconverged

    def normal(self, zv, x, y, z, rho):
        _s, sx, sy = self.sag_and_gradient(x, y)
        return -sx, -sy, np.full_like(np.asarray(x, dtype=np.float64), -1.0)

    def check(self, semi_diameter_mm, fields):
        r = np.linspace(0.0, semi_diameter_mm, CHECK_SAMPLES)[:, None]
        phi = np.linspace(0.0, 2.0 * math.pi, 25)[None, :]
        with np.errstate(invalid="ignore", over="ignore"):
            s = self.sag(r * np.cos(phi), r * np.sin(phi))
        if not np.all(np.isfinite(s)):
            raise fields.error(f"the {self.kind} surface has no points over all of its "
                               f"semi_diameter {semi_diameter_mm:g} mm (radii too small for "
                               "it)", "semi_diameter", scaled=True)

    # ---- lens file helpers -------------------------------------------------------------------
    @staticmethod
    def _radius(table, key, fields) -> float:
        r = _read_radius(table[key], fields) if key in table else math.inf
        if math.isfinite(r) and math.isinf(r * fields.scale):
            raise fields.error(f"{key} {r:g} is out of range after scale", key)
        return r * fields.scale

    @staticmethod
    def _rotation(table, fields) -> float:
        r = fields.number(table.get("rotation", 0.0), "rotation")
        return math.fmod(r, 360.0) + 0.0

    @staticmethod
    def _radius_text(r: float) -> str:
        return '"flat"' if math.isinf(r) else toml_float(float(r))

    def _rotation_items(self):
        return [("rotation", toml_float(self.rotation_deg))] if self.rotation_deg else []

    # ---- OSL -------------------------------------------------------------------------------
    def _osl_local(self) -> list[str]:
        """OSL lines setting float S, Su, Sv from float u, v (returning 0 where the surface
        has no point)."""
        raise NotImplementedError

    def osl_hit(self, index, zv, sd2):
        """A specialised `nl_ana_i(p, d, sd2, gx, gy)`: the Newton iteration above in float32
        (ASPHERE's tolerances), the lens-space gradient at the hit for the normal."""
        from .asphere import ASPHERE_RESIDUAL_MM, ASPHERE_STEP_TOLERANCE_MM
        from .base import OSL_BACKWARD_TOLERANCE_MM
        from ..oslfmt import flt
        c, s = self._cs()
        gx, gy = f"gx{index}", f"gy{index}"
        local = ["    " + ln for ln in self._osl_local()]
        grad = [f"    gx = Su * {flt(c)} - Sv * {flt(s)};",
                f"    gy = Su * {flt(s)} + Sv * {flt(c)};"]
        turn = [f"    float u = x * {flt(c)} + y * {flt(s)};",
                f"    float v = -x * {flt(s)} + y * {flt(c)};"]
        fn = [
            f"// Surface {index + 1}: {self.kind} {self!r}",
            f"int nl_ana_{index}(output point p, vector d, float sd2, output float gx, "
            "output float gy)",
            "{",
            f"    float s0 = {flt(zv)} - p[2];",
            "    float ds = -d[2];",
            "    if (ds == 0.0) return 0;",
            "    float t = -s0 / ds;",
            "    float S = 0.0, Su = 0.0, Sv = 0.0;",
            f"    for (int it = 0; it < {NEWTON_MAX_ITERATIONS}; ++it) {{",
            "        float x = p[0] + t * d[0];",
            "        float y = p[1] + t * d[1];",
        ] + ["    " + ln for ln in turn + local + grad] + [
            "        float fp = ds - (gx * d[0] + gy * d[1]);",
            "        if (fp == 0.0) return 0;",
            "        float step = (s0 + t * ds - S) / fp;",
            "        t -= step;",
            f"        if (abs(step) < {flt(ASPHERE_STEP_TOLERANCE_MM)}) break;",
            "    }",
            f"    if (!(t >= {flt(-OSL_BACKWARD_TOLERANCE_MM)})) return 0;",
            "    p += t * d;",
            "    float x = p[0];",
            "    float y = p[1];",
        ] + turn + local + grad + [
            f"    if (abs(s0 + t * ds - S) > {flt(ASPHERE_RESIDUAL_MM)}) return 0;",
            "    return x * x + y * y <= sd2;",
            "}",
        ]
        body = [f"float {gx} = 0.0;", f"float {gy} = 0.0;",
                f"if (!nl_ana_{index}(p, d, {sd2}, {gx}, {gy})) return;"]
        return fn + [""], body, f"vector(-{gx}, -{gy}, -1.0)"


@register
@dataclass(frozen=True)
class Biconic(AnamorphicSurface):
    """Curvatures 1 / radius_u_mm, 1 / radius_v_mm and conics in the turned frame."""

    radius_u_mm: float = math.inf
    radius_v_mm: float = math.inf
    conic_u: float = 0.0
    conic_v: float = 0.0
    rotation_deg: float = 0.0

    kind = "biconic"
    required_keys = ("radius_x", "radius_y")
    optional_keys = ("conic_x", "conic_y", "rotation")
    label = "biconic"

    def _vertex_curvatures(self):
        return _curv(self.radius_u_mm), _curv(self.radius_v_mm)

    def _meridians(self):
        cu, cv = self._vertex_curvatures()
        return [("radius_x", "conic_x", cu, self.conic_u),
                ("radius_y", "conic_y", cv, self.conic_v)]

    def _local_sag(self, u, v, clamp=False):
        cu, cv = self._vertex_curvatures()
        ku, kv = self.conic_u, self.conic_v
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            n = cu * u * u + cv * v * v
            arg = 1.0 - (1.0 + ku) * cu * cu * u * u - (1.0 + kv) * cv * cv * v * v
            q = np.sqrt(np.maximum(arg, 0.0) if clamp else arg)
            s = n / (1.0 + q)
            # d/du of n / (1 + q), with dq/du = -(1 + k_u) c_u^2 u / q
            qu = -(1.0 + ku) * cu * cu * u / q
            qv = -(1.0 + kv) * cv * cv * v / q
            den = (1.0 + q) ** 2
            su = np.where(u == 0.0, 0.0, (2.0 * cu * u * (1.0 + q) - n * qu) / den)
            sv = np.where(v == 0.0, 0.0, (2.0 * cv * v * (1.0 + q) - n * qv) / den)
        return s, su, sv

    def kernel_params(self):
        """(c_u, c_v, 1 + k_u, 1 + k_v, cos r, sin r)."""
        cu, cv = self._vertex_curvatures()
        return KERNEL_BICONIC, (cu, cv, 1.0 + self.conic_u, 1.0 + self.conic_v, *self._cs())

    def _osl_local(self):
        from ..oslfmt import flt
        cu, cv = self._vertex_curvatures()
        au = (1.0 + self.conic_u) * cu * cu
        av = (1.0 + self.conic_v) * cv * cv
        return [
            f"float nn = {flt(cu)} * u * u + {flt(cv)} * v * v;",
            f"float arg = 1.0 - {flt(au)} * u * u - {flt(av)} * v * v;",
            "if (arg <= 0.0) return 0;",
            "float q = sqrt(arg);",
            "S = nn / (1.0 + q);",
            "float den = (1.0 + q) * (1.0 + q);",
            f"Su = (2.0 * {flt(cu)} * u * (1.0 + q) + nn * {flt(au)} * u / q) / den;",
            f"Sv = (2.0 * {flt(cv)} * v * (1.0 + q) + nn * {flt(av)} * v / q) / den;",
        ]

    @classmethod
    def from_table(cls, table, fields):
        return cls(cls._radius(table, "radius_x", fields), cls._radius(table, "radius_y", fields),
                   fields.number(table.get("conic_x", 0.0), "conic_x") + 0.0,
                   fields.number(table.get("conic_y", 0.0), "conic_y") + 0.0,
                   cls._rotation(table, fields))

    def check(self, semi_diameter_mm, fields):
        for key, k in (("conic_x", self.conic_u), ("conic_y", self.conic_v)):
            if not math.isfinite(k):
                raise fields.error(f"{key} must be finite, got {k:g}", key)
        if math.isinf(self.radius_u_mm) and math.isinf(self.radius_v_mm):
            raise fields.error("a biconic flat in both directions is a plane: write a "
                               "standard surface with radius = \"flat\"", "radius_x")
        super().check(semi_diameter_mm, fields)

    def toml_items(self):
        items = [("radius_x", self._radius_text(self.radius_u_mm)),
                 ("radius_y", self._radius_text(self.radius_v_mm))]
        if self.conic_u:
            items.append(("conic_x", toml_float(self.conic_u)))
        if self.conic_v:
            items.append(("conic_y", toml_float(self.conic_v)))
        return items + self._rotation_items()


@register
@dataclass(frozen=True)
class Cylinder(Biconic):
    """A biconic flat along its axis: `axis` "x" (power in y) or "y" (power in x); the
    biconic's fields, one radius infinite."""

    kind = "cylinder"
    required_keys = ("radius", "axis")
    optional_keys = ("conic", "rotation")
    label = "cylinder"

    @property
    def axis(self) -> str:
        return "x" if math.isinf(self.radius_u_mm) else "y"

    @property
    def radius(self) -> float:
        return self.radius_v_mm if self.axis == "x" else self.radius_u_mm

    def _meridians(self):
        k = self.conic_v if self.axis == "x" else self.conic_u
        return [("radius", "conic", _curv(self.radius), k)]

    @classmethod
    def make(cls, radius_mm: float, axis: str, conic: float = 0.0, rotation_deg: float = 0.0):
        """The cylinder of radius R with its axis along x (curved in y) or y."""
        if axis == "x":
            return cls(math.inf, float(radius_mm), 0.0, float(conic), float(rotation_deg))
        return cls(float(radius_mm), math.inf, float(conic), 0.0, float(rotation_deg))

    @classmethod
    def from_table(cls, table, fields):
        axis = table["axis"]
        if axis not in ("x", "y"):
            raise fields.error(f"axis must be \"x\" (the cylinder runs along x: power in y) "
                               f"or \"y\", got {describe(axis)}", "axis")
        r = cls._radius(table, "radius", fields)
        if math.isinf(r):
            raise fields.error("a flat cylinder is a plane: give its radius", "radius")
        return cls.make(r, axis, fields.number(table.get("conic", 0.0), "conic") + 0.0,
                        cls._rotation(table, fields))

    def toml_items(self):
        k = self.conic_v if self.axis == "x" else self.conic_u
        items = [("radius", toml_float(float(self.radius))), ("axis", f'"{self.axis}"')]
        if k:
            items.append(("conic", toml_float(k)))
        return items + self._rotation_items()


@register
@dataclass(frozen=True)
class Toroidal(AnamorphicSurface):
    """The conic curve (radius_v_mm, conic_v) in v swept about an axis parallel to u at
    radius_u_mm from the vertex."""

    radius_v_mm: float = math.inf
    radius_u_mm: float = math.inf
    conic_v: float = 0.0
    rotation_deg: float = 0.0

    kind = "toroidal"
    required_keys = ("radius_y", "radius_x")
    optional_keys = ("conic_y", "rotation")
    label = "toroidal"

    def _vertex_curvatures(self):
        return _curv(self.radius_u_mm), _curv(self.radius_v_mm)

    def _meridians(self):
        # the sweep radius itself is written (S = R_u - sign sqrt(...)), not its curvature
        ru = 0.0 if math.isinf(self.radius_u_mm) else self.radius_u_mm
        return [("radius_y", "conic_y", _curv(self.radius_v_mm), self.conic_v),
                ("radius_x", None, ru, 0.0)]

    def _local_sag(self, u, v, clamp=False):
        cv = _curv(self.radius_v_mm)
        f, q = _conic_sag(cv, self.conic_v, v * v, clamp)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            fp = np.where(v == 0.0, 0.0, cv * v / q)
            ru = self.radius_u_mm
            if math.isinf(ru):
                return f + 0.0 * u, np.zeros_like(f + 0.0 * u), fp + 0.0 * u
            a = ru - f
            w = a * a - u * u
            root = np.sqrt(np.maximum(w, 0.0) if clamp else w)
            sign = 1.0 if ru > 0 else -1.0
            s = ru - sign * root
            su = np.where(u == 0.0, 0.0, sign * u / root)
            sv = sign * a * fp / root
        return s, su, sv

    def kernel_params(self):
        """(c_v, 1 + k_v, R_u (inf: the cylinder f(v)), sign(R_u), cos r, sin r)."""
        ru = self.radius_u_mm
        return KERNEL_TOROIDAL, (_curv(self.radius_v_mm), 1.0 + self.conic_v, ru,
                                 1.0 if ru > 0 else -1.0, *self._cs())

    def _osl_local(self):
        from ..oslfmt import flt
        cv = _curv(self.radius_v_mm)
        av = (1.0 + self.conic_v) * cv * cv
        lines = [
            f"float argv = 1.0 - {flt(av)} * v * v;",
            "if (argv <= 0.0) return 0;",
            "float qv = sqrt(argv);",
            f"float f = {flt(cv)} * v * v / (1.0 + qv);",
            f"float df = {flt(cv)} * v / qv;",
        ]
        ru = self.radius_u_mm
        if math.isinf(ru):
            return lines + ["S = f;", "Su = 0.0;", "Sv = df;"]
        sign = "1.0" if ru > 0 else "-1.0"
        return lines + [
            f"float a = {flt(ru)} - f;",
            "float w = a * a - u * u;",
            "if (w <= 0.0) return 0;",
            "float root = sqrt(w);",
            f"S = {flt(ru)} - {sign} * root;",
            f"Su = {sign} * u / root;",
            f"Sv = {sign} * a * df / root;",
        ]

    @classmethod
    def from_table(cls, table, fields):
        return cls(cls._radius(table, "radius_y", fields), cls._radius(table, "radius_x", fields),
                   fields.number(table.get("conic_y", 0.0), "conic_y") + 0.0,
                   cls._rotation(table, fields))

    def check(self, semi_diameter_mm, fields):
        if not math.isfinite(self.conic_v):
            raise fields.error(f"conic_y must be finite, got {self.conic_v:g}", "conic_y")
        if math.isinf(self.radius_u_mm) and math.isinf(self.radius_v_mm):
            raise fields.error("a toroid flat in both directions is a plane: write a standard "
                               "surface with radius = \"flat\"", "radius_y")
        super().check(semi_diameter_mm, fields)

    def toml_items(self):
        items = [("radius_y", self._radius_text(self.radius_v_mm)),
                 ("radius_x", self._radius_text(self.radius_u_mm))]
        if self.conic_v:
            items.append(("conic_y", toml_float(self.conic_v)))
        return items + self._rotation_items()
