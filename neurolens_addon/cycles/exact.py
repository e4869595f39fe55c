"""OSL for the exact lens: core.trace's sequential trace, surface by surface, in float32.

For each camera ray: a sensor point (frame), a direction towards the lens's rear pupil with its
irradiance weight (pupil_table), then every surface from the back (sensor side) to the front:
- intersection in the surface's local frame s = z_vertex - z with the conic
      c (x^2 + y^2) + c (1 + k) s^2 - 2 s = 0,
  i.e. A t^2 + 2 B t + C = 0 with A = c + (c(1+k) - c) d_s^2 (d unit),
  B = c (o_x d_x + o_y d_y) + (c(1+k) s_0 - 1) d_s, C = c (o_x^2 + o_y^2) + (c(1+k) s_0 - 2) s_0,
  roots q / A and C / q with q = -(B + sign(B) sqrt(B^2 - AC)), keeping the nearest forward root
  on the cap through the vertex (1 - c(1+k) s > 0); a plane is t = (z_v - o_z) / d_z.
  Spheres with |R| <= 200 mm use the equivalent centre form, division-free and ~40 % faster:
  with oc = o - (0, 0, z_v - R), t = -oc.d -/+ sqrt((oc.d)^2 - |oc|^2 + R^2) (float32 error
  ~1e-7 |R| mm, so flatter spheres keep the cancellation-free form);
- an even asphere refines that root with Newton steps on f(t) = s(t) - sag(rho(t)),
      sag = c rho / (1 + sqrt(1 - c^2 (1+k) rho)) + sum_h A_2h rho^h,   rho = x^2 + y^2,
  and is dropped unless |f| <= 1e-4 mm;
- clipping: rho > semi-diameter^2, or outside the stop shape at the stop (stop_shape);
- refraction, Snell in vector form with eta = n_before / n_after and cos_i = -N.d > 0:
      d' = eta d + (eta cos_i - sqrt(1 - eta^2 (1 - cos_i^2))) N,  TIR drops the ray;
  normals (x, y, z): conic (-c x, -c y, -(1 - c(1+k) s)), asphere (-2 x g, -2 y g, -1) with
  g = dsag/drho, plane (0, 0, 1). Surfaces with the same index on both sides do not refract.
Indices per medium come from spectral.media_osl (the glass law at the ray's wavelength, or
d-line constants). Each surface is emitted as one call with literal constants (the OSL
optimizer folds them, e.g. A = c for a sphere), in the order of the constant table printed in
the shader's header; a dropped ray returns with black throughput.
"""

from __future__ import annotations

import math

from ..core.aperture import stop_radius_for_f_number
from ..core.paraxial import paraxial_data
from .frame import assemble
from .oslfmt import flt
from .pupil_table import build_pupil_table, pupil_osl
from .spectral import media_osl
from .stop_shape import embedded_aperture, inside_osl

#: a ray may start this far behind the next surface (float32 positions ~1e-5 mm apart)
BACKWARD_TOLERANCE_MM = 1e-4
ASPHERE_MAX_ITERATIONS = 16
#: spheres up to this |radius| are intersected in the centre form (no division; its float32
#: error grows like 1e-7 |R| mm), flatter ones with the cancellation-free quadratic
SPHERE_CENTRE_FORM_MAX_MM = 200.0
ASPHERE_STEP_TOLERANCE_MM = 1e-6
ASPHERE_RESIDUAL_MM = 1e-4

COMMON_FUNCTIONS = f"""
// Snell's law with a unit normal n (spheres), oriented here against the ray.
// 0 on total internal reflection.
int nl_refract_unit(output vector d, vector n, float eta)
{{
    vector m = n;
    float cosi = -dot(m, d);
    if (cosi < 0.0) {{ cosi = -cosi; m = -m; }}
    float k = 1.0 - eta * eta * (1.0 - cosi * cosi);
    if (k < 0.0) return 0;
    d = eta * d + (eta * cosi - sqrt(k)) * m;
    return 1;
}}

// Snell's law with any normal n (aspheres, planes).
int nl_refract(output vector d, vector n, float eta)
{{
    return nl_refract_unit(d, normalize(n), eta);
}}

// Nearest forward root of the conic through the vertex z_v (local s = z_v - z); 0 if none.
int nl_conic_root(point p, vector d, float zv, float c, float ck, output float t)
{{
    float s0 = zv - p[2];
    float ds = -d[2];
    float a = c + (ck - c) * ds * ds;
    float b = c * (p[0] * d[0] + p[1] * d[1]) + (ck * s0 - 1.0) * ds;
    float cc = c * (p[0] * p[0] + p[1] * p[1]) + (ck * s0 - 2.0) * s0;
    float disc = b * b - a * cc;
    if (disc < 0.0) return 0;
    float q = b >= 0.0 ? -(b + sqrt(disc)) : -(b - sqrt(disc));
    if (q == 0.0) return 0;
    float t2 = cc / q;
    int ok2 = t2 >= {flt(-BACKWARD_TOLERANCE_MM)} && 1.0 - ck * (s0 + t2 * ds) > 0.0;
    if (a != 0.0) {{
        float t1 = q / a;
        if (t1 >= {flt(-BACKWARD_TOLERANCE_MM)} && 1.0 - ck * (s0 + t1 * ds) > 0.0
            && (!ok2 || t1 < t2)) {{
            t = t1;
            return 1;
        }}
    }}
    t = t2;
    return ok2;
}}

// Move to a spherical or conic surface; 0 if missed or beyond the semi-diameter.
int nl_conic(output point p, output vector d, float zv, float c, float ck, float sd2)
{{
    float t = 0.0;
    if (!nl_conic_root(p, d, zv, c, ck, t)) return 0;
    p += t * d;
    return p[0] * p[0] + p[1] * p[1] <= sd2;
}}

// Through a sphere (radius R = 1/c, |R| <= SPHERE_CENTRE_FORM_MAX_MM) at z_v: intersect in the
// centre form (oc = p - (0, 0, z_v - R): t = -oc.d -/+ sqrt((oc.d)^2 - |oc|^2 + R^2), no
// division), take the nearer forward root on the cap, clip at the semi-diameter, refract with
// eta. The normal (-c x, -c y, c s - 1) is unit.
int nl_sphere(output point p, output vector d, float zv, float c, float r, float sd2,
              float eta)
{{
    vector oc = vector(p[0], p[1], p[2] - (zv - r));
    float b = dot(oc, d);
    float disc = b * b - (dot(oc, oc) - r * r);
    if (disc < 0.0) return 0;
    float sq = sqrt(disc);
    float t = -b - sq;
    if (!(t >= {flt(-BACKWARD_TOLERANCE_MM)} && 1.0 - c * (zv - p[2] - t * d[2]) > 0.0)) {{
        t = sq - b;
        if (!(t >= {flt(-BACKWARD_TOLERANCE_MM)} && 1.0 - c * (zv - p[2] - t * d[2]) > 0.0))
            return 0;
    }}
    p += t * d;
    if (p[0] * p[0] + p[1] * p[1] > sd2) return 0;
    return nl_refract_unit(d, vector(-c * p[0], -c * p[1], c * (zv - p[2]) - 1.0), eta);
}}

// The same for shallow spheres (|R| large: the centre form would lose float32 precision):
// the conic root without cancellation (nl_conic_root), then refraction.
int nl_sphere_shallow(output point p, output vector d, float zv, float c, float sd2, float eta)
{{
    float t = 0.0;
    if (!nl_conic_root(p, d, zv, c, c, t)) return 0;
    p += t * d;
    if (p[0] * p[0] + p[1] * p[1] > sd2) return 0;
    return nl_refract_unit(d, vector(-c * p[0], -c * p[1], c * (zv - p[2]) - 1.0), eta);
}}

// Move to a plane z = z_v; 0 if behind the ray or beyond the semi-diameter.
int nl_plane(output point p, vector d, float zv, float sd2)
{{
    if (!(d[2] > 0.0)) return 0;
    p += ((zv - p[2]) / d[2]) * d;
    return p[0] * p[0] + p[1] * p[1] <= sd2;
}}
""".strip().splitlines()


def _asphere_function(i: int, surf, zv: float) -> list[str]:
    """A specialised `nl_asphere_i(p, d, g)`: Newton on the sag, g = dsag/drho at the hit."""
    c = surf.curvature
    ck = c * (1.0 + surf.conic)
    coef = {p // 2: a for p, a in surf.aspheric}
    top = max(coef) if coef else 0
    # Horner in rho for sum_h A_h rho^h and its derivative sum_h h A_h rho^(h-1).
    poly = "0.0"
    dpoly = "0.0"
    for h in range(top, 0, -1):
        a = coef.get(h, 0.0)
        poly = f"({poly} + {flt(a)}) * rho" if h < top else f"{flt(a)} * rho"
        dpoly = f"({dpoly}) * rho + {flt(h * a)}" if h < top else flt(h * a)
    terms = ", ".join(f"A{2 * h} {coef[h]:.6g}" for h in sorted(coef))
    return [
        f"// Surface {i + 1}: even asphere (c {c:.6g}, k {surf.conic:g}, {terms}).",
        f"int nl_asphere_{i}(output point p, vector d, float sd2, output float g)",
        "{",
        "    float t = 0.0;",
        f"    if (!nl_conic_root(p, d, {flt(zv)}, {flt(c)}, {flt(ck)}, t)) return 0;",
        f"    float s0 = {flt(zv)} - p[2];",
        "    float ds = -d[2];",
        "    float f = 1.0;",
        f"    for (int it = 0; it < {ASPHERE_MAX_ITERATIONS}; ++it) {{",
        "        float x = p[0] + t * d[0];",
        "        float y = p[1] + t * d[1];",
        "        float rho = x * x + y * y;",
        f"        float arg = 1.0 - {flt(ck * c)} * rho;",
        "        if (arg <= 0.0) return 0;",
        "        float root = sqrt(arg);",
        f"        float sag = {flt(c)} * rho / (1.0 + root) + {poly};",
        f"        g = {flt(0.5 * c)} / root + {dpoly};",
        "        f = s0 + t * ds - sag;",
        "        float fp = ds - 2.0 * g * (x * d[0] + y * d[1]);",
        "        if (fp == 0.0) return 0;",
        "        float step = f / fp;",
        "        t -= step;",
        f"        if (abs(step) < {flt(ASPHERE_STEP_TOLERANCE_MM)}) break;",
        "    }",
        f"    if (!(t >= {flt(-BACKWARD_TOLERANCE_MM)})) return 0;",
        "    p += t * d;",
        "    float rho = p[0] * p[0] + p[1] * p[1];",
        f"    float arg = 1.0 - {flt(ck * c)} * rho;",
        "    if (arg <= 0.0) return 0;",
        "    float root = sqrt(arg);",
        f"    float sag = {flt(c)} * rho / (1.0 + root) + {poly};",
        f"    g = {flt(0.5 * c)} / root + {dpoly};",
        f"    if (abs(s0 + t * ds - sag) > {flt(ASPHERE_RESIDUAL_MM)}) return 0;",
        "    return rho <= sd2;",
        "}",
    ]


def _eta(n_before: str, n_after: str) -> str | None:
    """OSL operand for n_before / n_after, or None where the two media are the same."""
    if n_before == n_after:
        return None
    try:
        return flt(float(n_before) / float(n_after))
    except ValueError:
        return f"{n_before} / {n_after}"


def stop_radius(spec) -> float:
    """The stop radius (mm) for the spec's f-number (the design's when None)."""
    lens = spec.lens
    if spec.f_number is None:
        return float(lens.stop_radius_mm)
    return stop_radius_for_f_number(lens.stop_radius_mm, lens.f_number, spec.f_number)


def surface_table(lens) -> list[str]:
    """Header rows: the constants of every surface, front to back, as emitted."""
    rows = ["surfaces, front to back (z_v mm, c 1/mm, c(1+k), semi-diameter mm, kind):"]
    for i, (s, z) in enumerate(zip(lens.surfaces, lens.vertex_z)):
        kind = "stop" if s.stop else ("asphere" if s.aspheric else
                                      "plane" if s.is_flat else
                                      "conic" if s.conic else "sphere")
        rows.append(f"  {i + 1:2d}  z {z:10.5f}  c {s.curvature:12.8f}  "
                    f"ck {s.curvature * (1 + s.conic):12.8f}  sd {s.semi_diameter_mm:8.4f}  "
                    f"{kind}  {s.material.name}")
    return rows


def trace_lines(spec, R: float) -> tuple[list[str], list[str]]:
    """(functions, body) tracing every surface, sensor side first, on `point p`, `vector d`
    (declared by the caller); the body returns (drops the ray) where the trace fails."""
    lens = spec.lens
    decls, n = media_osl(lens, spec.dispersion)
    functions, body = [], list(decls)
    zs = lens.vertex_z
    for i in range(len(lens.surfaces) - 1, -1, -1):
        s = lens.surfaces[i]
        zv = float(zs[i])
        sd2 = flt(s.semi_diameter_mm ** 2)
        eta = _eta(n[i + 1], n[i])      # travelling towards the scene: media[i+1] -> media[i]
        c, ck = s.curvature, s.curvature * (1.0 + s.conic)
        body.append(f"// surface {i + 1}" + (" (stop)" if s.stop else ""))
        if s.aspheric:
            functions += _asphere_function(i, s, zv) + [""]
            body += [f"float g{i} = 0.0;",
                     f"if (!nl_asphere_{i}(p, d, {sd2}, g{i})) return;"]
            normal = f"vector(-2.0 * p[0] * g{i}, -2.0 * p[1] * g{i}, -1.0)"
        elif s.is_flat:
            body.append(f"if (!nl_plane(p, d, {flt(zv)}, {sd2})) return;")
            normal = "vector(0.0, 0.0, 1.0)"
        elif s.conic == 0.0 and eta is not None and not s.stop:
            if abs(s.radius_mm) <= SPHERE_CENTRE_FORM_MAX_MM:
                body.append(f"if (!nl_sphere(p, d, {flt(zv)}, {flt(c)}, {flt(s.radius_mm)}, "
                            f"{sd2}, {eta})) return;")
            else:
                body.append(f"if (!nl_sphere_shallow(p, d, {flt(zv)}, {flt(c)}, {sd2}, "
                            f"{eta})) return;")
            continue
        else:
            body.append(f"if (!nl_conic(p, d, {flt(zv)}, {flt(c)}, {flt(ck)}, {sd2})) return;")
            normal = (f"vector({flt(-c)} * p[0], {flt(-c)} * p[1], "
                      f"{flt(ck)} * ({flt(zv)} - p[2]) - 1.0)")
        if s.stop:
            body.append(f"if (!nl_inside_stop(p[0] * {flt(1.0 / R)}, p[1] * {flt(1.0 / R)})) "
                        f"return;")
        if eta is not None:
            body.append(f"if (!nl_refract(d, {normal}, {eta})) return;")
    return functions, body


def generate_exact(spec) -> str:
    lens = spec.lens
    R = stop_radius(spec)
    aperture = embedded_aperture(spec.aperture)
    table = build_pupil_table(lens, spec.sensor_z_mm, spec.film_radius_mm, R, aperture)
    functions = COMMON_FUNCTIONS + [""] + inside_osl(aperture) + [""] + pupil_osl(table) + [""]
    fn, trace = trace_lines(spec, R)
    functions += fn
    body = [
        "// pupil-aware direction from the sensor point, and its irradiance weight",
        "vector d = vector(0.0, 0.0, 1.0);",
        "if (!nl_pupil_sample(sx, sy, u1, u2, d, lw)) return;",
        f"point p = point(sx, sy, {flt(spec.sensor_z_mm)});",
    ] + trace + ["lp = p;", "ld = d;"]
    efl = paraxial_data(lens).efl_mm
    header = [f"NeuroLens exact lens: {lens.name} (content hash {lens.content_hash()})",
              f"source: {lens.source}",
              (f"stop radius {R:.6g} mm (f/{(spec.f_number or lens.f_number):g}), aperture "
              f"{aperture!r}, sensor z {spec.sensor_z_mm:.6g} mm, film "
              f"{spec.sensor_width_mm:g} x {spec.sensor_height_mm:g} mm, dispersion "
              f"{'on' if spec.dispersion else 'off'}")] + surface_table(lens)
    return assemble(spec, header, functions, body, origin_z_mm=spec.sensor_z_mm,
                    focal_mm=abs(efl) if math.isfinite(efl) and efl != 0 else 50.0)
