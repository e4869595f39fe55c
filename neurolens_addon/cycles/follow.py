"""Where the sensor sits and how wide the stop is, per frame: baked, or read from Blender.

A still camera bakes its sensor plane z_s, stop radius R and on-axis normalisation W into the
shader as constants. A camera whose focus or f-number is animated (`CameraSpec.follow`) reads
Blender's own values every frame instead, so a saved .blend renders its focus pull and its
f-number ramp on a machine without the add-on (the add-on's frame handler is not needed):

  focus     d = cam:focal_distance (scene units; Blender's Depth of Field focus distance, or
            its focus object's distance) times mm per unit, measured from the sensor;
            t = 1 / d is clamped to the baked range [1 / d_far, 1 / d_near] and
            z_s = the table of core.focus's sensor positions at K points uniform in t,
            interpolated linearly (z_s is smooth in 1 / d: Newton's lens equation);
  f-number  N = 0.5 / cam:aperture_size (Cycles passes 0.5 / N for a custom camera with Depth
            of Field on), clamped to the baked range [N_lo, N_hi]; R = R_d N_d / N
            (core.aperture.stop_radius_for_f_number);
  exposure  W(z_s, N): the mean weight of the rays that pass from the image centre
            (pupil_table.centre_weight), tabulated as log W at the K focus points and M
            f-numbers spaced evenly in log N and interpolated bilinearly (W ~ N^-2 is then
            exact between points, where interpolating W itself was 6 % off at f/2 to f/8);
            the throughput is divided by it,
            so the centre keeps throughput 1 in every frame, as a still camera's does.
The pupil slabs are built at the widest f-number from the sensor planes at both ends and the
middle of the focus range together, so they hold the passing rays of every frame (tested
between the tabulated planes). With Depth of Field off Cycles passes no values
(aperture 0): the shader then renders the far end of the focus range and the widest f-number,
which is why the add-on turns Depth of Field on for such a camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.aperture import stop_radius_for_f_number
from ..core.focus import focus_sensor_z
from ..core.oslfmt import float_array, flt
from .pupil_table import aperture_key, build_pupil_table, centre_weight, pupil_osl

#: focus points (uniform in 1 / distance) and f-numbers (uniform in log N) of the tables
FOCUS_POINTS = 17
F_NUMBER_POINTS = 5
#: sensor planes the pupil slabs are traced from (ends and middle of the focus range): the
#: passing region moves smoothly with the sensor, and the slabs' half-cell margin holds it
SLAB_PLANES = 3


@dataclass(frozen=True)
class LensState:
    """What the lens shaders need: the pupil table, its OSL, body lines that set `d` and `lw`
    (and return for a ray that misses every slab), and OSL operands for z_s and 1 / R."""

    table: object
    functions: list
    lines: list
    sensor_z: str
    inv_stop_radius: str
    describe: str


def _focus_points(spec) -> tuple[np.ndarray, np.ndarray]:
    """(t = 1 / d (1/mm), z_s (mm)) at FOCUS_POINTS spaced evenly in t over the range."""
    near, far = spec.follow.focus_mm
    t = np.linspace(1.0 / far if math.isfinite(far) else 0.0, 1.0 / near, FOCUS_POINTS)
    z = np.array([focus_sensor_z(spec.lens, 1.0 / x if x > 0 else math.inf) for x in t])
    return t, z


def _f_number_points(spec) -> np.ndarray:
    lo, hi = spec.follow.f_numbers
    return np.exp(np.linspace(math.log(lo), math.log(hi), F_NUMBER_POINTS))


def lens_state(spec, aperture, stop_radius: float) -> LensState:
    """The still camera's constants, or the following camera's tables and reads."""
    lens = spec.lens
    if spec.follow is None:
        table = build_pupil_table(lens, spec.sensor_z_mm, spec.film_radius_mm, stop_radius,
                                  aperture)
        lines = ["// pupil-aware direction from the sensor point, and its irradiance weight",
                 "vector d = vector(0.0, 0.0, 1.0);",
                 "if (!nl_pupil_sample(sx, sy, u1, u2, d, lw)) return;"]
        describe = (f"stop radius {stop_radius:.6g} mm (f/{(spec.f_number or lens.f_number):g}),"
                    f" sensor z {spec.sensor_z_mm:.6g} mm")
        return LensState(table, pupil_osl(table), lines, flt(spec.sensor_z_mm),
                         flt(1.0 / stop_radius), describe)
    key = (lens, spec.follow, round(spec.film_radius_mm, 9), aperture_key(aperture),
           round(spec.mm_to_units, 15))
    hit = _STATES.get(key)
    if hit is None:
        hit = _following_state(spec, aperture)
        if len(_STATES) >= 8:
            _STATES.pop(next(iter(_STATES)))
        _STATES[key] = hit
    return hit


#: following states by value: a camera re-synced every frame builds its tables once
_STATES: dict = {}


def _following_state(spec, aperture) -> LensState:
    lens = spec.lens
    t, z = _focus_points(spec)
    n = _f_number_points(spec)
    r_d, n_d = float(lens.stop_radius_mm), float(lens.f_number)
    radii = [stop_radius_for_f_number(r_d, n_d, x) for x in n]
    planes = z[np.round(np.linspace(0, len(z) - 1, SLAB_PLANES)).astype(int)]
    table = build_pupil_table(lens, float(z[0]), spec.film_radius_mm, radii[0], aperture,
                              also_sensor_z=tuple(float(v) for v in planes[1:]))
    log_norm = np.array([[-math.log(centre_weight(table, lens, float(zk), rm, aperture))
                          for rm in radii] for zk in z])
    k, m = FOCUS_POINTS, F_NUMBER_POINTS
    log_span = math.log(n[-1] / n[0])
    tables = float_array("NL_FOCUS_Z", z, f"sensor z (mm) at 1/d from {t[0]:.6g} to "
                                          f"{t[-1]:.6g} 1/mm, {k} points")
    tables += float_array("NL_LOG_NORM", log_norm, f"log(1 / centre weight), {k} focus points "
                                                   f"x {m} f-numbers from f/{n[0]:g} to "
                                                   f"f/{n[-1]:g}")
    dt = (t[-1] - t[0]) / (k - 1)
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
        "float nl_z = mix(NL_FOCUS_Z[nl_i], NL_FOCUS_Z[nl_i + 1], nl_g);",
        (f"float nl_y = log(nl_N / {flt(n[0])}) * {flt((m - 1) / log_span)};" if log_span > 0
         else "float nl_y = 0.0;"),
        f"int nl_j = clamp((int)nl_y, 0, {m - 2});",
        "float nl_h = clamp(nl_y - nl_j, 0.0, 1.0);",
        f"float nl_e0 = mix(NL_LOG_NORM[nl_i * {m} + nl_j], NL_LOG_NORM[nl_i * {m} + nl_j + 1], "
        "nl_h);",
        f"float nl_e1 = mix(NL_LOG_NORM[(nl_i + 1) * {m} + nl_j], "
        f"NL_LOG_NORM[(nl_i + 1) * {m} + nl_j + 1], nl_h);",
        f"float nl_inv_R = nl_N * {flt(1.0 / (r_d * n_d))};",
        "// pupil-aware direction from the sensor point, and its irradiance weight",
        "vector d = vector(0.0, 0.0, 1.0);",
        "if (!nl_pupil_sample(sx, sy, nl_z, u1, u2, d, lw)) return;",
        "lw *= exp(mix(nl_e0, nl_e1, nl_g));",
    ]
    near, far = spec.follow.focus_mm
    describe = (f"follows Blender's focus ({near / 1000.0:.6g} to {far / 1000.0:.6g} m) and "
                f"f-number (f/{n[0]:g} to f/{n[-1]:g})")
    return LensState(table, pupil_osl(table, follow=True), lines, "nl_z", "nl_inv_R", describe)
