"""The imaging regression function's planes and its rotational frame (shared by the trainer
and the learned-lens runtime).

A learned lens maps a ray on the input plane Pi_1 (the plane of the rear vertex, on the sensor
side) to the aperture-stop plane (stage 1), and a ray on the stop plane to the output plane
Pi_2 just in front of the front vertex (stage 2). Sensor focusing is free-space propagation from
the sensor plane z_s to Pi_1:  x_1 = x_s + (z_1 - z_s) u / w. Pi_1 sits at the rear vertex rather
than at the image plane (the paper's choice) because there a ray's (x, y) is nearly where it
meets the rear element: the free-space step x + d u / w, which is not polynomial, stays out of
what the networks learn (the error this saves: docs/measurements.md).
Pi_1 is only a parametrisation of the sensor ray's line; a surface bulging past it is fine.

A rotationally symmetric lens commutes with rotations about the axis, so each stage is learned in
the ray's radial frame: with phi = atan2(y, x), r = |(x, y)|, the rotated direction
    u_r =  cos(phi) u + sin(phi) v,    u_t = -sin(phi) u + cos(phi) v,
the stage sees (r, u_r, u_t, w[, lambda]) and returns (x'_r, x'_t, u'_r, u'_t), rotated back by
+phi; w' = sqrt(1 - u'^2 - v'^2). At r = 0 any phi is consistent (we use phi = 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .prescription import Lens

#: gap between the front vertex and the output plane Pi_2 (mm)
OUTPUT_PLANE_GAP_MM = 1.0


@dataclass(frozen=True)
class IRFPlanes:
    input_z: float
    stop_z: float
    output_z: float

    def as_dict(self) -> dict:
        return {"input_z": self.input_z, "stop_z": self.stop_z, "output_z": self.output_z}


def irf_planes(lens: Lens) -> IRFPlanes:
    stop = lens.surfaces[lens.stop_index]
    if not stop.is_flat:
        raise ValueError(f"lens '{lens.name}': a learned lens needs a flat aperture stop "
                         f"(surface {lens.stop_index + 1} is curved)")
    return IRFPlanes(lens.rear_vertex_z, float(lens.vertex_z[lens.stop_index]),
                     lens.front_vertex_z + OUTPUT_PLANE_GAP_MM)


def propagate_to_z(o: np.ndarray, d: np.ndarray, z: float) -> np.ndarray:
    """Origins moved along their rays to the plane z (rays with d_z = 0, or invalid rays
    carried as zeros, get NaN: callers keep their validity masks)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (z - o[2]) / d[2]
        return np.stack([o[0] + t * d[0], o[1] + t * d[1], np.full_like(o[0], z)])


def to_radial(x, y, u, v):
    """(r, u_r, u_t, cos phi, sin phi) of rays at (x, y) with direction (u, v, .)."""
    r = np.hypot(x, y)
    safe = np.where(r > 0, r, 1.0)
    c = np.where(r > 0, x / safe, 1.0)
    s = np.where(r > 0, y / safe, 0.0)
    return r, c * u + s * v, -s * u + c * v, c, s


def from_radial(xr, xt, ur, ut, c, s):
    """Rotate radial-frame position and direction components back to (x, y, u, v)."""
    return c * xr - s * xt, s * xr + c * xt, c * ur - s * ut, s * ur + c * ut


def unit_w(u, v):
    """w = sqrt(1 - u^2 - v^2), NaN where the direction is not a unit vector."""
    with np.errstate(invalid="ignore"):
        return np.sqrt(1.0 - u * u - v * v)
