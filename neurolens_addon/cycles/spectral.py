"""Wavelength per camera ray and refractive index per medium, written as OSL.

Wavelength (one uniform number xi per ray). The ray's wavelength is drawn from the sensor
density p = (s_R + s_G + s_B) / 3 of core.sensor_response, linear between its M knots
lambda_j, by the exact inverse CDF: a binary search of the tabulated CDF P_j for the segment j
with P_j <= xi < P_{j+1}, then, with a = p(lambda_j), b = p(lambda_{j+1}), h the segment width
and r = xi - P_j,
    t = 2 r / (a + sqrt(a^2 + 2 (b - a) r / h)),   lambda = lambda_j + t.
The ray's colour weight is w = s(lambda) / p(lambda) = 3 s(lambda) / sum_c s_c(lambda), with s
interpolated linearly between the same knots: non-negative, R + G + B = 3 on every ray, and
E[w] = (1, 1, 1), so white stays white and no pixel can go negative.

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

import math

import numpy as np

from ..core.oslfmt import comment_text, float_array, flt, indent
from ..core.prescription import WAVELENGTH_D_NM
from ..core.sensor_response import sensor_response


def sample_wavelength(xi):
    """numpy twin of the shader's nl_wavelength: (lambda (N,), RGB weight (N, 3))."""
    return sensor_response().sample_sensor(np.asarray(xi, dtype=np.float64))


def wavelength_osl() -> list[str]:
    """OSL: constant tables and `nl_wavelength(xi, lambda_nm, weight)`."""
    r = sensor_response()
    m = len(r.knots)
    steps = max(1, math.ceil(math.log2(m - 1)))
    tables = float_array("NL_LAMBDA", r.knots, "knots of the channel responses (nm)")
    tables += float_array("NL_CDF", r.sensor_cdf, "CDF of the sensor density at the knots")
    tables += float_array("NL_S_R", r.values[:, 0], "channel responses s_c at the knots (1/nm)")
    tables += float_array("NL_S_G", r.values[:, 1])
    tables += float_array("NL_S_B", r.values[:, 2])
    return [
        "// Wavelength of one ray, drawn from the sensor density, and its RGB weight s / p.",
        "void nl_wavelength(float xi, output float lambda_nm, output color weight)",
        "{",
    ] + indent(tables) + [
        "    float u = clamp(xi, 0.0, 0.99999994);",
        f"    int lo = 0, hi = {m - 1};",
        f"    for (int i = 0; i < {steps}; ++i) {{",
        "        int mid = (lo + hi) / 2;",
        "        if (hi - lo > 1) {",
        "            if (NL_CDF[mid] <= u) lo = mid; else hi = mid;",
        "        }",
        "    }",
        "    float h = NL_LAMBDA[lo + 1] - NL_LAMBDA[lo];",
        "    color s0 = color(NL_S_R[lo], NL_S_G[lo], NL_S_B[lo]);",
        "    color s1 = color(NL_S_R[lo + 1], NL_S_G[lo + 1], NL_S_B[lo + 1]);",
        "    float a = (s0[0] + s0[1] + s0[2]) / 3.0;",
        "    float b = (s1[0] + s1[1] + s1[2]) / 3.0;",
        "    float r = u - NL_CDF[lo];",
        "    float den = a + sqrt(max(a * a + 2.0 * (b - a) * r / h, 0.0));",
        "    float t = den > 0.0 ? clamp(2.0 * r / den, 0.0, h) : 0.0;",
        "    lambda_nm = NL_LAMBDA[lo] + t;",
        "    color s = mix(s0, s1, t / h);",
        "    float total = s[0] + s[1] + s[2];",
        "    weight = total > 0.0 ? s * (3.0 / total) : color(1.0);",
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
            decls.append(f"float {seen[key]} = {index_expression(m)};  "
                         f"// {comment_text(m.name)}")
        names.append(seen[key])
    return decls, names
