"""OSL of a lens's surfaces: core.trace's sequential trace, surface by surface, in float32.

Every surface from the back (sensor side) to the front:
- intersection and clipping at the semi-diameter (rho > sd^2 drops the ray): OSL from the
  surface's kind (core.surfaces: each kind's equations and functions; the functions of the kinds
  in use are emitted once, in registration order);
- at the stop, the stop shape (stop_shape) at (x, y) / R;
- refraction, Snell in vector form with eta = n_before / n_after and cos_i = -N.d > 0:
      d' = eta d + (eta cos_i - sqrt(1 - eta^2 (1 - cos_i^2))) N,  TIR drops the ray,
  with the kind's normal N at the hit; surfaces with the same index on both sides do not
  refract. A kind may fuse intersection, clipping and refraction into one call (spheres).
Indices per medium come from spectral.media_osl (the glass law at the ray's wavelength, or
d-line constants). Each surface is emitted as one call with literal constants (the OSL
optimizer folds them, e.g. A = c for a sphere), in the order of the constant table printed in
the shader's header; a dropped ray returns with black throughput. The exact camera (exact) and
the ghost paths (ghosts) both use it.
"""

from __future__ import annotations

from ..core.oslfmt import comment_text, flt
from ..core.surfaces import kind_classes
from .shader_range import shader_semi_diameter_sq
from .spectral import media_osl

REFRACT_FUNCTIONS = """
// Snell's law with a unit normal n (spheres), oriented here against the ray.
// 0 on total internal reflection.
int nl_refract_unit(output vector d, vector n, float eta)
{
    vector m = n;
    float cosi = -dot(m, d);
    if (cosi < 0.0) { cosi = -cosi; m = -m; }
    float k = 1.0 - eta * eta * (1.0 - cosi * cosi);
    if (k < 0.0) return 0;
    d = eta * d + (eta * cosi - sqrt(k)) * m;
    return 1;
}

// Snell's law with any normal n (aspheres, planes).
int nl_refract(output vector d, vector n, float eta)
{
    return nl_refract_unit(d, normalize(n), eta);
}
""".strip().splitlines()


def common_functions(lens) -> list[str]:
    """Refraction, then the OSL library of every kind the lens's surfaces are (or extend), in
    registration order."""
    out = list(REFRACT_FUNCTIONS)
    for kind in kind_classes():
        if "osl_library" in vars(kind) and any(isinstance(s.shape, kind) for s in lens.surfaces):
            out += [""] + kind.osl_library()
    return out


def _eta(n_before: str, n_after: str) -> str | None:
    """OSL operand for n_before / n_after, or None where the two media are the same."""
    if n_before == n_after:
        return None
    try:
        return flt(float(n_before) / float(n_after))
    except ValueError:
        return f"{n_before} / {n_after}"


def surface_table(lens) -> list[str]:
    """Header rows: the constants of every surface, front to back, as emitted."""
    rows = ["surfaces, front to back (z_v mm, c 1/mm, c(1+k), semi-diameter mm, kind):"]
    for i, (s, z) in enumerate(zip(lens.surfaces, lens.vertex_z)):
        kind = "stop" if s.stop else s.shape.label
        rows.append(f"  {i + 1:2d}  z {z:10.5f}  c {s.curvature:12.8f}  "
                    f"ck {s.curvature * (1 + s.conic):12.8f}  sd {s.semi_diameter_mm:8.4f}  "
                    f"{kind}  {comment_text(s.material.name)}")
    return rows


def trace_lines(spec, inv_stop_radius: str) -> tuple[list[str], list[str]]:
    """(functions, body) tracing every surface, sensor side first, on `point p`, `vector d`
    (declared by the caller); the body returns (drops the ray) where the trace fails.
    inv_stop_radius: OSL operand for 1 / R (a constant, or the frame's value: follow)."""
    lens = spec.lens
    decls, n = media_osl(lens, spec.dispersion)
    functions, body = [], list(decls)
    zs = lens.vertex_z
    for i in range(len(lens.surfaces) - 1, -1, -1):
        s = lens.surfaces[i]
        zv = float(zs[i])
        sd2 = flt(shader_semi_diameter_sq(s.semi_diameter_mm))
        eta = _eta(n[i + 1], n[i])      # travelling towards the scene: media[i+1] -> media[i]
        body.append(f"// surface {i + 1}" + (" (stop)" if s.stop else ""))
        fused = None if s.stop or eta is None else s.shape.osl_fused(zv, sd2, eta)
        if fused is not None:
            body += fused
            continue
        fn, hit, normal = s.shape.osl_hit(i, zv, sd2)
        functions += fn
        body += hit
        if s.stop:
            body.append(f"if (!nl_inside_stop(p[0] * {inv_stop_radius}, "
                        f"p[1] * {inv_stop_radius})) return;")
        if eta is not None:
            body.append(f"if (!nl_refract(d, {normal}, {eta})) return;")
    return functions, body
