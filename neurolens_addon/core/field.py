"""The field a lens covers: half-field angles, parallel beams from a field angle, image heights,
and the lateral colour an RGB camera records there.

Beams are built over the whole front aperture and only the rays that pass are kept, which stays
right where paraxial pupils are wrong (wide angles, fisheyes: the pupil moves and tilts with
the field).

Lateral colour under channel weights w_c(lambda) (a colour-matching function or a sensor
response): channel c's image of a distant point sits at the weighted mean image height
    h_c = integral w_c(lambda) h(lambda) / integral w_c(lambda)
(the centroid of the channel's image, each wavelength's beam carrying the same flux), and the
lateral colour is h_R - h_B: what a chart's off-axis edges show as red and blue fringes.
"""

from __future__ import annotations

import math

import numpy as np

from .paraxial import paraxial_data
from .prescription import WAVELENGTH_D_NM, Lens
from .rays import Rays

#: the full-frame diagonal half-size (mm), used when a lens states no field of view
FULL_FRAME_HALF_DIAGONAL_MM = 21.63


def half_field_deg(lens: Lens) -> float:
    """Half of the full field the lens covers: its stated field, or that of a full-frame
    diagonal at its focal length."""
    if lens.field_of_view_deg:
        return 0.5 * float(lens.field_of_view_deg)
    return math.degrees(math.atan(FULL_FRAME_HALF_DIAGONAL_MM / paraxial_data(lens).efl_mm))


def field_beam(lens: Lens, field_deg: float, n: int, wavelength_nm: float = WAVELENGTH_D_NM, *,
               span=None, two_d: bool = True, seed: int = 0):
    """Parallel rays from a field angle in the y-z plane, over a line (two_d) or a jittered
    square grid (n points) around the paraxial entrance pupil's projection."""
    th = math.radians(field_deg)
    z0 = lens.front_vertex_z + 5.0
    span = 1.2 * lens.surfaces[0].semi_diameter_mm if span is None else span
    d = np.array([0.0, -math.sin(th), -math.cos(th)])
    y_c = math.tan(th) * (z0 - paraxial_data(lens).entrance_pupil.z_mm) if abs(th) < 1.55 else 0.0
    if two_d:
        ys = y_c + np.linspace(-span, span, n)
        xs = np.zeros_like(ys)
    else:
        m = max(2, int(math.sqrt(n)))
        step = 2.0 * span / m
        g = -span + step * (np.arange(m) + 0.5)
        xs, ys = np.meshgrid(g, g)
        jitter = np.random.default_rng(seed).uniform(-0.5, 0.5, (2, xs.size)) * step
        xs = xs.ravel() + jitter[0]
        ys = ys.ravel() + jitter[1] + y_c
    o = np.stack([xs, ys, np.full_like(xs, z0)])
    return Rays(o, np.repeat(d[:, None], xs.size, axis=1), np.full(xs.size, float(wavelength_nm)))


def image_height_mm(lens: Lens, field_deg: float, sensor_z: float = 0.0,
                    wavelength_nm: float = WAVELENGTH_D_NM) -> float:
    """|y| of the centroid on the sensor of a parallel beam from the field angle (NaN if the
    whole beam is vignetted)."""
    from .trace import trace
    rays = field_beam(lens, field_deg, 2500, wavelength_nm, two_d=False)
    res = trace(lens, rays, from_sensor=False, sensor_z=sensor_z)
    if not res.valid.any():
        return math.nan
    return float(abs(res.rays.o[1, res.valid].mean()))


def film_radius_mm(lens: Lens) -> float:
    """Radius of the image circle over the lens's field (at 98 % of the half field)."""
    h = image_height_mm(lens, 0.98 * half_field_deg(lens))
    return h if math.isfinite(h) else FULL_FRAME_HALF_DIAGONAL_MM


def lateral_colour_mm(lens: Lens, field_deg: float, weights, sensor_z: float = 0.0,
                      wavelengths_nm=None) -> float:
    """h_R - h_B (mm, module docstring) at a field angle; `weights(lambda) -> (N, 3)`.
    Integrated by the trapezoid rule over `wavelengths_nm` (default 380-780 nm every 10 nm)."""
    lam = np.arange(380.0, 780.1, 10.0) if wavelengths_nm is None else \
        np.asarray(wavelengths_nm, dtype=np.float64)
    h = np.array([image_height_mm(lens, field_deg, sensor_z, wl) for wl in lam])
    ok = np.isfinite(h)
    w = np.asarray(weights(lam[ok]), dtype=np.float64)
    hc = np.trapz(w * h[ok, None], lam[ok], axis=0) / np.trapz(w, lam[ok], axis=0)
    return float(hc[0] - hc[2])
