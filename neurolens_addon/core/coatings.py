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

Multi-layer: a stack of films by the product of their matrices (the films in order from the
air side; seen from the glass side, reversed), by default the classic quarter-half-quarter
broadband design; or a maker's reflectance curve R(lambda) at normal incidence, interpolated
linearly (ends held), the same at every angle (a broadband stack changes little within the
angles a lens's surfaces see).

R is the same whichever side the light arrives from (reciprocity of a lossless stack).
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


def stack_reflectance(n0, ns, cos_i, wavelength_nm, layers, kernels=None) -> np.ndarray:
    """Unpolarised reflectance of thin films `layers` ((index, physical thickness nm), from the
    n0 side) on an interface: the product of the layers' characteristic matrices (module
    docstring), the films' indices constant over wavelength. kernels: as core.trace's (the
    compiled twin: core.coatings_kernels)."""
    from . import jit
    if jit.mode(kernels) == "compiled":
        from .coatings_kernels import stack_reflectance as compiled
        return compiled(n0, ns, cos_i, wavelength_nm, layers)
    n0, ns, cos_i, lam = (np.asarray(v, dtype=np.float64)
                          for v in (n0, ns, cos_i, wavelength_nm))
    cos_i = np.clip(np.abs(cos_i), 0.0, 1.0)
    cos_s, tir = _cos_transmitted(n0, ns, cos_i)
    out = 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        for pol in ("s", "p"):
            adm = (lambda n, c: n * c) if pol == "s" else (lambda n, c: n / c)
            # [B, C] = M_1 M_2 ... M_k [1, eta_s], multiplied from the substrate outwards
            b = np.ones(np.broadcast_shapes(n0.shape, ns.shape, cos_i.shape, lam.shape),
                        dtype=np.complex128)
            c = adm(ns, cos_s) * b
            for n1, d_nm in reversed(tuple(layers)):
                cos_1, _ = _cos_transmitted(n0, float(n1), cos_i)
                e1 = adm(float(n1), cos_1)
                delta = 2.0 * math.pi * float(n1) * float(d_nm) * cos_1 / lam
                cd, sd = np.cos(delta), np.sin(delta)
                b, c = cd * b + 1j * sd * c / e1, 1j * e1 * sd * b + cd * c
            e0 = adm(n0, cos_i)
            r = (e0 * b - c) / (e0 * b + c)
            out = out + 0.5 * np.abs(r) ** 2
    return np.where(tir | ~np.isfinite(out), 1.0, np.clip(out, 0.0, 1.0))


def single_layer_reflectance(n0, ns, cos_i, wavelength_nm, film_index: float,
                             film_thickness_nm: float) -> np.ndarray:
    """Unpolarised reflectance of one film (index, physical thickness) on an interface."""
    return stack_reflectance(n0, ns, cos_i, wavelength_nm,
                             ((film_index, film_thickness_nm),))


def quarter_half_quarter(design_nm: float = 510.0) -> tuple:
    """The classic three-layer broadband anti-reflection stack (Macleod, Thin-Film Optical
    Filters, 4th ed., sec. 4.2, "quarter-half-quarter"): from the air side MgF2 (1.38,
    quarter wave), ZrO2 (2.05, half wave), Al2O3 (1.62, quarter wave) at design_nm."""
    q = design_nm / 4.0
    return ((1.38, q / 1.38), (2.05, 2.0 * q / 2.05), (1.62, q / 1.62))


@dataclass(frozen=True)
class Coating:
    """What covers a lens's air-glass surfaces: "bare"; "single" (a film of film_index,
    quarter-wave at design_nm); "multi" (the film stack `layers`, (index, thickness nm) from
    the air side; by default quarter_half_quarter()); or "table" (a reflectance curve,
    table_nm / table_r, at normal incidence)."""

    kind: str = "single"
    film_index: float = MGF2_INDEX
    design_nm: float = DESIGN_WAVELENGTH_NM
    layers: tuple = ()
    table_nm: tuple = ()
    table_r: tuple = ()

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"coating kind must be one of {', '.join(KINDS)}, got "
                             f"{self.kind!r}")
        if self.kind == "single" and not (self.film_index > 1.0 and self.design_nm > 0.0):
            raise ValueError(f"single-layer coating needs an index > 1 and a design wavelength "
                             f"> 0, got {self.film_index!r} and {self.design_nm!r}")
        if self.kind == "multi" and not all(
                len(l) == 2 and l[0] >= 1.0 and l[1] >= 0.0 for l in self.stack):
            raise ValueError("a coating stack is (index >= 1, thickness nm >= 0) per layer")
        if self.kind == "table":
            nm, r = np.asarray(self.table_nm, float), np.asarray(self.table_r, float)
            if (nm.ndim != 1 or nm.size < 2 or nm.shape != r.shape or np.any(np.diff(nm) <= 0)
                    or not np.all(np.isfinite(r)) or np.any((r < 0) | (r > 1))):
                raise ValueError("a coating table needs two or more increasing wavelengths "
                                 "(nm) and reflectances in [0, 1] of the same count")

    def path_weight(self, idx, m1, m2, reflect, cos_out, wl, weight, live=None) -> bool:
        """A ghost path's coating weights, compiled (core.coatings_kernels.path_weight_kernel:
        weight[i] *= the product over the steps a ray crossed of R where it reflects, 1 - R
        where it refracts; idx (media, rays) the indices, m1 / m2 each step's media rows,
        cos_out (steps, rays) its cosines, nan where not reached), in place, for the rays
        `live` (None: all; the others' weights are left as they are); False for a tabulated
        coating (the caller weighs it with `reflectance`)."""
        from . import jit
        from .coatings_kernels import path_weight_kernel
        if self.kind == "table":
            return False
        if self.kind == "bare":
            fwd = rev = np.zeros((0, 2))
        elif self.kind == "single":
            fwd = rev = np.array([[self.film_index, self.film_thickness_nm]], np.float64)
        else:
            fwd = np.array([[float(n), float(d)] for n, d in self.stack], np.float64)
            rev = np.ascontiguousarray(fwd[::-1])
        c = np.ascontiguousarray
        live = np.ones(weight.shape[0], np.bool_) if live is None else c(live, np.bool_)
        with jit.KERNEL_LOCK:
            path_weight_kernel(self.kind == "bare", c(idx, np.float64), c(m1, np.int64),
                               c(m2, np.int64), c(reflect, np.bool_), c(cos_out, np.float64),
                               c(wl, np.float64), c(fwd[:, 0]), c(fwd[:, 1]), c(rev[:, 0]),
                               c(rev[:, 1]), float(AIR_MAX_INDEX), live, weight)
        return True

    @property
    def film_thickness_nm(self) -> float:
        """The quarter-wave thickness: n_1 d = lambda_0 / 4."""
        return self.design_nm / (4.0 * self.film_index)

    @property
    def stack(self) -> tuple:
        return tuple(self.layers) if self.layers else quarter_half_quarter()

    def reflectance(self, n0, ns, cos_i, wavelength_nm) -> np.ndarray:
        """R of a surface between n0 and ns, at cos(incidence) and wavelength (arrays
        broadcast); a surface between equal indices reflects nothing, and one between two
        glasses (a cemented interface, which no maker coats) is bare."""
        if self.kind == "bare":
            return self._coated(n0, ns, cos_i, wavelength_nm)
        n0, ns, cos_i, lam = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in
                                                   (n0, ns, cos_i, wavelength_nm)))
        cemented = (n0 > AIR_MAX_INDEX) & (ns > AIR_MAX_INDEX)
        if not cemented.any():
            return self._coated(n0, ns, cos_i, lam)
        # each kind of surface computed on its own entries only (a ghost's path weighs every
        # step of every ray at once: the stack's matrices and Fresnel's both, everywhere,
        # cost a flare most of its time)
        r = np.empty(n0.shape)
        air = ~cemented
        r[air] = self._coated(n0[air], ns[air], cos_i[air], lam[air])
        r[cemented] = fresnel_reflectance(n0[cemented], ns[cemented], cos_i[cemented])
        return r

    def _coated(self, n0, ns, cos_i, wavelength_nm) -> np.ndarray:
        if self.kind == "bare":
            r = fresnel_reflectance(n0, ns, cos_i)
        elif self.kind == "single":
            r = single_layer_reflectance(n0, ns, cos_i, wavelength_nm, self.film_index,
                                         self.film_thickness_nm)
        elif self.kind == "multi":
            # the stack faces the air: seen from the glass side, its layers come reversed
            n0a = np.asarray(n0, dtype=np.float64)
            nsa = np.asarray(ns, dtype=np.float64)
            from_air = stack_reflectance(n0a, nsa, cos_i, wavelength_nm, self.stack)
            r = from_air if np.all(n0a <= nsa) else np.where(
                n0a <= nsa, from_air,
                stack_reflectance(n0a, nsa, cos_i, wavelength_nm, tuple(reversed(self.stack))))
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


KINDS = ("bare", "single", "multi", "table")
#: an index up to this is air (or a gas): a surface with glass on both sides is cemented
AIR_MAX_INDEX = 1.01
