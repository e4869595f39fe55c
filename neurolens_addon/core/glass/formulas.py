"""Catalog glasses (`Glass`): the manufacturer's dispersion formula and coefficients.

L is the wavelength in micrometres. Sellmeier's law (C_i in um^2; the Schott, Ohara and CDGM
catalogues' convention):
    n(L)^2 = 1 + sum_{i=1..3} B_i L^2 / (L^2 - C_i)  =  1 + sum B_i + sum B_i C_i / (L^2 - C_i)
(the second form, one pass fewer per term, is the one evaluated). Where a maker publishes the
Schott power series instead (HOYA, a few CDGM glasses) that is used as is:
    n(L)^2 = A0 + A1 L^2 + A2 L^-2 + A3 L^-4 + A4 L^-6 + A5 L^-8   (Horner in 1 / L^2).
Finite positive wavelengths outside a glass's `wavelength_range_nm` are extrapolated with the
same formula (and may give NaN inside an absorption pole of the Sellmeier law, far outside the
visible).
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from ..errors import GlassError
from .arrays import as_wavelengths, nan_bad, output, scratch, shaped
from .medium import Medium


class Glass(Medium):
    """A catalog glass: the manufacturer's dispersion formula and coefficients.

    `formula` is "sellmeier" (default; `B`, `C` with C in um^2):
        n^2 = 1 + sum_i B_i L^2 / (L^2 - C_i)
    or "schott" (the power series some catalogues, e.g. HOYA's, publish instead; `A` = A0..A5):
        n^2 = A0 + A1 L^2 + A2 L^-2 + A3 L^-4 + A4 L^-6 + A5 L^-8
    with L the wavelength in micrometres.
    """

    def __init__(self, name: str, manufacturer: str, B: Iterable[float] | None = None,
                 C: Iterable[float] | None = None, *, A: Iterable[float] | None = None,
                 formula: str = "sellmeier", nd: float | None = None,
                 vd: float | None = None, source: str = "",
                 wavelength_range_nm: tuple[float, float] = (380.0, 780.0)):
        self.name = str(name)
        self.manufacturer = str(manufacturer)
        self.formula = str(formula).lower()
        if self.formula == "sellmeier":
            if B is None or C is None:
                raise GlassError(f"glass '{name}': the Sellmeier formula needs B and C")
            self.B = tuple(float(b) for b in B)
            self.C = tuple(float(c) for c in C)
            if len(self.B) != len(self.C) or not self.B:
                raise GlassError(f"glass '{name}': Sellmeier needs as many B as C coefficients "
                                 f"(got {len(self.B)} B and {len(self.C)} C)")
            self.A = ()
            self._n2_offset = 1.0 + sum(self.B)
            self._poles = tuple((c, b * c) for b, c in zip(self.B, self.C))
        elif self.formula == "schott":
            if A is None:
                raise GlassError(f"glass '{name}': the Schott formula needs A0..A5")
            self.A = tuple(float(a) for a in A)
            if len(self.A) != 6:
                raise GlassError(f"glass '{name}': the Schott formula needs 6 coefficients "
                                 f"A0..A5, got {len(self.A)}")
            self.B = self.C = ()
        else:
            raise GlassError(f"glass '{name}': unknown dispersion formula '{formula}' "
                             f"(expected 'sellmeier' or 'schott')")
        self.source = str(source)
        self.note = ""
        lo, hi = wavelength_range_nm
        self.wavelength_range_nm = (float(lo), float(hi))
        # n_d, V_d as listed by the catalogue (the formula's own values when not given)
        cnd, cvd = self.abbe_from_index()
        self.nd = float(nd) if nd is not None else cnd
        self.vd = float(vd) if vd is not None else cvd

    def index(self, wavelength_nm, out: np.ndarray | None = None) -> np.ndarray:
        w = as_wavelengths(wavelength_nm)
        n2 = output(out, w)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            if self.formula == "sellmeier":
                L2, t = scratch(w.shape, 2)
                np.multiply(w, w, out=L2)
                L2 *= 1e-6                       # nm^2 -> um^2
                # B L^2 / (L^2 - C) = B + B C / (L^2 - C): one pass fewer per term
                n2.fill(self._n2_offset)
                for c, bc in self._poles:
                    np.subtract(L2, c, out=t)
                    np.divide(bc, t, out=t)
                    n2 += t
            else:
                a0, a1, a2, a3, a4, a5 = self.A
                L2, inv = scratch(w.shape, 2)
                np.multiply(w, w, out=L2)
                L2 *= 1e-6
                np.reciprocal(L2, out=inv)
                np.multiply(inv, a5, out=n2)     # Horner in 1/L^2
                for a in (a4, a3, a2):
                    n2 += a
                    n2 *= inv
                L2 *= a1
                n2 += L2
                n2 += a0
            np.sqrt(n2, out=n2)
        return shaped(nan_bad(n2, w), wavelength_nm)
