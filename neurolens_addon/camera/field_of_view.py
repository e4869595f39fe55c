"""What a focused lens images onto a film: the field of view per film extent, the image circle.

The image height h(theta) of a field angle theta is the centroid on the sensor of a parallel
beam at theta, traced exactly (distortion and focus breathing included); NaN where the whole
beam is vignetted. The image circle's diameter is 2 max h over the angles up to where the beam
is vignetted away or h turns back. The full field of view onto a film half-extent e is
2 theta with h(theta) = e (interpolated linearly between traced angles), None beyond the
image circle. One batched trace per (lens, sensor position), cached.
"""

from __future__ import annotations

import math

import numpy as np

from .lru import cache, stats

_FOV_ANGLES = 33
_FOV_BEAM = 144
_FOV = cache(1024)         # (content hash, sensor z, extent) -> degrees
_HEIGHTS = cache(256)      # (content hash, sensor z) -> (angles, image heights)



def _image_heights(entry, sensor_z_mm: float) -> tuple[np.ndarray, np.ndarray]:
    key = (entry.content_hash, round(float(sensor_z_mm), 6))
    hit = _HEIGHTS.get_lru(key)
    if hit is not None:
        return hit
    from ..core.field import field_beam, half_field_deg
    from ..core.rays import Rays
    from ..core.trace import trace

    stats["fov_traces"] += 1
    top = min(89.0, 2.0 * half_field_deg(entry.lens) + 5.0)
    angles = np.linspace(0.0, top, _FOV_ANGLES)
    beams = [field_beam(entry.lens, float(a), _FOV_BEAM, two_d=False) for a in angles]
    sizes = [b.n for b in beams]
    rays = Rays(np.concatenate([b.o for b in beams], axis=1),
                np.concatenate([b.d for b in beams], axis=1),
                np.concatenate([b.wavelength for b in beams]))
    res = trace(entry.lens, rays, from_sensor=False, sensor_z=float(sensor_z_mm), threads=1)
    heights = np.full(angles.size, np.nan)
    start = 0
    for k, n in enumerate(sizes):
        v = res.valid[start:start + n]
        if v.any():
            heights[k] = abs(float(res.rays.o[1, start:start + n][v].mean()))
        start += n
    heights[0] = 0.0
    return _HEIGHTS.put(key, (angles, heights))


def image_circle_mm(entry, sensor_z_mm: float) -> float:
    """Diameter of the image circle (module docstring)."""
    angles, heights = _image_heights(entry, sensor_z_mm)
    best = 0.0
    for k in range(1, angles.size):
        if not math.isfinite(heights[k]) or heights[k] < heights[k - 1]:
            break
        best = float(heights[k])
    return 2.0 * best


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
    angles, heights = _image_heights(entry, sensor_z_mm)
    result = -1.0
    for k in range(1, angles.size):
        h0, h1 = heights[k - 1], heights[k]
        if not math.isfinite(h1) or h1 < h0:
            break           # vignetted, or the image height turns back: the coverage ends
        if h1 >= half:
            t = (half - h0) / (h1 - h0) if h1 > h0 else 0.0
            result = 2.0 * float(angles[k - 1] + t * (angles[k] - angles[k - 1]))
            break
    _FOV.put(key, result)
    return None if result < 0 else result
