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

Sensor-side profile (the way a render sees the lens, and past 90 degrees, as a fisheye's film
does): from a film point at radius r, a uniform grid of aim points over the plane renderers aim
at (core.pupil.sampling_plane: the exit pupil, or the rear vertex when the exit pupil lies
behind the sensor; a square twice its half width across, widened for the film's edge) is traced
exactly; each passing ray carries the irradiance weight cos^4(t) / dz^2 of a uniform scene.
  illumination  E(r) = sum of the passing rays' weights, relative to E(0); the image circle's
                radius is the largest traced r up to which E(r) stays above 1 % and the field
                angle keeps growing;
  field angle   theta(r) = the angle from the axis of the weight-averaged exit direction.
(Aiming at the rear vertex alone fails a lens that ends in a cover glass a millimetre or two
from the sensor: no aim point there passes.)
"""

from __future__ import annotations

import math

import numpy as np

from .np_compat import trapezoid
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


def design_film_radius_mm(lens: Lens) -> float:
    """The film radius the design covers: the image height at 98 % of its half field (what a
    learned model covers at least; a render's own film radius is core.film.Film.radius_mm)."""
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
    hc = trapezoid(w * h[ok, None], lam[ok], axis=0) / trapezoid(w, lam[ok], axis=0)
    return float(hc[0] - hc[2])


_PROFILE_RADII = 41
_PROFILE_AIM = 40               # aim points per side of the grid
_DARK = 0.01                    # relative illumination below which the film is outside


def sensor_profile(lens: Lens | None, sensor_z: float, azimuth_deg: float = 0.0, *,
                   tracer=None, plane=None):
    """(film radii (mm), field angles (degrees), relative illumination) traced from the sensor
    out to 1.6 full-frame half diagonals (module docstring), along the film direction at
    `azimuth_deg` from +x (an anamorphic lens images each direction differently; a lens of
    revolution the same). A lens known only by its learned model (camera.table_lens) gives
    `tracer` (Rays from the sensor -> a result with .valid and .rays) and `plane` ((z, half
    width) aimed at) in place of `lens`."""
    from .pupil import sampling_plane
    from .trace import trace
    zs = float(sensor_z)
    c, s = math.cos(math.radians(azimuth_deg)), math.sin(math.radians(azimuth_deg))
    radii = np.linspace(0.0, 1.6 * FULL_FRAME_HALF_DIAGONAL_MM, _PROFILE_RADII)
    if tracer is None:
        z_aim, half = sampling_plane(lens, zs)
        half = max(half, 1.5 * radii[-1] * (z_aim - zs) / max(lens.total_track_mm, 1e-9))

        def tracer(rays):
            return trace(lens, rays, from_sensor=True, threads=1)
    else:
        z_aim, half = plane
    g = (np.arange(_PROFILE_AIM) + 0.5) / _PROFILE_AIM * 2.0 * half - half
    ax, ay = (a.ravel() for a in np.meshgrid(g, g))
    r = np.repeat(radii, ax.size)
    px, py = np.tile(ax, radii.size), np.tile(ay, radii.size)
    d = np.stack([px - r * c, py - r * s, np.full(r.size, z_aim - zs)])
    length = np.linalg.norm(d, axis=0)
    o = np.stack([r * c, r * s, np.full(r.size, zs)])
    res = tracer(Rays(o, d / length, np.full(r.size, WAVELENGTH_D_NM)))
    w = (res.valid * ((z_aim - zs) / length) ** 4).reshape(radii.size, -1)
    e = w.sum(axis=1)
    ex = res.rays.d * res.valid
    mean = np.stack([(ex[k].reshape(radii.size, -1) * w).sum(axis=1) for k in range(3)])
    angles = np.degrees(np.arctan2(np.hypot(mean[0], mean[1]), mean[2]))
    illumination = e / e[0] if e[0] > 0 else np.zeros_like(e)
    return radii, angles, illumination


def circle_radius_mm(radii, angles, illumination) -> float:
    """The largest traced radius before the film goes dark or the field angle turns back."""
    end = np.flatnonzero((illumination < _DARK) | np.r_[False, np.diff(angles) < 0])
    last = (end[0] - 1) if end.size else radii.size - 1
    return float(radii[max(last, 0)])


def image_circle_radius_mm(lens: Lens, sensor_z: float) -> float:
    """Radius of the image circle on the sensor plane `sensor_z` (module docstring)."""
    return circle_radius_mm(*sensor_profile(lens, sensor_z))
