"""Focusing by moving the sensor, solved with exact rays so that focus breathing is real.

For an object at distance D in front of the sensor (D measured from the sensor plane, as a
camera's distance scale is), the sensor sits at the plane of least RMS spot radius of an exact
ray bundle from the object point through the aperture. Rays arriving at plane z = z_s with
positions (x_i, y_i) and slopes (a_i, b_i) = (dx/dz, dy/dz) reach plane z_s + delta at
x_i + delta a_i; the RMS radius about the centroid is least at
    delta = -sum(x~_i a~_i + y~_i b~_i) / sum(a~_i^2 + b~_i^2)        (~ : centroid removed).
Because D is measured from the sensor, the object moves with it: iterate z_s -> z_s + delta
(a contraction for any real lens) until delta is below tolerance.

Lenses that focus by moving groups (a [focus] table, core.variable_gaps) move them instead and
keep only the small residual sensor shift this solves on the moved lens.
The closest focus is the source's stated value when the lens file gives one, else the last
distance of a [focus] table; otherwise the distance at which the sensor has moved CLOSEST_FOCUS_EXTENSION times the focal length behind the
infinity position (a magnification of about 0.15, typical of unit-focusing lenses).
"""

from __future__ import annotations

import math

import numpy as np

from .errors import FocusError
from .paraxial import paraxial_data, paraxial_image_z
from .prescription import WAVELENGTH_D_NM, Lens
from .rays import Rays
from .trace import trace
from .variable_gaps import TABULATED_REL_TOL

CLOSEST_FOCUS_EXTENSION = 0.15
_RINGS = (0.2, 0.4, 0.55, 0.7, 0.8, 0.9)
_SPOKES = 24


def _object_bundle(lens: Lens, z_obj: float, stop_radius: float, wavelength_nm: float, catalog):
    """Rays from an axial object point (z_obj = inf: from infinity) through the entrance pupil."""
    pd = paraxial_data(lens, wavelength_nm, catalog)
    r_ep = 0.5 * pd.entrance_pupil.diameter_mm * stop_radius / lens.stop_radius_mm
    phi = np.linspace(0.0, 2.0 * np.pi, _SPOKES, endpoint=False)
    rr = np.array(_RINGS)[:, None] * r_ep
    px = (rr * np.cos(phi)).ravel()
    py = (rr * np.sin(phi)).ravel()
    n = px.size
    z_start = lens.front_vertex_z + 1.0
    o = np.empty((3, n))
    d = np.empty((3, n))
    if math.isinf(z_obj):
        o[0], o[1], o[2] = px, py, z_start
        d[0], d[1], d[2] = 0.0, 0.0, -1.0
    else:
        zp = pd.entrance_pupil.z_mm
        d[0], d[1], d[2] = px, py, zp - z_obj
        d /= np.linalg.norm(d, axis=0)
        o[0], o[1], o[2] = 0.0, 0.0, z_obj
    return Rays(o, d, np.full(n, float(wavelength_nm)))


def best_focus_z(lens: Lens, z_obj: float, *, sensor_z_guess: float = 0.0, stop_radius=None,
                 wavelength_nm=WAVELENGTH_D_NM, catalog=None) -> float:
    """Lens-space z of least RMS spot for a fixed object point (no sensor coupling)."""
    stop_radius = lens.stop_radius_mm if stop_radius is None else stop_radius
    rays = _object_bundle(lens, z_obj, stop_radius, wavelength_nm, catalog)
    res = trace(lens, rays, from_sensor=False, stop_radius=stop_radius, sensor_z=sensor_z_guess,
                catalog=catalog, threads=1)
    v = res.valid
    if v.sum() < 8:
        raise FocusError(f"lens '{lens.name}': too few rays pass the lens to find focus "
                         f"for an object at z = {z_obj:g} mm")
    x, y = res.rays.o[0, v], res.rays.o[1, v]
    a = res.rays.d[0, v] / res.rays.d[2, v]
    b = res.rays.d[1, v] / res.rays.d[2, v]
    x, y, a, b = x - x.mean(), y - y.mean(), a - a.mean(), b - b.mean()
    delta = -np.sum(x * a + y * b) / np.sum(a * a + b * b)
    return float(sensor_z_guess + delta)


def sensor_z_for_infinity(lens: Lens, **kw) -> float:
    return best_focus_z(lens, math.inf, **kw)


def closest_focus_mm(lens: Lens, wavelength_nm=WAVELENGTH_D_NM, catalog=None) -> float:
    """Closest focus distance from the sensor (mm)."""
    if lens.closest_focus_mm is not None:
        return float(lens.closest_focus_mm)
    if lens.focus_gaps is not None:                 # internal focusing: the table's nearest
        return float(lens.focus_gaps.positions[-1])
    pd = paraxial_data(lens, wavelength_nm, catalog)
    f = pd.efl_mm
    # Newton's lens equation x x' = f^2 with x' = extension: object is f^2/x' before the
    # front focal point.
    ext = CLOSEST_FOCUS_EXTENSION * f
    z_obj = pd.front_focal_z_mm + f * f / ext
    return float(z_obj - (pd.rear_focal_z_mm - ext))


def focus_sensor_z(lens: Lens, object_distance_mm: float, *, stop_radius=None,
                   wavelength_nm=WAVELENGTH_D_NM, catalog=None, tolerance_mm=1e-7,
                   max_iterations=50) -> float:
    """Sensor position (lens-space z) that focuses an object `object_distance_mm` in front of
    the sensor; inf focuses at infinity. A lens with focusing groups is taken as moved for that
    distance (camera.focusing.focused_lens): its residual is solved with the object that far
    from the design plane. Raises FocusError nearer than the closest focus."""
    d = float(object_distance_mm)
    if math.isnan(d) or d <= 0.0:
        raise FocusError(f"focus distance must be positive, got {object_distance_mm!r} mm")
    if math.isinf(d):
        return sensor_z_for_infinity(lens, stop_radius=stop_radius, wavelength_nm=wavelength_nm,
                                     catalog=catalog)
    near = closest_focus_mm(lens, wavelength_nm, catalog)
    if d < near * (1.0 - TABULATED_REL_TOL):      # (Blender's focus distance is float32)
        raise FocusError(f"lens '{lens.name}' focuses no closer than {near / 1000.0:.3f} m "
                         f"(asked for {d / 1000.0:.3f} m)")
    if lens.focus_gaps is not None:
        # Moving groups have focused (the lens passed in is moved: camera.focusing): the
        # sensor stays by the design plane, and the exact residual (spherical aberration's
        # focus shift) is solved with the object d from that plane. Letting the object ride
        # along with the sensor is ill-posed near 1:1 (both conjugates shift alike), and the
        # distance differs by the residual only.
        return best_focus_z(lens, d, sensor_z_guess=0.0, stop_radius=stop_radius,
                            wavelength_nm=wavelength_nm, catalog=catalog)
    # Paraxial start, then the fixed point of exact best focus with the object riding along.
    z_s = 0.0
    for _ in range(20):
        z_new = paraxial_image_z(lens, d, z_s, wavelength_nm, catalog)
        if abs(z_new - z_s) < 1e-9:
            break
        z_s = z_new
    # Secant steps on h(z) = best_focus(z) - z: a plain fixed-point iteration contracts by
    # the magnification squared per step (the object rides along with the sensor), which
    # never converges for a macro lens at 1:1.
    def h(z):
        return best_focus_z(lens, z + d, sensor_z_guess=z, stop_radius=stop_radius,
                            wavelength_nm=wavelength_nm, catalog=catalog) - z
    z_prev, h_prev = z_s, h(z_s)
    z_s = z_prev + h_prev
    for _ in range(max_iterations):
        if abs(h_prev) < tolerance_mm:
            return z_prev + h_prev
        h_s = h(z_s)
        if abs(h_s) < tolerance_mm:
            return z_s + h_s
        slope = (h_s - h_prev) / (z_s - z_prev) if z_s != z_prev else 0.0
        step = -h_s / slope if slope < -1e-12 and math.isfinite(slope) else h_s
        z_prev, h_prev, z_s = z_s, h_s, z_s + step
    raise FocusError(f"lens '{lens.name}': focus at {d:g} mm did not converge")


def focused_distance_mm(lens: Lens, sensor_z: float, *, stop_radius=None,
                        wavelength_nm=WAVELENGTH_D_NM, catalog=None) -> float:
    """Inverse of focus_sensor_z: the object distance (from the sensor) in focus for a sensor
    position, by bisection on the monotone map distance -> sensor z."""
    z_inf = sensor_z_for_infinity(lens, stop_radius=stop_radius, wavelength_nm=wavelength_nm,
                                  catalog=catalog)
    if sensor_z >= z_inf:
        return math.inf
    lo, hi = closest_focus_mm(lens, wavelength_nm, catalog), 1e9
    for _ in range(80):
        mid = math.sqrt(lo * hi)
        z = focus_sensor_z(lens, mid, stop_radius=stop_radius, wavelength_nm=wavelength_nm,
                           catalog=catalog)
        if z < sensor_z:
            lo = mid
        else:
            hi = mid
        if hi / lo < 1 + 1e-9:
            break
    return math.sqrt(lo * hi)


#: where a model is measured (its image error, what a ray through it costs): 2 m from the sensor
EVALUATION_FOCUS_MM = 2000.0


def evaluation_focus_mm(lens: Lens, sensor_z_range) -> float:
    """The focus distance (mm) a model trained for sensor positions `sensor_z_range` is
    measured at: a lens with focusing groups at a close tabulated position, that position;
    else EVALUATION_FOCUS_MM (or the lens's closest focus, when farther: a long telephoto)
    when the range holds it, else the middle of the range."""
    from .variable_gaps import tabulated_position
    k = tabulated_position(lens, lens.focus_gaps)
    if k:                       # groups at a close tabulated position: focused there
        return float(lens.focus_gaps.positions[k])
    focus = max(EVALUATION_FOCUS_MM, closest_focus_mm(lens))
    z = focus_sensor_z(lens, focus)
    lo, hi = sensor_z_range
    if lo <= z <= hi:
        return focus
    return focused_distance_mm(lens, 0.5 * (lo + hi))
