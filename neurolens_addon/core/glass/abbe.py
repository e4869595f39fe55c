"""Glasses known only by (n_d, V_d) (`AbbeGlass`), as patents give them.

A one-resonance dispersion law (L in micrometres)
    n(L) = A + B / (L^2 - L0^2)
whose three parameters satisfy, exactly, the three conditions
    n(587.5618 nm) = n_d                                   (d line, helium)
    n_F - n_C      = (n_d - 1) / V_d                       (F 486.1327 nm, C 656.2725 nm)
    n_g - n_F      = P_gF (n_F - n_C),  P_gF = 0.6438 - 0.001682 V_d   (g 435.8343 nm)
i.e. n_d and V_d are reproduced exactly and the curvature follows Schott's "normal line" of
partial dispersion. With x = L^2 and f(x) = 1 / (x - x0) the last two conditions fix x0 = L0^2
in closed form (their ratio P_gF is a ratio of linear functions of x0):
    (f(x_g) - f(x_F)) / (f(x_F) - f(x_C)) = (x_F - x_g)(x_C - x0) / ((x_C - x_F)(x_g - x0)),
then B and A follow. For glass-like V_d, L0^2 < 0.04 um^2 (a resonance deep in the
ultraviolet; negative, i.e. no real pole, for fluor crowns), so n decreases monotonically and
convexly through the visible like a real glass; glasses off the normal line (dense flints,
fluor crowns, KzFS) differ from it by their partial-dispersion offset (accuracy against the
catalog: docs/measurements.md). If the pole would fall at or above 300 nm (only for V_d far
outside glass values) the 3-term Cauchy law n = A + B/L^2 + C/L^4 through the same three
conditions is used. With vd=None the material is non-dispersive: n = n_d at every wavelength.
Far outside the visible the law is held at n >= 1 (its asymptote A may lie below 1).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import GlassError
from ..prescription import WAVELENGTH_D_NM
from .arrays import as_wavelengths, nan_bad, output, scratch, shaped
from .medium import WAVELENGTH_C_NM, WAVELENGTH_F_NM, WAVELENGTH_G_NM, Medium

#: Schott's normal line of the partial dispersion P_gF = (n_g - n_F) / (n_F - n_C).
NORMAL_LINE_PGF = (0.6438, -0.001682)
#: The physical bounds of the model's inputs that lens files are held to (lensfile.checks):
#: n_d from vacuum's 1 to 3, beyond every material transparent across the visible (rutile
#: 2.6-2.9, diamond 2.42; the catalogue's glasses 1.43-2.10); V_d from 5, below the most
#: dispersive of them (rutile ~10, dense flints 17-21), to 150, beyond the least (the
#: fluorides: CaF2 95, MgF2 106). Outside them the law is no longer a glass's: at V_d = 1e-10 it
#: gives n ~ 1e10 at 380 nm and 4e9 at the F line (n_d exact, n = 1 beyond it), and above
#: V_d ~ 300 the Cauchy fallback makes n rise with wavelength.
ND_LIMITS = (1.0, 3.0)
VD_LIMITS = (5.0, 150.0)


class AbbeGlass(Medium):
    """A glass known only by (n_d, V_d): see the module docstring for the model."""

    def __init__(self, nd: float, vd: float | None, name: str | None = None, *,
                 manufacturer: str = "(n_d, V_d) model", source: str = "",
                 wavelength_range_nm: tuple[float, float] = (380.0, 780.0)):
        nd = float(nd)
        if not math.isfinite(nd) or nd < 1.0:
            raise GlassError(f"glass '{name or nd}': n_d must be a finite number >= 1, got {nd}")
        if vd is not None:
            vd = float(vd)
            if not math.isfinite(vd) or vd <= 0.0:
                raise GlassError(f"glass '{name or nd}': V_d must be a finite number > 0, "
                                 f"got {vd}")
            if nd == 1.0:
                raise GlassError(f"glass '{name or nd}': n_d = 1 cannot have a finite V_d")
        self.nd = nd
        self.vd = vd
        self.name = name if name is not None else (
            f"nd={nd:g}" + (f",vd={vd:g}" if vd is not None else ""))
        self.manufacturer = manufacturer
        self.source = source or ("(n_d, V_d) model: n = A + B / (L^2 - L0^2) through n_d, V_d "
                                 "and Schott's normal line P_gF = 0.6438 - 0.001682 V_d")
        lo, hi = wavelength_range_nm
        self.wavelength_range_nm = (float(lo), float(hi))
        #: "constant" (vd None), "oscillator" (the normal case) or "cauchy" (fallback)
        self.law = "constant"
        self.coefficients = (nd, 0.0, 0.0)
        if vd is not None:
            self.law, self.coefficients = _abbe_law(nd, vd)

    @property
    def partial_dispersion_gF(self) -> float | None:
        if self.vd is None:
            return None
        return NORMAL_LINE_PGF[0] + NORMAL_LINE_PGF[1] * self.vd

    def index(self, wavelength_nm, out: np.ndarray | None = None) -> np.ndarray:
        w = as_wavelengths(wavelength_nm)
        n = output(out, w)
        a, b, c = self.coefficients
        if self.law == "constant":
            n.fill(a)
            return shaped(nan_bad(n, w), wavelength_nm)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            np.multiply(w, w, out=n)
            n *= 1e-6                         # L^2 in um^2
            if self.law == "oscillator":      # n = a + b / (L^2 - c)
                n -= c
                np.divide(b, n, out=n)
                n += a
            else:                             # n = a + b / L^2 + c / L^4
                (x,) = scratch(w.shape, 1)
                np.reciprocal(n, out=x)
                np.multiply(x, c, out=n)
                n += b
                n *= x
                n += a
            # far outside the visible the law's asymptote A can lie below 1 (a dense flint in
            # the infrared): no glass has an index below vacuum's, so the law stops at 1
            np.maximum(n, 1.0, out=n)
        return shaped(nan_bad(n, w), wavelength_nm)


def _abbe_law(nd: float, vd: float) -> tuple[str, tuple[float, float, float]]:
    """Coefficients of the (n_d, V_d) model (see the module docstring).

    With x = L^2 (um^2) and f(x) = 1 / (x - x0), the conditions on n_F - n_C and n_g - n_F fix
    x0 in closed form (their ratio P_gF is a ratio of linear functions of x0), then B and A
    follow. A pole x0 at or above (300 nm)^2 would bend the curve inside the visible: there
    (only for V_d far outside glass values) the 3-term Cauchy law through the same three
    conditions is used instead.
    """
    dFC = (nd - 1.0) / vd
    pgf = NORMAL_LINE_PGF[0] + NORMAL_LINE_PGF[1] * vd
    xd, xf, xc, xg = ((v * 1e-3) ** 2 for v in (WAVELENGTH_D_NM, WAVELENGTH_F_NM,
                                                WAVELENGTH_C_NM, WAVELENGTH_G_NM))
    # (f(g) - f(F)) / (f(F) - f(C)) = (xF - xg)(xC - x0) / ((xC - xF)(xg - x0)) = P_gF
    m, k = xf - xg, xc - xf
    den = m - pgf * k
    if den != 0.0:
        x0 = (m * xc - pgf * k * xg) / den
        if math.isfinite(x0) and x0 < 0.09:
            B = dFC / (1.0 / (xf - x0) - 1.0 / (xc - x0))
            A = nd - B / (xd - x0)
            return "oscillator", (A, B, x0)
    rows = np.array([[1.0, 1.0 / x, 1.0 / (x * x)] for x in (xd, xf, xc, xg)])
    M = np.array([rows[0], rows[1] - rows[2], rows[3] - rows[1]])
    rhs = np.array([nd, dFC, pgf * dFC])
    return "cauchy", tuple(float(v) for v in np.linalg.solve(M, rhs))
