"""Wavelength per camera ray and refractive index per medium, written as OSL.

Wavelength sampling (one uniform number xi per ray). The core's "visible" density
(core.spectrum.sample_wavelengths) is tabulated by its inverse CDF at K + 1 knots
lambda_k = sample_wavelengths(k / K, "visible"); the shader draws
    s = K xi,  k = floor(s),  lambda = lambda_k + (s - k) (lambda_{k+1} - lambda_k),
so lambda has the density p = 1 / (K (lambda_{k+1} - lambda_k)) on segment k, and the ray is
weighted by
    w(lambda) = k_rgb rgb_bar(lambda) / p = k_rgb rgb_bar(lambda) K (lambda_{k+1} - lambda_k),
with rgb_bar the linear Rec.709 colour-matching functions interpolated linearly between the CIE
5 nm knots (exactly core.spectrum's interpolation) and k_rgb = core.spectrum.rgb_normalisation.
Then E[w] = k_rgb * integral(rgb_bar) = (1, 1, 1) whatever the knots: white stays white, and the
knots only shape the noise.

Refractive index of each medium at L = lambda / 1000 (micrometres), L2 = L^2, from the glass
law core.glass resolved for it:
    Sellmeier  n = sqrt(1 + sum B_i + sum B_i C_i / (L2 - C_i))
    Schott     n = sqrt(A0 + A1 L2 + (A2 + (A3 + (A4 + A5 / L2) / L2) / L2) / L2)
    (n_d, V_d) oscillator  n = A + B / (L2 - L0^2);  Cauchy  n = a + (b + c / L2) / L2
    air 1, index-only glass n_d.
The expressions use only + - * / and sqrt, so the same text evaluates in Python (tests check
it against core.glass) and in OSL.
"""

from __future__ import annotations

import numpy as np

from ..core.prescription import WAVELENGTH_D_NM
from ..core.spectrum import (
    CIE_MIN_NM,
    DEFAULT_HI_NM,
    DEFAULT_LO_NM,
    cmf_rgb,
    rgb_normalisation,
    sample_wavelengths,
)
from ..core.oslfmt import float_array, flt, indent

#: Segments of the tabulated inverse CDF of the wavelength density.
WAVELENGTH_SEGMENTS = 64
#: Spacing of the CIE table (nm); the colour-matching knots lie on it.
CMF_STEP_NM = 5.0


def wavelength_knots(segments: int = WAVELENGTH_SEGMENTS, lo: float = DEFAULT_LO_NM,
                     hi: float = DEFAULT_HI_NM) -> np.ndarray:
    """lambda_0..lambda_K: the inverse CDF of core.spectrum's "visible" density at k / K."""
    u = np.arange(segments + 1, dtype=np.float64) / segments
    lam, _ = sample_wavelengths(np.minimum(u, np.nextafter(1.0, 0.0)), lo, hi, "visible")
    lam[0], lam[-1] = lo, hi
    return lam


def cmf_knots(lo: float = DEFAULT_LO_NM, hi: float = DEFAULT_HI_NM):
    """(wavelengths on the CIE 5 nm grid covering [lo, hi], k_rgb * rgb_bar there (M, 3))."""
    first = CIE_MIN_NM + CMF_STEP_NM * np.floor((lo - CIE_MIN_NM) / CMF_STEP_NM)
    last = CIE_MIN_NM + CMF_STEP_NM * np.ceil((hi - CIE_MIN_NM) / CMF_STEP_NM)
    wl = np.arange(first, last + 0.5 * CMF_STEP_NM, CMF_STEP_NM)
    rgb = cmf_rgb(wl) * rgb_normalisation(lo, hi)
    rgb[(wl < lo) | (wl > hi)] = 0.0
    return wl, rgb


def sample_wavelength(xi, segments: int = WAVELENGTH_SEGMENTS):
    """numpy twin of the shader's nl_wavelength: (lambda (N,), RGB weight (N, 3))."""
    lam_k = wavelength_knots(segments)
    wl, rgb = cmf_knots()
    s = np.clip(np.asarray(xi, dtype=np.float64), 0.0, np.nextafter(1.0, 0.0)) * segments
    k = np.minimum(s.astype(np.int64), segments - 1)
    width = lam_k[k + 1] - lam_k[k]
    lam = lam_k[k] + (s - k) * width
    t = (lam - wl[0]) / CMF_STEP_NM
    j = np.clip(t.astype(np.int64), 0, len(wl) - 2)
    g = (t - j)[:, None]
    cmf = (1.0 - g) * rgb[j] + g * rgb[j + 1]
    return lam, cmf * (segments * width)[:, None]


def wavelength_osl(segments: int = WAVELENGTH_SEGMENTS) -> list[str]:
    """OSL: constant tables and `nl_wavelength(xi, lambda_nm, weight)`."""
    lam_k = wavelength_knots(segments)
    wl, rgb = cmf_knots()
    m = len(wl)
    tables = float_array("NL_LAMBDA", lam_k, f"inverse CDF of the wavelength density at "
                                             f"k/{segments} (nm)")
    tables += float_array("NL_CMF_R", rgb[:, 0], f"k_rgb * rgb_bar on the CIE grid from "
                                                 f"{wl[0]:g} nm every {CMF_STEP_NM:g} nm")
    tables += float_array("NL_CMF_G", rgb[:, 1])
    tables += float_array("NL_CMF_B", rgb[:, 2])
    return [
        "// Wavelength of one ray and its RGB weight k_rgb rgb_bar(lambda) / p(lambda).",
        "void nl_wavelength(float xi, output float lambda_nm, output color weight)",
        "{",
    ] + indent(tables) + [
        f"    float s = clamp(xi, 0.0, 0.99999994) * {flt(segments)};",
        f"    int k = min((int)s, {segments - 1});",
        "    float width = NL_LAMBDA[k + 1] - NL_LAMBDA[k];",
        "    lambda_nm = NL_LAMBDA[k] + (s - k) * width;",
        f"    float t = (lambda_nm - {flt(wl[0])}) * {flt(1.0 / CMF_STEP_NM)};",
        f"    int j = clamp((int)t, 0, {m - 2});",
        "    float g = t - j;",
        "    color lo = color(NL_CMF_R[j], NL_CMF_G[j], NL_CMF_B[j]);",
        "    color hi = color(NL_CMF_R[j + 1], NL_CMF_G[j + 1], NL_CMF_B[j + 1]);",
        f"    weight = mix(lo, hi, g) * ({flt(segments)} * width);",
        "}",
    ]


# ---- refractive indices --------------------------------------------------------------------

def _minus(c: float) -> str:
    """'- c' written so that both Python and OSL read it (no '- -')."""
    return f"- {flt(c)}" if c >= 0 else f"+ {flt(-c)}"


def index_expression(medium, var: str = "L2") -> str:
    """An expression for the index of a core.glass medium in terms of `var` = L^2 (um^2)."""
    from ..core.glass import AIR, AbbeGlass, Glass
    if medium is AIR:
        return "1.0"
    if isinstance(medium, Glass):
        if medium.formula == "sellmeier":
            offset = 1.0 + sum(medium.B)
            terms = " + ".join(f"{flt(b * c)} / ({var} {_minus(c)})"
                               for b, c in zip(medium.B, medium.C))
            return f"sqrt({flt(offset)} + {terms})"
        a0, a1, a2, a3, a4, a5 = medium.A
        return (f"sqrt({flt(a0)} + {flt(a1)} * {var} + ({flt(a2)} + ({flt(a3)} + ({flt(a4)} + "
                f"{flt(a5)} / {var}) / {var}) / {var}) / {var})")
    if isinstance(medium, AbbeGlass):
        a, b, c = medium.coefficients
        if medium.law == "constant":
            return flt(a)
        if medium.law == "oscillator":
            return f"({flt(a)} + {flt(b)} / ({var} {_minus(c)}))"
        return f"({flt(a)} + ({flt(b)} + {flt(c)} / {var}) / {var})"
    raise TypeError(f"no OSL form for medium {medium!r}")


def media_osl(lens, dispersion: bool, catalog=None):
    """Indices of the lens's media (n+1 slots: before surface 0, ..., after the last).

    Returns (declaration lines, one OSL operand per slot). Without dispersion every operand is
    the float32 literal of the index at the d line (computed in float64 by core.glass); with it,
    each distinct glass gets one `float nl_nK = <law at L2>;` evaluated once per ray.
    """
    from ..core.glass import AIR, resolve_medium
    media = [resolve_medium(m, catalog) for m in lens.media()]
    if not dispersion:
        wl = np.array([WAVELENGTH_D_NM])
        return [], [flt(float(m.index(wl)[0])) for m in media]
    decls, names, seen = [], [], {}
    for m in media:
        if m is AIR:
            names.append("1.0")
            continue
        key = id(m)
        if key not in seen:
            seen[key] = f"nl_n{len(seen)}"
            decls.append(f"float {seen[key]} = {index_expression(m)};  // {m.name}")
        names.append(seen[key])
    return decls, names
