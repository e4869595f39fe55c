"""Rays from film points aimed at a plane behind the lens: how the chief rays are found.

A ray from the film point (x, y) on the sensor plane z_s aimed at (a_x, a_y) on the plane z_a
has the direction (a_x - x, a_y - y, z_a - z_s) made unit; z_a is the paraxial exit pupil's
plane, or the rear vertex's where that pupil does not lie in front of the sensor. core.stmap
(along one radius) and core.chief_grid (over the film) solve the aim that crosses the stop's
centre.
"""

from __future__ import annotations

import math

import numpy as np

from .prescription import Lens
from .rays import Rays


def aim_plane_z(lens: Lens, sensor_z: float) -> float:
    """The plane chief rays are aimed at: the paraxial exit pupil's, or the rear vertex's
    where that pupil does not lie in front of the sensor."""
    from .paraxial import paraxial_data
    z_a = float(paraxial_data(lens).exit_pupil.z_mm)
    return z_a if z_a > sensor_z + 1e-6 else float(lens.rear_vertex_z)


def aimed_rays(x, y, ax, ay, sensor_z: float, z_a: float, wavelength_nm: float) -> Rays:
    """The rays from film points (x, y) on the sensor plane aimed at (ax, ay) on the plane z_a
    (arrays of one length, or scalars broadcast to them)."""
    m = np.size(x)
    x, y = np.broadcast_to(x, (m,)), np.broadcast_to(y, (m,))
    o = np.stack([x, y, np.full(m, sensor_z)])
    d = np.stack([ax - x, ay - y, np.full(m, z_a - sensor_z)])
    d /= np.linalg.norm(d, axis=0)
    return Rays(o, d, np.full(m, float(wavelength_nm)))


def trace_aimed(lens: Lens, x, y, ax, ay, sensor_z: float, z_a: float, wavelength_nm: float,
                surfaces=None):
    """core.trace of aimed_rays through `surfaces` (None: the whole lens)."""
    from .trace import trace
    return trace(lens, aimed_rays(x, y, ax, ay, sensor_z, z_a, wavelength_nm),
                 from_sensor=True, surfaces=surfaces, stop_radius=math.inf, sensor_z=sensor_z)
