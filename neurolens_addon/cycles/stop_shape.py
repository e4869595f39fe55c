"""The aperture-stop shape as OSL: an inside test at the stop, and (thin lens) a sampler.

Coordinates are stop-normalised, (x, y) / R with R the stop radius, as in core.aperture, whose
shapes and equations these functions reproduce in float32:
- circle: inside iff x^2 + y^2 <= 1.
- n blades, rotation rot, curvature kappa: with alpha = pi / n, a = cos(alpha), h = sin(alpha),
  s = h^2 kappa / (1 + sqrt(1 - kappa^2 h^2)), q = kappa (a + s) - 1, the boundary in the frame
  of the nearest edge (angle beta from its normal) is
      r_max(beta) = (2 - kappa (a + s)) (a + s) / (sqrt(1 - q^2 sin^2 beta) - q cos beta),
  inside iff rho <= r_max(beta) (straight blades: r_max = a / cos(beta)).
- image mask (H x W over [-1, 1]^2, row 0 at y = +1): bilinear transmittance > 0.5, of the
  shape core.aperture.shader_shape gives (masks of more than SHADER_MASK_SIDE pixels a side
  area-averaged down: the shape the derived camera normalises the Cycles camera with).

Thin-lens sampling of the shape (u1, u2 uniform; unit-radius shape, weight keeps E[weight] = 1):
- circle: Shirley & Chiu's concentric map (the map Cycles' own camera uses), weight 1.
- straight blades: fan sector j = floor(n u1), swept-area fraction t = n u1 - j,
  beta = atan(2 t a h / a^2 - tan(alpha)), rho = (a / cos beta) sqrt(u2), exact and uniform.
- curved blades and masks: uniform on the bounding disc / square and rejected outside, weight
  (sampled area) / (shape area) so exposure does not change.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.aperture import CircularAperture, ImageMaskAperture, PolygonAperture, shader_shape
from ..core.oslfmt import float_array, flt, indent

#: relative slack of the inside test (float32 rounding on the boundary)
EDGE_SLACK = 1e-6


def _polygon_constants(ap: PolygonAperture) -> dict:
    kappa = ap.curvature
    alpha = math.pi / ap.blades
    a, h = math.cos(alpha), math.sin(alpha)
    kh = kappa * h
    s = h * kh / (1.0 + math.sqrt(max(0.0, 1.0 - kh * kh)))
    apex = a + s
    return {"alpha": alpha, "a": a, "h": h, "q": kappa * apex - 1.0,
            "num": (2.0 - kappa * apex) * apex, "rot": math.radians(ap.rotation_deg)}


def inside_osl(aperture) -> list[str]:
    """OSL `int nl_inside_stop(float x, float y)` for stop-normalised coordinates."""
    ap = shader_shape(aperture)
    head = "int nl_inside_stop(float x, float y)"
    if isinstance(ap, CircularAperture):
        return ["// Stop shape: circle.", head, "{",
                f"    return x * x + y * y <= {flt(1.0 + 2.0 * EDGE_SLACK)};", "}"]
    if isinstance(ap, PolygonAperture):
        k = _polygon_constants(ap)
        width = 2.0 * k["alpha"]
        return [(f"// Stop shape: {ap.blades} blades, rotation {ap.rotation_deg:g} deg, "
                f"curvature {ap.curvature:g}."), head, "{",
                "    float rho = sqrt(x * x + y * y);",
                f"    float phi = atan2(y, x) - {flt(k['rot'])};",
                f"    float sector = floor(phi * {flt(1.0 / width)});",
                (f"    float beta = clamp(phi - (sector + 0.5) * {flt(width)}, {flt(-k['alpha'])}, "
                f"{flt(k['alpha'])});"),
                "    float sb = sin(beta);",
                (f"    float rmax = {flt(k['num'])} / (sqrt(max(1.0 - {flt(k['q'] ** 2)} * sb * sb, "
                f"0.0)) - {flt(k['q'])} * cos(beta));"),
                f"    return rho <= rmax * {flt(1.0 + EDGE_SLACK)};", "}"]
    m = np.asarray(ap.mask, dtype=np.float64)
    h, w = m.shape
    table = float_array("NL_MASK", m, f"aperture mask {h} x {w}, row 0 at y = +1")
    return [f"// Stop shape: image mask ({h} x {w}), bilinear transmittance > 0.5.", head,
            "{"] + indent(table) + [
              "    if (abs(x) > 1.0 || abs(y) > 1.0) return 0;",
              f"    float fx = clamp((x + 1.0) * {flt(0.5 * w)} - 0.5, 0.0, {flt(w - 1)});",
              f"    float fy = clamp((1.0 - y) * {flt(0.5 * h)} - 0.5, 0.0, {flt(h - 1)});",
              f"    int j0 = min((int)floor(fx), {max(w - 2, 0)});",
              f"    int i0 = min((int)floor(fy), {max(h - 2, 0)});",
              f"    int j1 = min(j0 + 1, {w - 1});",
              f"    int i1 = min(i0 + 1, {h - 1});",
              "    float tx = fx - j0;",
              "    float ty = fy - i0;",
              f"    float top = mix(NL_MASK[i0 * {w} + j0], NL_MASK[i0 * {w} + j1], tx);",
              f"    float bottom = mix(NL_MASK[i1 * {w} + j0], NL_MASK[i1 * {w} + j1], tx);",
              "    return mix(top, bottom, ty) > 0.5;", "}"]


def _open_fraction(ap, n: int = 1024) -> float:
    """Fraction of [-1, 1]^2 (mask) or of the unit disc (curved blades) inside the shape."""
    g = -1.0 + (2.0 * np.arange(n) + 1.0) / n
    x, y = np.meshgrid(g, g)
    inside = np.asarray(ap.inside(x, y), dtype=bool)
    if isinstance(ap, ImageMaskAperture):
        return float(inside.mean())
    disc = x * x + y * y <= 1.0
    return float((inside & disc).sum() / disc.sum())


def sample_osl(aperture) -> list[str]:
    """OSL `void nl_sample_aperture(u1, u2, x, y, weight)`: a point of the unit-radius shape."""
    ap = shader_shape(aperture)
    head = "void nl_sample_aperture(float u1, float u2, output float x, output float y, " \
           "output float weight)"
    concentric = ["    float a = 2.0 * u1 - 1.0;",
                  "    float b = 2.0 * u2 - 1.0;",
                  "    float r = 0.0;",
                  "    float phi = 0.0;",
                  "    if (a * a > b * b) { r = a; phi = M_PI_4 * (b / a); }",
                  "    else if (b != 0.0) { r = b; phi = M_PI_2 - M_PI_4 * (a / b); }",
                  "    x = r * cos(phi);",
                  "    y = r * sin(phi);"]
    if isinstance(ap, CircularAperture):
        return ["// Concentric disc map (Shirley & Chiu).", head, "{"] + concentric + \
               ["    weight = 1.0;", "}"]
    if isinstance(ap, PolygonAperture) and ap.curvature == 0.0:
        k = _polygon_constants(ap)
        n = ap.blades
        return [f"// Uniform point of the {n}-blade iris: fan sector, then swept area.", head, "{",
                f"    float s = clamp(u1, 0.0, 0.99999994) * {flt(n)};",
                "    float sector = floor(s);",
                (f"    float beta = atan({flt(2.0 * k['h'] / k['a'])} * (s - sector) - "
                f"{flt(math.tan(k['alpha']))});"),
                f"    float rho = {flt(k['a'])} / cos(beta) * sqrt(u2);",
                f"    float phi = {flt(k['rot'])} + (2.0 * sector + 1.0) * {flt(k['alpha'])} + beta;",
                "    x = rho * cos(phi);",
                "    y = rho * sin(phi);",
                "    weight = 1.0;", "}"]
    frac = _open_fraction(ap)
    if isinstance(ap, ImageMaskAperture):
        return ["// Uniform on the mask's square, rejected outside the open part.", head, "{",
                "    x = 2.0 * u1 - 1.0;",
                "    y = 2.0 * u2 - 1.0;",
                f"    weight = nl_inside_stop(x, y) ? {flt(1.0 / frac)} : 0.0;", "}"]
    return ["// Uniform on the bounding disc, rejected outside the curved blades.", head, "{"] + \
        concentric + [f"    weight = nl_inside_stop(x, y) ? {flt(1.0 / frac)} : 0.0;", "}"]
