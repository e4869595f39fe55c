"""OSL for ghosts in the exact and learned cameras: the engine's estimator
(engine/camera_rays.py) in the shader.

A camera sample is a ghost sample when xi_g = hashnoise(u1, u2, raster, SEED) < s (the share:
a hash of the aperture sample and the raster position, as the wavelength's, since Cycles draws
the aperture sample from a table every pixel shares); it picks ghost g by a second hash
against the cumulative probabilities p_g, aims at the point
(r cos phi, r sin phi) of core.pupil.rear_disc with r = R sqrt(u1), phi = 2 pi u2 (weight
cos^4 / dz^2 * pi R^2), and follows the ghost's path (core.ghost_path.ghost_steps) surface by
surface: each surface's own intersection OSL (core.surfaces), the stop's shape wherever the
path crosses it, and at every surface between different media the coating's reflectance R
(nl_reflectance: the same formulas as core.coatings, in float32) multiplying the weight by R
where the path reflects (d' = reflect(d, N)) and by 1 - R where it refracts. The sample's
weight is that times k / (s T_0 p_g) (core.ghosts.GhostPlan) over E_0, the derived camera's
centre irradiance; an image sample keeps its weight times kappa / (1 - s). The exact and the
learned cameras render them (the ghost paths are exact either way), still cameras only.
"""

from __future__ import annotations

import math

from ..core.coatings import AIR_MAX_INDEX
from ..core.ghost_path import ghost_steps
from ..core.oslfmt import float_array, flt, indent
from .lens_osl import common_functions
from .pupil_osl import rear_disc_osl
from .shader_range import shader_semi_diameter_sq
from .spectral import media_osl

#: hashnoise seeds: ghost or image, and which ghost
SEED_CHOICE = 0.3183098862
SEED_GHOST = 0.4142135624


def reflectance_osl(coating) -> list[str]:
    """`float nl_reflectance(n0, ns, cos_i, lambda_nm)`: core.coatings.Coating.reflectance."""
    head = [
        f"// Surface reflectance (core.coatings, {coating.kind}): unpolarised, 0 between equal",
        "// indices, 1 past the critical angle, bare Fresnel between two glasses.",
        "float nl_fresnel(float n0, float ns, float ci)",
        "{",
        "    float s2 = (n0 / ns) * (n0 / ns) * max(1.0 - ci * ci, 0.0);",
        "    if (s2 >= 1.0) return 1.0;",
        "    float ct = sqrt(1.0 - s2);",
        "    float rs = (n0 * ci - ns * ct) / (n0 * ci + ns * ct);",
        "    float rp = (ns * ci - n0 * ct) / (ns * ci + n0 * ct);",
        "    return 0.5 * (rs * rs + rp * rp);",
        "}",
        "",
    ]
    if coating.kind == "bare":
        body = ["    return nl_fresnel(n0, ns, ci);"]
        return head + _wrap(body)
    if coating.kind == "table":
        lam = float_array("NL_COAT_NM", coating.table_nm)
        r = float_array("NL_COAT_R", coating.table_r)
        m = len(coating.table_nm)
        body = indent(lam + r) + [
            "    float s2 = (n0 / ns) * (n0 / ns) * max(1.0 - ci * ci, 0.0);",
            "    if (s2 >= 1.0) return 1.0;",
            "    if (lambda_nm <= NL_COAT_NM[0]) return NL_COAT_R[0];",
            f"    for (int i = 1; i < {m}; ++i)",
            "        if (lambda_nm <= NL_COAT_NM[i]) {",
            "            float t = (lambda_nm - NL_COAT_NM[i - 1]) / "
            "(NL_COAT_NM[i] - NL_COAT_NM[i - 1]);",
            "            return mix(NL_COAT_R[i - 1], NL_COAT_R[i], t);",
            "        }",
            f"    return NL_COAT_R[{m - 1}];",
        ]
        return head + _wrap(body)
    layers = ((coating.film_index, coating.film_thickness_nm),) if coating.kind == "single" \
        else tuple(coating.stack)
    return head + _stack_function(layers) + [""] + _wrap([
        "    if (n0 <= ns) return nl_stack(n0, ns, ci, lambda_nm, 0);",
        "    return nl_stack(n0, ns, ci, lambda_nm, 1);"])


def _wrap(body: list[str]) -> list[str]:
    return [
        "float nl_reflectance(float n0, float ns, float ci, float lambda_nm)",
        "{",
        "    if (n0 == ns) return 0.0;",
        f"    if (n0 > {flt(AIR_MAX_INDEX)} && ns > {flt(AIR_MAX_INDEX)}) "
        "return nl_fresnel(n0, ns, ci);",
    ] + body + ["}"]


def _stack_function(layers) -> list[str]:
    """`nl_stack(n0, ns, ci, lambda, reversed)`: the characteristic-matrix product (complex
    numbers as pairs of floats), layers from the n0 side, reversed seen from the glass."""
    k = len(layers)
    out = float_array("NL_LAYER_N", [n for n, _d in layers]) + \
        float_array("NL_LAYER_D", [d for _n, d in layers])
    return [
        "float nl_stack(float n0, float ns, float ci, float lambda_nm, int rev)",
        "{",
    ] + indent(out) + [
        "    float s2 = (n0 / ns) * (n0 / ns) * max(1.0 - ci * ci, 0.0);",
        "    if (s2 >= 1.0) return 1.0;",
        "    float cs = sqrt(1.0 - s2);",
        "    float sin0 = sqrt(max(1.0 - ci * ci, 0.0));",
        "    float total = 0.0;",
        "    for (int pol = 0; pol < 2; ++pol) {",
        "        // [B, C] = M_1 ... M_k [1, eta_s], from the substrate outwards",
        "        float br = 1.0, bi = 0.0;",
        "        float es = pol == 0 ? ns * cs : ns / max(cs, 1e-12);",
        "        float cr = es, cim = 0.0;",
        f"        for (int j = {k - 1}; j >= 0; --j) {{",
        f"            int l = rev ? {k - 1} - j : j;",
        "            float n1 = NL_LAYER_N[l];",
        "            float sl = n0 * sin0 / n1;",
        "            float c1 = sqrt(max(1.0 - sl * sl, 0.0));",
        "            float e1 = pol == 0 ? n1 * c1 : n1 / max(c1, 1e-12);",
        f"            float dl = {flt(2.0 * math.pi)} * n1 * NL_LAYER_D[l] * c1 / lambda_nm;",
        "            float cd = cos(dl), sd = sin(dl);",
        "            // B' = cd B + i sd C / e1,  C' = i e1 sd B + cd C",
        "            float nbr = cd * br - sd * cim / e1;",
        "            float nbi = cd * bi + sd * cr / e1;",
        "            float ncr = cd * cr - e1 * sd * bi;",
        "            float nci = cd * cim + e1 * sd * br;",
        "            br = nbr; bi = nbi; cr = ncr; cim = nci;",
        "        }",
        "        float e0 = pol == 0 ? n0 * ci : n0 / max(ci, 1e-12);",
        "        float ar = e0 * br - cr, ai = e0 * bi - cim;",
        "        float dr = e0 * br + cr, di = e0 * bi + cim;",
        "        total += 0.5 * (ar * ar + ai * ai) / max(dr * dr + di * di, 1e-30);",
        "    }",
        "    return min(total, 1.0);",
        "}",
    ]


def ghost_branch(spec, plan, n, inv_stop_radius: str, sensor_z: str,
                 inv_centre: str, existing: str = "") -> tuple[list[str], list[str]]:
    """(functions, body lines) of the ghost branch: sets `point p`, `vector d`, `float lw`
    (declared by the caller) or returns. n: the media operands (spectral.media_osl);
    existing: the shader's functions so far (a surface function already there is not
    repeated)."""
    lens = spec.lens
    functions, seen = [], set()
    cdf = [0.0]
    for p in plan.probability:
        cdf.append(cdf[-1] + p)
    xi = (flt(spec.probe_sample[3]) if spec.probe is not None and len(spec.probe_sample) == 4
          else f"hashnoise(point(u1, u2, raster[0]), raster[1] + {flt(SEED_GHOST)})")
    body = [
        "// a ghost: which one, and a direction over the rear element's disc",
        f"float xi_ghost = {xi};",
        "int ghost = 0;",
    ]
    for k in range(1, len(plan.ghosts)):
        body.append(f"if (xi_ghost >= {flt(cdf[k])}) ghost = {k};")
    body += rear_disc_osl(lens, sensor_z) + [f"p = point(sx, sy, {sensor_z});",
                                             "float g_w = 1.0;"]
    for k, g in enumerate(plan.ghosts):
        order, pairs, refl = ghost_steps(len(lens.surfaces), g)
        body.append(f"{'if' if k == 0 else 'else if'} (ghost == {k}) {{")
        lines = [f"// ghost {g} (reflected at surfaces {g.a + 1} and {g.b + 1})"]
        for i, (m0, m1), reflect in zip(order, pairs, refl):
            s = lens.surfaces[i]
            zv = float(lens.vertex_z[i])
            sd2 = flt(shader_semi_diameter_sq(s.semi_diameter_mm))
            fn, hit, normal = s.shape.osl_hit(i, zv, sd2)
            key = "\n".join(fn)
            if fn and key not in seen and key not in existing:
                seen.add(key)
                functions += fn
            step = list(hit)
            if s.stop:
                step.append(f"if (!nl_inside_stop(p[0] * {inv_stop_radius}, "
                            f"p[1] * {inv_stop_radius})) return;")
            if n[m0] != n[m1]:
                step += [
                    f"vector g_n = normalize({normal});",
                    "float g_ci = abs(dot(g_n, d));",
                    f"float g_R = nl_reflectance({n[m0]}, {n[m1]}, g_ci, lambda_nm);",
                ]
                if reflect:
                    step += ["g_w *= g_R;", "d = reflect(d, g_n);"]
                else:
                    step += ["g_w *= 1.0 - g_R;",
                             f"if (!nl_refract_unit(d, g_n, {n[m0]} / {n[m1]})) return;"]
            elif reflect:                    # (never on a ghost's path: equal media)
                step.append("return;")
            # a block per step: a surface crossed twice declares its locals twice
            lines += ["{"] + indent(step) + ["}"]
        body += indent(lines) + ["}"]
    body += [
        "if (!(d[2] > 0.0)) return;",
        f"lw *= g_w * {inv_centre};",
    ]
    probs = float_array("NL_GHOST_P", plan.probability)
    body += indent(probs, 0) + [
        f"lw *= {flt(plan.ghost_factor)} / NL_GHOST_P[ghost];",
    ]
    return functions, body


def with_ghosts(spec, state, functions: list[str], image_body: list[str]):
    """(functions, body): the camera's body split between the ghost branch and the image's
    (module docstring), for the exact and the learned camera alike (the ghost paths are
    always traced exactly: the media, refraction and surface functions are added when the
    image's own body has none)."""
    plan = spec.ghosts
    decls, n = media_osl(spec.lens, spec.dispersion)
    image = [ln for ln in image_body if ln not in decls]
    have = "\n".join(functions)
    extra = [] if "nl_refract_unit" in have else common_functions(spec.lens) + [""]
    g_fn, g_body = ghost_branch(spec, plan, n, state.inv_stop_radius, state.sensor_z,
                                state.inv_centre, existing=have)
    choice = (flt(spec.probe_sample[2]) if spec.probe is not None
              and len(spec.probe_sample) == 4
              else f"hashnoise(point(u1, u2, raster[0]), raster[1] + {flt(SEED_CHOICE)})")
    functions = functions + [""] + extra + reflectance_osl(plan.coating) + [""] + g_fn
    body = list(decls) + [
        "// ghost or image: a share of the samples follows the ghosts (cycles.ghosts)",
        f"float xi_choice = {choice};",
        f"if (xi_choice < {flt(plan.share)}) {{",
        "    point p = point(0.0);",
        "    vector d = vector(0.0, 0.0, 1.0);",
    ] + indent(g_body) + ["    lp = p;", "    ld = d;", "} else {"] + indent(image) + [
        f"    lw *= {flt(plan.image_factor)};", "}"]
    return functions, body
