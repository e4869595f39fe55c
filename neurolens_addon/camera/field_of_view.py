"""What a focused lens images onto a film: the field of view per film extent, the image circle.

The sensor-side profile (film radius -> field angle, relative illumination) along a film
direction and the image circle are core.field's (`sensor_profile`, `circle_radius_mm`: traced
from the sensor, the way a render sees the lens); this module caches them per (lens, sensor
position, direction) and answers the panel's questions, on the film the lens itself images
onto (camera.derived: an anamorphic lens's is 1 / squeeze as wide as the desqueezed frame):
  field of view 2 theta(e) for a film half-extent e along a direction (linear between traced
                radii), None beyond the image circle; the frame's horizontal (along x, the
                lens film's half width), vertical (along y, its half height) and diagonal
                (along its diagonal, its half diagonal) fields;
  image circle  the diameter lit along the lens film's diagonal (a lens of revolution's
                circle; an anamorphic lens lights an oval, and the diagonal is where the
                frame's corners go dark).
The thin lens: 2 atan(e / f) on the frame itself.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.field import circle_radius_mm, sensor_profile
from .lru import cache, stats

_FOV = cache(1024)         # (content hash, group, sensor z, direction, extent) -> degrees
_PROFILE = cache(256)      # (content hash, group, sensor z, direction) -> profile


def _azimuth(entry, azimuth_deg: float) -> float:
    """The direction traced: every direction is the same for a lens of revolution."""
    return round(float(azimuth_deg), 9) if entry.lens.anamorphic else 0.0


def _profile(entry, sensor_z_mm: float, focus_group: float = 0.0, azimuth_deg: float = 0.0):
    """(film radii, field angles in degrees, relative illumination) of the focused lens (its
    focusing groups at `focus_group`, core.variable_gaps: the field breathes with them) along
    the film direction `azimuth_deg`."""
    a = _azimuth(entry, azimuth_deg)
    key = (entry.content_hash, round(float(focus_group), 12), round(float(sensor_z_mm), 6), a)
    hit = _PROFILE.get_lru(key)
    if hit is not None:
        return hit
    stats["fov_traces"] += 1
    lens = entry.lens
    if entry.table:          # a lens known only from a ray table: traced through its model
        return _PROFILE.put(key, sensor_profile(None, float(sensor_z_mm), a, tracer=lens.trace,
                                                plane=lens.plane))
    if focus_group and lens.focus_gaps is not None:
        from ..core.variable_gaps import lens_at
        lens = lens_at(lens, focus=float(focus_group))
    return _PROFILE.put(key, sensor_profile(lens, float(sensor_z_mm), a))


def image_circle_mm(entry, sensor_z_mm: float, focus_group: float = 0.0,
                    azimuth_deg: float = 0.0) -> float:
    """Diameter of the image circle along the film direction `azimuth_deg` (module
    docstring)."""
    return 2.0 * circle_radius_mm(*_profile(entry, sensor_z_mm, focus_group, azimuth_deg))


def field_of_view_deg(entry, sensor_z_mm: float, half_extent_mm: float,
                      focus_group: float = 0.0, azimuth_deg: float = 0.0) -> float | None:
    """Full angle (degrees) imaged onto [-half_extent, +half_extent] of the film along the
    direction `azimuth_deg`; None when the extent reaches beyond the image circle (module
    docstring)."""
    half = float(half_extent_mm)
    if not half > 0.0:
        return 0.0
    a = _azimuth(entry, azimuth_deg)
    key = (entry.content_hash, round(float(focus_group), 12), round(float(sensor_z_mm), 6), a,
           round(half, 6))
    hit = _FOV.get_lru(key)
    if hit is not None:
        return None if hit < 0 else hit
    radii, angles, illumination = _profile(entry, sensor_z_mm, focus_group, a)
    inside = half <= circle_radius_mm(radii, angles, illumination)
    result = 2.0 * float(np.interp(half, radii, angles)) if inside else -1.0
    _FOV.put(key, result)
    return None if result < 0 else result


def frame_field_of_view(setup) -> tuple[tuple, float | None]:
    """((horizontal, vertical, diagonal) full angles in degrees, each None beyond the image
    circle; the image circle's diameter in mm, None for the thin lens) of a LensSetup's frame
    (module docstring)."""
    if setup.model == "thin":
        w, h = setup.film.size_mm
        f = setup.entry.efl_mm
        return tuple(2.0 * math.degrees(math.atan(x / f))
                     for x in (0.5 * w, 0.5 * h, 0.5 * math.hypot(w, h))), None
    c = setup.derived
    w, h = c.lens_film.size_mm
    diagonal = math.degrees(math.atan2(h, w))
    z, group, entry = c.sensor_z_mm, setup.focus_group, setup.entry
    fov = (field_of_view_deg(entry, z, 0.5 * w, group, 0.0),
           field_of_view_deg(entry, z, 0.5 * h, group, 90.0),
           field_of_view_deg(entry, z, 0.5 * math.hypot(w, h), group, diagonal))
    return fov, image_circle_mm(entry, z, group, diagonal)
