"""OSL of the camera-ray samplers: the slab pupil and the rear disc (core.pupil_slabs,
core.pupil), written as the derived camera gives them.

`nl_pupil_sample(sx, sy, u1, u2, dir, weight)` aims from the sensor point (sx, sy) at a point
of its band's slabs (core.pupil_slabs: the equations) with the irradiance weight
    cos^4(theta) A_k / dz^2 / E_0,
E_0 the derived camera's centre irradiance (core.pupil.centre_irradiance), so the image centre
has throughput 1 at any f-number, as Blender's cameras do; vignetting and the cos^4 fall-off off
axis stay real. A following camera (cycles.follow) passes its sensor plane,
`nl_pupil_sample(sx, sy, z_s, u1, u2, dir, weight)`, and divides by its own E_0.
The rear disc: a direction to the uniform point (R sqrt(u1), angle 2 pi u2) of
core.pupil.rear_disc with the weight cos^4 / dz^2 * pi R^2 (core.pupil.disc_rays).
"""

from __future__ import annotations

import math

from ..core.oslfmt import float_array, flt, indent
from ..core.pupil import rear_disc


def pupil_osl(table, inv_centre: float | None) -> list[str]:
    """OSL: the slab tables of a core.pupil_slabs.SlabPupil and `nl_pupil_sample`; the weight
    is divided by E_0 (inv_centre = 1 / E_0) for a still camera, or left for the caller
    (inv_centre None: a following camera, whose sensor plane is an argument)."""
    follow = inv_centre is None
    B, S = table.bands, table.slabs
    dz = table.plane_z - table.sensor_z
    tables = float_array("NL_PUPIL_Y", table.y, f"slab edges y_0..y_{S} per band ({B} bands "
                                                f"of sensor radius, mm on the plane z = "
                                                f"{table.plane_z:.6g})")
    tables += float_array("NL_PUPIL_X0", table.x_lo, "slab x extent, low (mm)")
    tables += float_array("NL_PUPIL_X1", table.x_hi, "slab x extent, high (mm)")
    return [
        "// Direction from the sensor point (sx, sy) to a point of its band's slabs, and the",
        "// irradiance weight cos^4(theta) A_k / dz^2 (over E_0: 1 at the image centre).",
        ("int nl_pupil_sample(float sx, float sy, float z_s, float u1, float u2, output vector dir,"
         if follow else
         "int nl_pupil_sample(float sx, float sy, float u1, float u2, output vector dir,"),
        "                    output float weight)",
        "{",
    ] + indent(tables) + [
        "    float r = sqrt(sx * sx + sy * sy);",
        f"    int band = min((int)(r * {flt(B / table.film_radius)}), {B - 1});",
        f"    float s = clamp(u2, 0.0, 0.99999994) * {flt(S)};",
        f"    int k = min((int)s, {S - 1});",
        f"    int row = band * {S + 1} + k;",
        "    float ya = NL_PUPIL_Y[row];",
        "    float yb = NL_PUPIL_Y[row + 1];",
        "    float xa = NL_PUPIL_X0[row - band];",
        "    float xb = NL_PUPIL_X1[row - band];",
        f"    float area = {flt(S)} * (yb - ya) * (xb - xa);",
        "    if (area <= 0.0) return 0;",
        "    float ly = ya + (s - k) * (yb - ya);",
        "    float lx = xa + u1 * (xb - xa);",
        "    // rotate the band frame (sensor point on +x) to the sensor point's azimuth",
        "    float c = 1.0;",
        "    float sn = 0.0;",
        "    if (r > 0.0) { float inv_r = 1.0 / r; c = sx * inv_r; sn = sy * inv_r; }",
    ] + ([f"    float dz = {flt(table.plane_z)} - z_s;",
          "    vector v = vector(c * lx - sn * ly - sx, sn * lx + c * ly - sy, dz);",
          "    float inv_len = 1.0 / sqrt(dot(v, v));",
          "    dir = v * inv_len;",
          "    float cz2 = dz * dz * inv_len * inv_len;",
          "    weight = area * cz2 * cz2 / (dz * dz);"] if follow else [
        f"    vector v = vector(c * lx - sn * ly - sx, sn * lx + c * ly - sy, {flt(dz)});",
        "    float inv_len = 1.0 / sqrt(dot(v, v));",
        "    dir = v * inv_len;",
        f"    float cz2 = {flt(dz * dz)} * inv_len * inv_len;",
        f"    weight = area * cz2 * cz2 * {flt(inv_centre / (dz * dz))};"]) + [
        "    return 1;",
        "}",
    ]


def rear_disc_osl(lens, sensor_z: str) -> list[str]:
    """OSL setting `vector d` (declared by the caller) from the sensor point (sx, sy) towards a
    uniform point of core.pupil.rear_disc, and `float lw` to its irradiance weight
    (core.pupil.disc_rays in the shader). sensor_z: the sensor plane's operand."""
    z_p, rad = rear_disc(lens)
    return [
        f"float rd_r = {flt(rad)} * sqrt(u1);",
        "float rd_phi = M_2PI * u2;",
        f"float rd_dz = {flt(z_p)} - {sensor_z};",
        "d = normalize(vector(rd_r * cos(rd_phi) - sx, rd_r * sin(rd_phi) - sy, rd_dz));",
        f"lw = d[2] * d[2] * d[2] * d[2] / (rd_dz * rd_dz) * {flt(math.pi * rad * rad)};",
    ]
