"""OSL for the exact lens: the derived camera's lens traced surface by surface (lens_osl).

For each camera ray: a sensor point (frame), a direction towards the lens's rear pupil with its
irradiance weight over the derived camera's centre irradiance (follow.lens_state: the slab
pupil, or the rear disc for an anamorphic lens), then every surface from the back (sensor side)
to the front (lens_osl.trace_lines), the stop clipped at the derived camera's stop radius; with
ghosts a share of the samples follows them (ghosts).
"""

from __future__ import annotations

import math

from ..core.paraxial import paraxial_data
from .follow import lens_state
from .frame import assemble
from .ghosts import with_ghosts
from .lens_osl import common_functions, surface_table, trace_lines
from ..core.aperture import shader_shape
from .stop_shape import inside_osl


def generate_exact(spec) -> str:
    lens = spec.lens
    aperture = shader_shape(spec.aperture)
    state = lens_state(spec)
    functions = (common_functions(lens) + [""] + inside_osl(aperture) + [""] + state.functions
                 + [""])
    fn, trace = trace_lines(spec, state.inv_stop_radius)
    functions += fn
    body = state.lines + [
        f"point p = point(sx, sy, {state.sensor_z});",
    ] + trace + ["lp = p;", "ld = d;"]
    if spec.ghosts is not None:
        functions, body = with_ghosts(spec, state, functions, body)
    efl = paraxial_data(lens).efl_mm
    header = [f"NeuroLens exact lens: {lens.name} (content hash {lens.content_hash()})",
              f"source: {lens.source}",
              (f"{state.describe}, aperture {aperture!r}, film "
              f"{spec.sensor_width_mm:g} x {spec.sensor_height_mm:g} mm, dispersion "
              f"{'on' if spec.dispersion else 'off'}")] + surface_table(lens)
    return assemble(spec, header, functions, body, origin_z=state.sensor_z,
                    focal_mm=abs(efl) if math.isfinite(efl) and efl != 0 else 50.0)
