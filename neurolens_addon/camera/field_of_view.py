"""What a focused lens images onto a film: the field of view per film extent, the image circle.

Traced from the sensor, the way a render sees the lens (and past 90 degrees, as a fisheye's
film does): from a film point at radius r, a uniform grid of aim points over the rear vertex
plane (a square 1.6 rear semi-diameters across each way) is traced exactly; each passing ray
carries the irradiance weight cos^4(t) / dz^2 of a uniform scene.
  illumination  E(r) = sum of the passing rays' weights; the image circle's radius is the
                largest traced r up to which E(r) stays above 1 % of E(0) and the field
                angle keeps growing;
  field angle   theta(r) = the angle from the axis of the weight-averaged exit direction
                (the centre of the beam the film point sees, distortion and focus breathing
                included);
  field of view 2 theta(e) for a film half-extent e (linear between traced radii), None beyond
                the image circle.
One batched trace per (lens, sensor position), cached.
"""

from __future__ import annotations


import numpy as np

from .lru import cache, stats

_RADII = 41
_AIM = 40                  # aim points per side of the rear grid
_DARK = 0.01               # relative illumination below which the film is outside the circle
_FOV = cache(1024)         # (content hash, sensor z, extent) -> degrees
_PROFILE = cache(256)      # (content hash, sensor z) -> (radii, angles, illumination)


def _profile(entry, sensor_z_mm: float):
    """(film radii, field angles in degrees, relative illumination) of the focused lens."""
    key = (entry.content_hash, round(float(sensor_z_mm), 6))
    hit = _PROFILE.get_lru(key)
    if hit is not None:
        return hit
    from ..core.field import FULL_FRAME_HALF_DIAGONAL_MM
    from ..core.rays import Rays
    from ..core.trace import trace

    stats["fov_traces"] += 1
    lens, zs = entry.lens, float(sensor_z_mm)
    z_rear = float(lens.vertex_z[-1])
    half = 1.6 * lens.surfaces[-1].semi_diameter_mm
    g = (np.arange(_AIM) + 0.5) / _AIM * 2.0 * half - half
    ax, ay = (a.ravel() for a in np.meshgrid(g, g))
    radii = np.linspace(0.0, 1.6 * FULL_FRAME_HALF_DIAGONAL_MM, _RADII)
    r = np.repeat(radii, ax.size)
    px, py = np.tile(ax, radii.size), np.tile(ay, radii.size)
    d = np.stack([px - r, py, np.full(r.size, z_rear - zs)])
    length = np.linalg.norm(d, axis=0)
    o = np.stack([r, np.zeros(r.size), np.full(r.size, zs)])
    res = trace(lens, Rays(o, d / length, np.full(r.size, 587.5618)), from_sensor=True,
                threads=1)
    w = (res.valid * ((z_rear - zs) / length) ** 4).reshape(radii.size, -1)
    e = w.sum(axis=1)
    ex = res.rays.d * res.valid
    mean = np.stack([(ex[k].reshape(radii.size, -1) * w).sum(axis=1) for k in range(3)])
    angles = np.degrees(np.arctan2(np.hypot(mean[0], mean[1]), mean[2]))
    illumination = e / e[0] if e[0] > 0 else np.zeros_like(e)
    return _PROFILE.put(key, (radii, angles, illumination))


def _circle_radius(radii, angles, illumination) -> float:
    """The largest traced radius before the film goes dark or the field angle turns back."""
    end = np.flatnonzero((illumination < _DARK) | np.r_[False, np.diff(angles) < 0])
    last = (end[0] - 1) if end.size else radii.size - 1
    return float(radii[max(last, 0)])


def image_circle_mm(entry, sensor_z_mm: float) -> float:
    """Diameter of the image circle (module docstring)."""
    return 2.0 * _circle_radius(*_profile(entry, sensor_z_mm))


def field_of_view_deg(entry, sensor_z_mm: float, half_extent_mm: float) -> float | None:
    """Full angle (degrees) imaged onto [-half_extent, +half_extent] of the film; None when
    the extent reaches beyond the image circle (module docstring)."""
    half = float(half_extent_mm)
    if not half > 0.0:
        return 0.0
    key = (entry.content_hash, round(float(sensor_z_mm), 6), round(half, 6))
    hit = _FOV.get_lru(key)
    if hit is not None:
        return None if hit < 0 else hit
    radii, angles, illumination = _profile(entry, sensor_z_mm)
    inside = half <= _circle_radius(radii, angles, illumination)
    result = 2.0 * float(np.interp(half, radii, angles)) if inside else -1.0
    _FOV.put(key, result)
    return None if result < 0 else result
