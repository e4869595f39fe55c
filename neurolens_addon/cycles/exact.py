"""OSL for the exact lens: core.trace's sequential trace, surface by surface, in float32.

For each camera ray: a sensor point (frame), a direction towards the lens's rear pupil with its
irradiance weight (pupil_table), then every surface from the back (sensor side) to the front:
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
the shader's header; a dropped ray returns with black throughput.
"""

from __future__ import annotations

import math

from ..core.aperture import stop_radius_for_f_number
from ..core.errors import LensError
from ..core.paraxial import paraxial_data
from ..core.surfaces import kind_classes
from .frame import assemble
from ..core.oslfmt import comment_text, flt, indent
from .follow import lens_state
from .spectral import media_osl
from .stop_shape import embedded_aperture, inside_osl

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
        sd2 = flt(s.semi_diameter_mm ** 2)
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


def rear_disc_osl(lens, sensor_z: str) -> list[str]:
    """OSL setting `vector d` (declared by the caller) from the sensor point (sx, sy) towards a
    uniform point (R sqrt(u1), angle 2 pi u2) of core.ghosts.rear_disc, and `float lw` to its
    irradiance weight cos^4 / dz^2 * pi R^2: core.ghosts.disc_rays in the shader. sensor_z:
    the sensor plane's operand."""
    from ..core.ghosts import rear_disc
    z_p, rad = rear_disc(lens)
    return [
        f"float rd_r = {flt(rad)} * sqrt(u1);",
        "float rd_phi = M_2PI * u2;",
        f"float rd_dz = {flt(z_p)} - {sensor_z};",
        "d = normalize(vector(rd_r * cos(rd_phi) - sx, rd_r * sin(rd_phi) - sy, rd_dz));",
        f"lw = d[2] * d[2] * d[2] * d[2] / (rd_dz * rd_dz) * {flt(math.pi * rad * rad)};",
    ]


def disc_state(spec, stop_r: float):
    """The pupil state of an anamorphic lens (the radial pupil table rotates one band to every
    azimuth, which such a lens does not allow): a direction to a uniform point of
    core.ghosts.rear_disc (weight cos^4 / dz^2 * pi R^2, as core.pupil.RearDiscSampler),
    normalised by the mean weight of the rays that pass from the film centre (W_ref, from the
    exact trace of the same sampler)."""
    from types import SimpleNamespace

    import numpy as np

    from ..core.pupil import RearDiscSampler
    from ..core.trace import trace
    from .follow import LensState
    lens = spec.lens
    zs = float(spec.sensor_z_mm)
    sampler = RearDiscSampler(lens, zs)
    rng = np.random.default_rng(17)
    n = 65536
    zero = np.zeros(n)
    smp = sampler.sample(zero, zero, rng.random(n), rng.random(n), None, 587.5618)
    res = trace(lens, smp.rays, from_sensor=True, stop_radius=stop_r, aperture=spec.aperture)
    w_ref = float(np.mean(np.where(res.valid, smp.weight, 0.0)))
    if not w_ref > 0.0:
        raise LensError(f"lens '{lens.name}': no ray from the film centre passes the lens")
    lines = (["// anamorphic lens: a direction to a uniform point of the rear element's disc",
              "vector d = vector(0.0, 0.0, 1.0);"] + rear_disc_osl(lens, flt(zs))
             + [f"lw *= {flt(1.0 / w_ref)};"])
    return LensState(SimpleNamespace(inv_w_ref=1.0 / w_ref), [], lines, flt(zs),
                     flt(1.0 / stop_r), f"stop radius {stop_r:.6g} mm, sensor z {zs:.6g} mm, "
                     f"rear-disc pupil (anamorphic, squeeze {spec.squeeze:.4g})")


def generate_exact(spec) -> str:
    lens = spec.lens
    R = stop_radius(spec)
    aperture = embedded_aperture(spec.aperture)
    state = disc_state(spec, R) if lens.anamorphic else lens_state(spec, aperture, R)
    functions = (common_functions(lens) + [""] + inside_osl(aperture) + [""] + state.functions
                 + [""])
    fn, trace = trace_lines(spec, state.inv_stop_radius)
    functions += fn
    body = state.lines + [
        f"point p = point(sx, sy, {state.sensor_z});",
    ] + trace + ["lp = p;", "ld = d;"]
    if spec.ghosts is not None:
        from .ghosts import with_ghosts
        functions, body = with_ghosts(spec, state, functions, body)
    efl = paraxial_data(lens).efl_mm
    header = [f"NeuroLens exact lens: {lens.name} (content hash {lens.content_hash()})",
              f"source: {lens.source}",
              (f"{state.describe}, aperture {aperture!r}, film "
              f"{spec.sensor_width_mm:g} x {spec.sensor_height_mm:g} mm, dispersion "
              f"{'on' if spec.dispersion else 'off'}")] + surface_table(lens)
    return assemble(spec, header, functions, body, origin_z=state.sensor_z,
                    focal_mm=abs(efl) if math.isfinite(efl) and efl != 0 else 50.0)
