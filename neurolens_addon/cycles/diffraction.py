"""OSL for diffraction (core.diffraction): the stop's Fraunhofer table and the turn of the exit ray.

The shader samples the same polar table as core.diffraction.sample_frequency (radial bin by a
binary search of the marginal CDF, angular bin by one of its row's CDF, half plane and the
point in the cell from the remainders) and turns the lens-space exit direction with
core.diffraction.tangent_frame's basis:
    ld' = normalize(ld + k f_x e_1 + k f_y e_2),   k = lambda_nm 1e-6 / R_ep (mm),
R_ep the entrance pupil's radius, proportional to the stop radius R (paraxial), so a camera
that follows an animated f-number scales k with its frame's 1 / R. The two uniforms are
hashnoise of the aperture sample with their own seeds (decorrelated from the pupil point and
the wavelength); a probe uses probe_sample itself (tests compare the shader with numpy).
"""

from __future__ import annotations

from ..core.diffraction import NPHI, NR, entrance_pupil_radius_mm, table_for
from ..core.oslfmt import float_array, flt, indent

#: hashnoise seeds of the two uniforms that pick the pattern's sample
SEEDS = (0.7548776662, 0.5698402910)


def pupil_per_stop(lens) -> float:
    """R_ep / R: the entrance pupil's radius per mm of stop radius (paraxial)."""
    return entrance_pupil_radius_mm(lens, lens.stop_radius_mm) / lens.stop_radius_mm


def scale_operand(spec, inv_stop_radius: str) -> str:
    """OSL operand of 1e-6 / R_ep (per nm of wavelength) for a lens camera whose 1 / R is the
    operand inv_stop_radius (a constant, or the frame's value)."""
    return f"{flt(1e-6 / pupil_per_stop(spec.lens))} * {inv_stop_radius}"


def diffraction_functions(aperture) -> list[str]:
    """OSL: `nl_fraunhofer(u1, u2, fx, fy)` over the shape's table, and `nl_diffract`."""
    t = table_for(aperture)
    tables = float_array("NL_FR_RHO", t.rho_edges, f"radial bin edges ({NR} bins, cycles "
                                                   "per entrance-pupil radius)")
    tables += float_array("NL_FR_M", t.marginal, "CDF over the radial bins")
    tables += float_array("NL_FR_C", t.conditional, f"CDF over {NPHI} angular bins in "
                                                    "[0, pi), per radial bin")
    return [
        f"// The aperture's Fraunhofer pattern (core.diffraction; {t.captured:.4f} of its energy",
        "// within the table): a frequency (fx, fy) in cycles per entrance-pupil radius.",
        "void nl_fraunhofer(float u1, float u2, output float fx, output float fy)",
        "{",
    ] + indent(tables) + [
        "    int lo = 0;",
        f"    int hi = {NR};",
        "    while (hi - lo > 1) { int mid = (lo + hi) / 2; if (NL_FR_M[mid] <= u1) lo = mid; "
        "else hi = mid; }",
        "    int k = lo;",
        "    float r1 = clamp((u1 - NL_FR_M[k]) / max(NL_FR_M[k + 1] - NL_FR_M[k], 1e-30), "
        "0.0, 1.0);",
        f"    int base = k * {NPHI + 1};",
        "    lo = 0;",
        f"    hi = {NPHI};",
        "    while (hi - lo > 1) { int mid = (lo + hi) / 2; if (NL_FR_C[base + mid] <= u2) "
        "lo = mid; else hi = mid; }",
        "    int j = lo;",
        "    float r2 = clamp((u2 - NL_FR_C[base + j]) / max(NL_FR_C[base + j + 1] - "
        "NL_FR_C[base + j], 1e-30), 0.0, 0.99999994);",
        "    float half = r2 >= 0.5 ? 1.0 : 0.0;",
        "    float r3 = 2.0 * r2 - half;",
        "    float e0 = NL_FR_RHO[k];",
        "    float e1 = NL_FR_RHO[k + 1];",
        "    float rho = sqrt(e0 * e0 + r1 * (e1 * e1 - e0 * e0));",
        f"    float phi = (j + r3) * {flt(3.141592653589793 / NPHI)} + M_PI * half;",
        "    fx = rho * cos(phi);",
        "    fy = rho * sin(phi);",
        "}",
        "",
        "// d turned by (kx, ky) along the x and y axes carried to d (rotation taking z to d).",
        "vector nl_diffract(vector d, float kx, float ky)",
        "{",
        "    float inv = 1.0 / max(1.0 + d[2], 1e-12);",
        "    vector e1 = vector(1.0 - d[0] * d[0] * inv, -d[0] * d[1] * inv, -d[0]);",
        "    vector e2 = vector(-d[0] * d[1] * inv, 1.0 - d[1] * d[1] * inv, -d[1]);",
        "    return normalize(d + kx * e1 + ky * e2);",
        "}",
    ]


def diffraction_lines(spec, scale: str) -> list[str]:
    """Shader body lines turning `ld` (after the lens), scale the operand of 1e-6 / R_ep."""
    if spec.probe is not None:
        xa, xb = flt(spec.probe_sample[0]), flt(spec.probe_sample[1])
    else:
        xa = f"hashnoise(point(u1, u2, {flt(SEEDS[0])}))"
        xb = f"hashnoise(point(u1, u2, {flt(SEEDS[1])}))"
    return [
        "// diffraction: the exit ray turned by the stop's Fraunhofer pattern at lambda",
        "float fr_x = 0.0;",
        "float fr_y = 0.0;",
        f"nl_fraunhofer({xa}, {xb}, fr_x, fr_y);",
        f"float fr_k = lambda_nm * {scale};",
        "ld = nl_diffract(ld, fr_k * fr_x, fr_k * fr_y);",
    ]
