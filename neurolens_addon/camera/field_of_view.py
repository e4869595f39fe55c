"""What a focused lens images onto a film: the field of view per film extent, the image circle.

The sensor-side profile (film radius -> field angle, relative illumination) and the image
circle are core.field's (`sensor_profile`, `circle_radius_mm`: traced from the sensor, the
way a render sees the lens); this module caches them per (lens, sensor position) and answers
the panel's questions:
  field of view 2 theta(e) for a film half-extent e (linear between traced radii), None beyond
                the image circle.
"""

from __future__ import annotations


import numpy as np

from ..core.field import circle_radius_mm, sensor_profile
from .lru import cache, stats

_FOV = cache(1024)         # (content hash, sensor z, extent) -> degrees
_PROFILE = cache(256)      # (content hash, sensor z) -> (radii, angles, illumination)


def _profile(entry, sensor_z_mm: float, focus_group: float = 0.0):
    """(film radii, field angles in degrees, relative illumination) of the focused lens (its
    focusing groups at `focus_group`, core.variable_gaps: the field breathes with them)."""
    key = (entry.content_hash, round(float(focus_group), 12), round(float(sensor_z_mm), 6))
    hit = _PROFILE.get_lru(key)
    if hit is not None:
        return hit
    stats["fov_traces"] += 1
    lens = entry.lens
    if focus_group and lens.focus_gaps is not None:
        from ..core.variable_gaps import lens_at
        lens = lens_at(lens, focus=float(focus_group))
    return _PROFILE.put(key, sensor_profile(lens, float(sensor_z_mm)))


def image_circle_mm(entry, sensor_z_mm: float, focus_group: float = 0.0) -> float:
    """Diameter of the image circle (module docstring)."""
    return 2.0 * circle_radius_mm(*_profile(entry, sensor_z_mm, focus_group))


def field_of_view_deg(entry, sensor_z_mm: float, half_extent_mm: float,
                      focus_group: float = 0.0) -> float | None:
    """Full angle (degrees) imaged onto [-half_extent, +half_extent] of the film; None when
    the extent reaches beyond the image circle (module docstring)."""
    half = float(half_extent_mm)
    if not half > 0.0:
        return 0.0
    key = (entry.content_hash, round(float(focus_group), 12), round(float(sensor_z_mm), 6),
           round(half, 6))
    hit = _FOV.get_lru(key)
    if hit is not None:
        return None if hit < 0 else hit
    radii, angles, illumination = _profile(entry, sensor_z_mm, focus_group)
    inside = half <= circle_radius_mm(radii, angles, illumination)
    result = 2.0 * float(np.interp(half, radii, angles)) if inside else -1.0
    _FOV.put(key, result)
    return None if result < 0 else result
