"""Where the sensor sits, how wide the stop is and how the rays are aimed, per frame: baked,
or read from Blender.

A still camera bakes the derived camera's sensor plane z_s, stop radius R and centre
irradiance E_0 (camera.derived) into the shader as constants, with its slab pupil
(core.pupil_slabs), or, for an anamorphic lens, the rear disc (the slab bands rotate one
azimuth to every other, which such a lens does not allow). A camera whose focus or f-number is
animated (`CameraSpec.follow`) reads Blender's own values every frame instead, so a saved
.blend renders its focus pull and its f-number ramp on a machine without the add-on (the
add-on's frame handler is not needed):

  focus     d = cam:focal_distance (scene units; Blender's Depth of Field focus distance, or
            its focus object's distance) times mm per unit, measured from the sensor;
            t = 1 / d is clamped to the range [1 / d_far, 1 / d_near];
  f-number  N = 0.5 / cam:aperture_size (Cycles passes 0.5 / N for a custom camera with Depth
            of Field on), clamped to the range [N_lo, N_hi]; R = R_d N_d / N
            (core.aperture.stop_radius_of);
  tables    z_s(t, N) and log E_0(t, N) from camera.derived.FollowTables (K focus points
            uniform in t, M f-numbers uniform in log N, each point the still camera's values),
            interpolated bilinearly (z_s is smooth in 1 / d: Newton's lens equation; log E_0
            makes E_0 ~ N^-2 exact between points); the throughput is divided by E_0, so the
            centre keeps throughput 1 in every frame, as a still camera's does.
The slabs are built at the widest f-number from sensor planes spread over the range
(FollowTables.slab_planes), so they hold the passing rays of every frame. With Depth of Field
off Cycles passes no values (aperture 0): the shader then renders the far end of the focus range
and the widest f-number, which is why the add-on turns Depth of Field on for such a camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..core.oslfmt import float_array, flt
from .pupil_osl import pupil_osl, rear_disc_osl


@dataclass(frozen=True)
class LensState:
    """What the lens shaders need: the sampler's OSL functions, body lines that set `d` and
    `lw` (and return for a ray that misses every slab), OSL operands for z_s and 1 / R, the
    operand of 1 / E_0 (ghost samples are normalised alike), a header description and the
    slab pupil written (None for the rear disc)."""

    functions: list
    lines: list
    sensor_z: str
    inv_stop_radius: str
    inv_centre: str
    describe: str
    table: object = None


def lens_state(spec) -> LensState:
    """The still camera's constants (slab pupil or rear disc), or the following camera's
    tables and reads."""
    if spec.follow is not None:
        return _following_state(spec)
    z, r, e0 = float(spec.sensor_z_mm), spec.stop_radius, spec.normalisation
    describe = (f"stop radius {r:.9g} mm (f/{(spec.f_number or spec.lens.f_number):g}), "
                f"sensor z {z:.9g} mm, centre irradiance {e0:.9g}")
    if spec.lens.anamorphic:
        lines = (["// anamorphic lens: a direction to a uniform point of the rear element's disc",
                  "vector d = vector(0.0, 0.0, 1.0);"] + rear_disc_osl(spec.lens, flt(z))
                 + [f"lw *= {flt(1.0 / e0)};"])
        return LensState([], lines, flt(z), flt(1.0 / r), flt(1.0 / e0),
                         describe + f", rear-disc pupil (anamorphic, squeeze "
                                    f"{spec.squeeze:.4g})")
    table = spec.slabs
    lines = ["// pupil-aware direction from the sensor point, and its irradiance weight",
             "vector d = vector(0.0, 0.0, 1.0);",
             "if (!nl_pupil_sample(sx, sy, u1, u2, d, lw)) return;"]
    return LensState(pupil_osl(table, 1.0 / e0), lines, flt(z), flt(1.0 / r), flt(1.0 / e0),
                     describe, table)


def _following_state(spec) -> LensState:
    tab = spec.tables
    t, n = tab.t, tab.f_numbers
    k, m = len(t), len(n)
    table = spec.slabs
    log_span = math.log(n[-1] / n[0])
    tables = float_array("NL_FOCUS_Z", tab.sensor_z, f"sensor z (mm), {k} focus points at 1/d "
                                                     f"from {t[0]:.6g} to {t[-1]:.6g} 1/mm x "
                                                     f"{m} f-numbers")
    tables += float_array("NL_LOG_NORM", -tab.log_centre,
                          f"log(1 / centre irradiance), {k} focus points x {m} f-numbers from "
                          f"f/{n[0]:g} to f/{n[-1]:g}")
    dt = (t[-1] - t[0]) / (k - 1)
    rn = float(tab.stop_radii[0] * n[0])          # R N, the same at every f-number
    lines = [
        "// focus and f-number: Blender's camera, this frame (module cycles.follow)",
        "float nl_fd = 0.0;",
        "float nl_ap = 0.0;",
        'getattribute("cam:focal_distance", nl_fd);',
        'getattribute("cam:aperture_size", nl_ap);',
        f"float nl_t = {flt(t[0])};",
        f"float nl_N = {flt(n[0])};",
        "if (nl_ap > 0.0) {",
        f"    nl_t = clamp(1.0 / max(nl_fd * {flt(1.0 / spec.mm_to_units)}, 1e-6), "
        f"{flt(t[0])}, {flt(t[-1])});",
        f"    nl_N = clamp(0.5 / nl_ap, {flt(n[0])}, {flt(n[-1])});",
        "}",
    ] + tables + [
        (f"float nl_x = (nl_t - {flt(t[0])}) * {flt(1.0 / dt)};" if dt > 0 else
         "float nl_x = 0.0;"),
        f"int nl_i = clamp((int)nl_x, 0, {k - 2});",
        "float nl_g = clamp(nl_x - nl_i, 0.0, 1.0);",
        (f"float nl_y = log(nl_N / {flt(n[0])}) * {flt((m - 1) / log_span)};" if log_span > 0
         else "float nl_y = 0.0;"),
        f"int nl_j = clamp((int)nl_y, 0, {m - 2});",
        "float nl_h = clamp(nl_y - nl_j, 0.0, 1.0);",
        f"float nl_z0 = mix(NL_FOCUS_Z[nl_i * {m} + nl_j], NL_FOCUS_Z[nl_i * {m} + nl_j + 1], "
        "nl_h);",
        f"float nl_z1 = mix(NL_FOCUS_Z[(nl_i + 1) * {m} + nl_j], "
        f"NL_FOCUS_Z[(nl_i + 1) * {m} + nl_j + 1], nl_h);",
        "float nl_z = mix(nl_z0, nl_z1, nl_g);",
        f"float nl_e0 = mix(NL_LOG_NORM[nl_i * {m} + nl_j], NL_LOG_NORM[nl_i * {m} + nl_j + 1], "
        "nl_h);",
        f"float nl_e1 = mix(NL_LOG_NORM[(nl_i + 1) * {m} + nl_j], "
        f"NL_LOG_NORM[(nl_i + 1) * {m} + nl_j + 1], nl_h);",
        "float nl_inv_E = exp(mix(nl_e0, nl_e1, nl_g));",
        f"float nl_inv_R = nl_N * {flt(1.0 / rn)};",
        "// pupil-aware direction from the sensor point, and its irradiance weight",
        "vector d = vector(0.0, 0.0, 1.0);",
        "if (!nl_pupil_sample(sx, sy, nl_z, u1, u2, d, lw)) return;",
        "lw *= nl_inv_E;",
    ]
    near, far = spec.follow.focus_mm
    describe = (f"follows Blender's focus ({near / 1000.0:.6g} to {far / 1000.0:.6g} m) and "
                f"f-number (f/{n[0]:g} to f/{n[-1]:g})")
    return LensState(pupil_osl(table, None), lines, "nl_z", "nl_inv_R", "nl_inv_E", describe,
                     table)
