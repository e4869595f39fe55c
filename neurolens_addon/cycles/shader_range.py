"""What Cycles' float32 camera can hold: a lens's numbers checked before shader text is written.

Cycles runs OSL in float32 (|x| <= 3.4e38, about seven digits). The exact camera writes, for
each surface, its vertex z, the squared semi-diameter (compared with rho = x^2 + y^2) and the
numbers its kind forms from its parameters (`SurfaceShape.shader_constants`: curvatures,
c (1 + k), c^2 (1 + k), an asphere's coefficients and rim sags). A number beyond float32 would
become infinite in the shader, so such a lens is refused here, naming the surface and the
lens-file field; the NeuroLens engine traces in float64 and renders it.

A semi-diameter only clips: one beyond SEMI_DIAMETER_MAX_MM (a million kilometres) clips no
ray that reaches it through any other surface, so the shader writes min(sd, that)^2 and a
"window" of 1e20 mm renders as it does in the engine.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.errors import LensError

#: the largest magnitude float32 holds, with a margin of ten for the shader's own arithmetic
#: on a constant (a product with a unit vector, a sum of two terms)
FLOAT32_SAFE = float(np.finfo(np.float32).max) / 10.0
#: the smallest positive scale written whose reciprocal the shader also writes (1 / R, 1 / E_0)
FLOAT32_TINY = 1.0 / FLOAT32_SAFE
#: semi-diameters are written no larger than this (mm): min(sd, it)^2 fits float32 with room
SEMI_DIAMETER_MAX_MM = 1e12


def shader_semi_diameter_sq(semi_diameter_mm: float) -> float:
    """The squared semi-diameter the shader clips with (module docstring)."""
    return min(float(semi_diameter_mm), SEMI_DIAMETER_MAX_MM) ** 2


def check_shader_range(lens) -> None:
    """Raise LensError naming the surface and field of the first number of `lens` that the
    float32 shader cannot hold."""
    for i, surface in enumerate(lens.surfaces):
        values = [("thickness", float(surface.thickness_mm))]
        values += surface.shape.shader_constants(min(surface.semi_diameter_mm,
                                                     SEMI_DIAMETER_MAX_MM))
        _check(lens, i, values)
    # each thickness fits, yet their sums (the vertices' z) might not
    for i, z in enumerate(lens.vertex_z):
        _check(lens, i, [("thickness", float(z))])


def _check(lens, index: int, values) -> None:
    for field, value in values:
        if not math.isfinite(value) or abs(value) > FLOAT32_SAFE:
            raise LensError(
                f"{value:.3g} is beyond what Cycles' float32 camera can hold (|x| < "
                f"{FLOAT32_SAFE:.1e}); the NeuroLens engine renders this lens in float64",
                path=lens.path, surface=index + 1, field=field)
