"""Reflectance of lens surfaces: bare (Fresnel), single-layer and tabulated multi-layer coatings.

Each surface between media n_0 (the ray's side) and n_s reflects a share R of the light and
passes T = 1 - R (no absorption), per wavelength and angle of incidence; light is unpolarised,
R = (R_s + R_p) / 2.

Bare surface (Fresnel; Hecht, Optics, 5th ed., sec. 4.6): with cos t from Snell's law
(n_0 sin i = n_s sin t)
    r_s = (n_0 cos i - n_s cos t) / (n_0 cos i + n_s cos t),
    r_p = (n_s cos i - n_0 cos t) / (n_s cos i + n_0 cos t),   R_x = r_x^2;
past the critical angle R = 1 (total internal reflection). At normal incidence
R = ((n_0 - n_s) / (n_0 + n_s))^2: 4.0 % for n = 1.5 in air.

Single layer (Macleod, Thin-Film Optical Filters, 4th ed., ch. 2, the characteristic
matrix): a film of index n_1 and thickness d, phase thickness delta = 2 pi n_1 d cos t_1 /
lambda, tilted admittances eta = n cos t (s) and n / cos t (p) of each medium:
    [B, C] = [[cos delta, i sin delta / eta_1], [i eta_1 sin delta, cos delta]] [1, eta_s],
    r = (eta_0 B - C) / (eta_0 B + C),   R = |r|^2.
A quarter-wave layer at lambda_0 (n_1 d = lambda_0 / 4) at normal incidence gives
R = ((n_0 n_s - n_1^2) / (n_0 n_s + n_1^2))^2: MgF2 (n_1 = 1.38) on n_s = 1.52 reflects
1.26 % at lambda_0 (0 for n_1 = sqrt(n_0 n_s)). The film's index is taken constant over the
visible (MgF2 varies by < 1 %).

Multi-layer: a maker's reflectance curve R(lambda) at normal incidence, interpolated linearly
(ends held), the same at every angle (a broadband stack changes little within the angles a
lens's surfaces see; said where used).

The coating is the same whichever side the light arrives from (reciprocity of R for a lossless
stack).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: MgF2's index at the d line (Dodge 1984, ordinary ray: 1.3777) and the usual design
#: wavelength of a single-layer coating (the eye's peak sensitivity)
MGF2_INDEX = 1.3777
DESIGN_WAVELENGTH_NM = 550.0


def _cos_transmitted(n0, ns, cos_i):
    """cos t from Snell's law and the total-internal-reflection mask."""
    sin2_t = (n0 / ns) ** 2 * np.maximum(1.0 - cos_i * cos_i, 0.0)
    tir = sin2_t > 1.0
    return np.sqrt(np.maximum(1.0 - sin2_t, 0.0)), tir


def fresnel_reflectance(n0, ns, cos_i) -> np.ndarray:
    """Unpolarised reflectance of a bare interface from index n0 into ns at cos(incidence)."""
    n0, ns, cos_i = (np.asarray(v, dtype=np.float64) for v in (n0, ns, cos_i))
    cos_i = np.clip(np.abs(cos_i), 0.0, 1.0)
    cos_t, tir = _cos_transmitted(n0, ns, cos_i)
    with np.errstate(invalid="ignore", divide="ignore"):
        rs = (n0 * cos_i - ns * cos_t) / (n0 * cos_i + ns * cos_t)
        rp = (ns * cos_i - n0 * cos_t) / (ns * cos_i + n0 * cos_t)
    r = 0.5 * (rs * rs + rp * rp)
    return np.where(tir | ~np.isfinite(r), 1.0, np.clip(r, 0.0, 1.0))


def single_layer_reflectance(n0, ns, cos_i, wavelength_nm, film_index: float,
                             film_thickness_nm: float) -> np.ndarray:
    """Unpolarised reflectance of one film (index, physical thickness) on an interface."""
    n0, ns, cos_i, lam = (np.asarray(v, dtype=np.float64)
                          for v in (n0, ns, cos_i, wavelength_nm))
    cos_i = np.clip(np.abs(cos_i), 0.0, 1.0)
    n1 = float(film_index)
    cos_1, _ = _cos_transmitted(n0, n1, cos_i)
    cos_s, tir = _cos_transmitted(n0, ns, cos_i)
    delta = 2.0 * math.pi * n1 * film_thickness_nm * cos_1 / lam
    c, s = np.cos(delta), np.sin(delta)
    out = 0.0
    for pol in ("s", "p"):
        if pol == "s":
            e0, e1, es = n0 * cos_i, n1 * cos_1, ns * cos_s
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                e0, e1, es = n0 / cos_i, n1 / cos_1, ns / cos_s
        with np.errstate(divide="ignore", invalid="ignore"):
            b = c + 1j * s * es / e1
            cc = 1j * e1 * s + c * es
            r = (e0 * b - cc) / (e0 * b + cc)
        out = out + 0.5 * np.abs(r) ** 2
    return np.where(tir | ~np.isfinite(out), 1.0, np.clip(out, 0.0, 1.0))


@dataclass(frozen=True)
class Coating:
    """What covers a lens's air-glass surfaces: "bare", "single" (a film of film_index,
    quarter-wave at design_nm) or "table" (reflectance per wavelength)."""

    kind: str = "single"
    film_index: float = MGF2_INDEX
    design_nm: float = DESIGN_WAVELENGTH_NM
    table_nm: tuple = ()
    table_r: tuple = ()

    def __post_init__(self):
        if self.kind not in ("bare", "single", "table"):
            raise ValueError(f"coating kind must be bare, single or table, got {self.kind!r}")
        if self.kind == "single" and not (self.film_index > 1.0 and self.design_nm > 0.0):
            raise ValueError(f"single-layer coating needs an index > 1 and a design wavelength "
                             f"> 0, got {self.film_index!r} and {self.design_nm!r}")
        if self.kind == "table":
            nm, r = np.asarray(self.table_nm, float), np.asarray(self.table_r, float)
            if (nm.ndim != 1 or nm.size < 2 or nm.shape != r.shape or np.any(np.diff(nm) <= 0)
                    or not np.all(np.isfinite(r)) or np.any((r < 0) | (r > 1))):
                raise ValueError("a coating table needs two or more increasing wavelengths "
                                 "(nm) and reflectances in [0, 1] of the same count")

    @property
    def film_thickness_nm(self) -> float:
        """The quarter-wave thickness: n_1 d = lambda_0 / 4."""
        return self.design_nm / (4.0 * self.film_index)

    def reflectance(self, n0, ns, cos_i, wavelength_nm) -> np.ndarray:
        """R of a surface between n0 and ns, at cos(incidence) and wavelength (arrays
        broadcast); a surface between equal indices reflects nothing."""
        if self.kind == "bare":
            r = fresnel_reflectance(n0, ns, cos_i)
        elif self.kind == "single":
            r = single_layer_reflectance(n0, ns, cos_i, wavelength_nm, self.film_index,
                                         self.film_thickness_nm)
        else:
            lam = np.asarray(wavelength_nm, dtype=np.float64)
            r = np.interp(lam, np.asarray(self.table_nm, float), np.asarray(self.table_r, float))
            r = np.broadcast_to(r, np.broadcast_shapes(np.shape(n0), np.shape(ns),
                                                       np.shape(cos_i), lam.shape)).copy()
            # total internal reflection stays total whatever the stack
            _, tir = _cos_transmitted(np.asarray(n0, float), np.asarray(ns, float),
                                      np.clip(np.abs(np.asarray(cos_i, float)), 0.0, 1.0))
            r = np.where(tir, 1.0, r)
        same = np.asarray(n0, dtype=np.float64) == np.asarray(ns, dtype=np.float64)
        return np.where(same, 0.0, r)
