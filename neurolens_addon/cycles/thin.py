"""OSL for the ideal thin lens: Blender's own perspective camera with our aperture shapes.

Cycles' perspective camera (camera_sample_perspective) in lens millimetres: the pinhole
direction of the image point is D_0 = (X, Y, f) with (X, Y) = (r - 0.5) (W, H) (upright: the
film mirror is undone), the plane in focus lies at z = u (the focus distance), and a ray leaves
the lens point P = (R a_x, R a_y, 0), R = f / (2 N), (a_x, a_y) a point of the unit aperture
shape, towards the focus point D_0 u / f:
    D = normalize(D_0 u / f - P)        (u = inf: D = D_0),
with weight 1 (a thin lens has no vignetting). The lens sits at the camera origin and the field
of view is the focal length's, as in Blender (no focus breathing), so with a circular aperture
and the same random numbers this camera reproduces Blender's perspective camera ray for ray.
"""

from __future__ import annotations

import math

from ..core.paraxial import paraxial_data
from .frame import assemble
from ..core.oslfmt import flt
from ..core.aperture import shader_shape
from .stop_shape import inside_osl, sample_osl


def thin_focal_mm(spec) -> float:
    if spec.focal_mm is not None:
        return float(spec.focal_mm)
    return float(paraxial_data(spec.lens).efl_mm)


def generate_thin(spec) -> str:
    f = thin_focal_mm(spec)
    aperture = shader_shape(spec.aperture)
    radius = f / (2.0 * float(spec.f_number))
    u_mm = float(spec.focus_distance_m) * 1000.0
    functions = inside_osl(aperture) + [""] + sample_osl(aperture) + [""]
    body = ["// a point of the aperture shape on the lens plane (camera origin)",
            "float ax = 0.0;",
            "float ay = 0.0;",
            "nl_sample_aperture(u1, u2, ax, ay, lw);",
            f"lp = point({flt(radius)} * ax, {flt(radius)} * ay, 0.0);",
            "// towards the image point's focus point (pinhole direction, upright)",
            f"vector pinhole = vector(-sx, -sy, {flt(f)});"]
    if math.isinf(u_mm):
        body.append("ld = normalize(pinhole);")
    else:
        body.append(f"ld = normalize(pinhole * {flt(u_mm / f)} - vector(lp));")
    header = [(f"NeuroLens thin lens (Blender's model): f {f:.6g} mm, f/{float(spec.f_number):g}, "
              f"focus {spec.focus_distance_m:g} m, aperture {aperture!r}"),
              f"film {spec.sensor_width_mm:g} x {spec.sensor_height_mm:g} mm"]
    return assemble(spec, header, functions, body, origin_z=0.0, focal_mm=f)
