"""Spectrum -> RGB: CIE 1931 colour matching, white normalisation, display colours.

Cycles and our engine are RGB renderers; the lens is traced at one wavelength per camera ray,
so colour comes from integrating spectra against colour-matching functions (DESIGN.md:
"normalised so white stays white").

Colour-matching functions
    x_bar, y_bar, z_bar: the CIE 1931 2-degree standard observer, 360-830 nm at 5 nm, read from
    `data/cie1931_2deg_5nm.csv` (source cited in its header). Between table rows they are
    interpolated linearly; outside 360-830 nm they are 0. (Wyman, Sloan & Shirley 2013 give an
    analytic multi-lobe Gaussian fit; we do NOT use it: the tabulated standard is the truth.)

XYZ -> linear Rec.709 / sRGB (D65)
    rgb = M xyz, M = inverse of the matrix whose columns are the Rec.709 primaries
    R (0.64, 0.33), G (0.30, 0.60), B (0.15, 0.06) scaled so that R + G + B = D65 white
    (x, y) = (0.3127, 0.3290), Y = 1 (IEC 61966-2-1), computed from those chromaticities:
        M = [[ 3.2409699, -1.5373832, -0.4986108],
             [-0.9692436,  1.8759675,  0.0415551],
             [ 0.0556301, -0.2039770,  1.0569715]]
    (the standard's 4-digit table 3.2406 -1.5372 -0.4986 / -0.9689 1.8758 0.0415 /
    0.0557 -0.2040 1.0570 agrees to its rounding).
    rgb_bar(lambda) = M [x_bar, y_bar, z_bar](lambda) are the Rec.709 colour-matching functions.

White stays white (per-channel normalisation)
    For a sampled range [lo, hi] (default 380-780 nm), channel c of a spectral radiance L is
        RGB_c = k_c * integral_lo^hi rgb_bar_c(lambda) L(lambda) dlambda,
        k_c   = 1 / integral_lo^hi rgb_bar_c(lambda) dlambda,
    so a spectrally flat L = 1 gives RGB = (1, 1, 1) exactly. The integrals of the piecewise
    linear rgb_bar are computed exactly (trapezoid rule on the table knots). This is a diagonal
    (von Kries-like) white balance in linear Rec.709 that maps equal-energy white E onto the
    display white; without it E would render slightly pink (E is not D65).
    Rendering weights each camera ray by non-negative channel responses derived from these
    curves (core.sensor_response), because the curves themselves go negative (spectral colours
    lie outside the Rec.709 gamut) and would make pixels negative.

Standard spectral lines (nm): F 486.1327 (H), d 587.5618 (He), C 656.2725 (H), g 435.8343 (Hg),
e 546.0740 (Hg).

Pure numpy, float64, vectorised over whole arrays; never NaN (invalid inputs give weight 0).
"""

from __future__ import annotations

import functools
import math
import os

import numpy as np

#: Fraunhofer / standard lines used in glass data (nm).
WAVELENGTHS_NM: dict[str, float] = {
    "F": 486.1327,
    "d": 587.5618,
    "C": 656.2725,
    "g": 435.8343,
    "e": 546.0740,
}

#: Default sampled range of the renderer (nm).
DEFAULT_LO_NM = 380.0
DEFAULT_HI_NM = 780.0

#: Extent of the CIE table (nm); the CMFs are 0 outside it.
CIE_MIN_NM = 360.0
CIE_MAX_NM = 830.0

_CIE_CSV = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data",
                        "cie1931_2deg_5nm.csv")



def _rgb_to_xyz_matrix(primaries_xy, white_xy) -> np.ndarray:
    """Matrix whose columns are the primaries' XYZ, scaled so that (1,1,1) -> white (Y = 1)."""
    def xyz(xy):
        x, y = xy
        return np.array([x / y, 1.0, (1.0 - x - y) / y])
    p = np.stack([xyz(c) for c in primaries_xy], axis=1)
    s = np.linalg.solve(p, xyz(white_xy))
    return p * s[None, :]


#: Linear Rec.709 / sRGB (D65) -> CIE XYZ.
LINEAR_SRGB_TO_XYZ: np.ndarray = _rgb_to_xyz_matrix(
    [(0.64, 0.33), (0.30, 0.60), (0.15, 0.06)], (0.3127, 0.3290))
#: CIE XYZ -> linear Rec.709 / sRGB (D65).
XYZ_TO_LINEAR_SRGB: np.ndarray = np.linalg.inv(LINEAR_SRGB_TO_XYZ)
LINEAR_SRGB_TO_XYZ.setflags(write=False)
XYZ_TO_LINEAR_SRGB.setflags(write=False)


@functools.lru_cache(maxsize=1)
def cie_table() -> tuple[np.ndarray, np.ndarray]:
    """(wavelengths (95,), xyz (95, 3)) of the CIE 1931 2-degree table, read once, read-only."""
    rows = []
    with open(_CIE_CSV, encoding="utf-8") as f:
        for line_no, line in enumerate(f, 1):
            line = line.strip()
            if not line or line.startswith("#") or line.startswith("wavelength"):
                continue
            parts = line.split(",")
            if len(parts) != 4:
                raise ValueError(f"{_CIE_CSV}: line {line_no}: expected 4 comma-separated "
                                 f"values (wavelength_nm,x_bar,y_bar,z_bar), got {line!r}")
            rows.append([float(p) for p in parts])
    data = np.array(rows, dtype=np.float64)
    wl = data[:, 0].copy()
    xyz = data[:, 1:].copy()
    if not (np.all(np.diff(wl) > 0) and wl[0] == CIE_MIN_NM and wl[-1] == CIE_MAX_NM):
        raise ValueError(f"{_CIE_CSV}: wavelengths must increase from {CIE_MIN_NM:g} to "
                         f"{CIE_MAX_NM:g} nm")
    wl.setflags(write=False)
    xyz.setflags(write=False)
    return wl, xyz


def cmf_xyz(wavelength_nm) -> np.ndarray:
    """CIE 1931 (x_bar, y_bar, z_bar) at each wavelength: shape wavelength.shape + (3,).

    Linear interpolation of the 5 nm table; 0 outside 360-830 nm and for non-finite input.
    """
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    wl, xyz = cie_table()
    flat = lam.reshape(-1)
    ok = np.isfinite(flat) & (flat >= CIE_MIN_NM) & (flat <= CIE_MAX_NM)
    safe = np.where(ok, flat, CIE_MIN_NM)
    out = np.stack([np.interp(safe, wl, xyz[:, c]) for c in range(3)], axis=-1)
    out[~ok] = 0.0
    return out.reshape(lam.shape + (3,))


def xyz_to_linear_srgb(xyz) -> np.ndarray:
    """Apply XYZ_TO_LINEAR_SRGB to the last axis."""
    return np.asarray(xyz, dtype=np.float64) @ XYZ_TO_LINEAR_SRGB.T


def cmf_rgb(wavelength_nm) -> np.ndarray:
    """Linear Rec.709 colour-matching functions rgb_bar = M xyz_bar (un-normalised)."""
    return xyz_to_linear_srgb(cmf_xyz(wavelength_nm))


def check_wavelength_range(lo: float, hi: float) -> tuple[float, float]:
    lo, hi = float(lo), float(hi)
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"wavelength range must satisfy lo < hi (nm), got lo={lo:g}, hi={hi:g}")
    if hi <= CIE_MIN_NM or lo >= CIE_MAX_NM:
        raise ValueError(f"wavelength range {lo:g}-{hi:g} nm lies outside the CIE table "
                         f"({CIE_MIN_NM:g}-{CIE_MAX_NM:g} nm)")
    return lo, hi


@functools.lru_cache(maxsize=32)
def _rgb_integrals(lo: float, hi: float) -> np.ndarray:
    """Exact integral over [lo, hi] of the piecewise-linear rgb_bar (3,)."""
    wl, _ = cie_table()
    knots = np.concatenate([[lo, hi], wl[(wl > lo) & (wl < hi)]])
    knots = np.unique(knots)
    vals = cmf_rgb(knots)
    integ = np.sum(0.5 * (vals[1:] + vals[:-1]) * np.diff(knots)[:, None], axis=0)
    integ.setflags(write=False)
    return integ


def rgb_normalisation(lo: float = DEFAULT_LO_NM, hi: float = DEFAULT_HI_NM) -> np.ndarray:
    """k (3,) with k_c = 1 / integral_lo^hi rgb_bar_c: a flat spectrum then maps to (1, 1, 1)."""
    lo, hi = check_wavelength_range(lo, hi)
    integ = _rgb_integrals(lo, hi)
    if np.any(integ <= 0):
        raise ValueError(f"wavelength range {lo:g}-{hi:g} nm is too narrow: a channel of the "
                         f"Rec.709 colour-matching functions integrates to {integ.min():.3g} "
                         "there, so white cannot be normalised")
    return 1.0 / integ


# ---- display colours --------------------------------------------------------------------------

def linear_to_srgb(rgb) -> np.ndarray:
    """sRGB transfer function (IEC 61966-2-1) of linear values clipped to [0, 1]."""
    c = np.clip(np.asarray(rgb, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1.0 / 2.4) - 0.055)


def wavelength_to_display_rgb(wavelength_nm) -> np.ndarray:
    """A plot colour (sRGB-encoded, in [0, 1], shape (..., 3)) for each wavelength.

    rgb = M xyz_bar(lambda) with lambda clamped to 360-830 nm, negative (out-of-gamut) channels
    clipped to 0, scaled so the largest channel is 1 (every wavelength equally bright), then
    sRGB-encoded. Purely for spot diagrams and legends, never for rendering.
    Non-finite wavelengths give mid grey.
    """
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    ok = np.isfinite(lam)
    rgb = cmf_rgb(np.clip(np.where(ok, lam, 550.0), CIE_MIN_NM, CIE_MAX_NM))
    rgb = np.maximum(rgb, 0.0)
    peak = rgb.max(axis=-1, keepdims=True)
    rgb = rgb / np.where(peak > 0, peak, 1.0)
    out = linear_to_srgb(rgb)
    out[~ok] = 0.5
    return out
