"""Focus distances a lens can reach, and the sensor position that focuses each one.

Distances are measured from the sensor plane (as a camera's distance scale is), in mm.
A distance nearer than the lens's closest focus, or no distance at all, cannot be focused:
the render uses the closest focus instead and says so; the focus picker refuses it. The
sensor position z_s(D) that focuses D is core.focus.focus_sensor_z (exact rays, least RMS
spot at the stop radius used), cached by (lens content, D, stop radius), so replaying
keyframed focus is a dictionary look-up.
"""

from __future__ import annotations

import math

from ..core.errors import FocusError
from ..core.variable_gaps import TABULATED_REL_TOL
from .lru import cache, stats

_FOCUS = cache(4096)       # (content hash, distance, stop radius) -> sensor z



def nearer_than_closest(entry, distance_mm: float) -> bool:
    d = float(distance_mm)
    # (within float32: Blender's focus distance set to the closest focus reads back a hair off)
    return math.isnan(d) or d < entry.closest_focus_mm * (1.0 - TABULATED_REL_TOL)


def clamp_focus_mm(entry, distance_mm: float) -> tuple[float, str | None]:
    """(usable distance, message or None): nearer than the closest focus, or no distance,
    focuses at the closest focus, with a message saying so."""
    d = float(distance_mm)
    near = entry.closest_focus_mm
    if nearer_than_closest(entry, d):
        asked = "nothing" if math.isnan(d) else f"{d / 1000.0:.3f} m"
        return near, (f"'{entry.name}' focuses no closer than {near / 1000.0:.3f} m: "
                      f"focus at {asked} refused, focusing at {near / 1000.0:.3f} m")
    return d, None


def refuse_nearer_than_closest(entry, distance_mm: float, what: str) -> None:
    """FocusError when `what` (e.g. "the picked point") lies nearer than the closest focus."""
    if nearer_than_closest(entry, distance_mm):
        near = entry.closest_focus_mm
        raise FocusError(f"'{entry.name}' focuses no closer than {near / 1000.0:.3f} m; "
                         f"{what} is {float(distance_mm) / 1000.0:.3f} m away: focus unchanged")


def not_nearer_m(entry, distance_m: float) -> float:
    """max(distance, closest focus) in metres, such that 1000 d >= the closest focus (mm) as
    core.focus computes it."""
    closest_mm = entry.closest_focus_mm
    d = max(float(distance_m), closest_mm / 1000.0)
    while 1000.0 * d < closest_mm:
        d = math.nextafter(d, math.inf)
    return d


def focus_group_position(entry, distance_mm: float) -> float:
    """Where a lens that focuses by moving groups (a [focus] table) puts them for
    `distance_mm` (core.variable_gaps: 0 at infinity, n - 1 at the closest focus); 0 for a
    lens that focuses as a unit."""
    if entry.lens.focus_gaps is None:
        return 0.0
    from ..core.variable_gaps import focus_position
    d = float(distance_mm)
    key = (entry.content_hash, "group", "inf" if math.isinf(d) else round(d, 6))
    s = _FOCUS.get_lru(key)
    if s is None:
        s = float(focus_position(entry.lens, d))
        _FOCUS.put(key, s)
    return s


def focused_lens(entry, distance_mm: float):
    """The lens as it stands focused at `distance_mm`: its focusing groups moved (the file's
    lens itself for unit focusing)."""
    from ..core.variable_gaps import lens_at
    s = focus_group_position(entry, distance_mm)
    return entry.lens if s == 0.0 else lens_at(entry.lens, focus=s)


def focus_sensor_z_mm(entry, distance_mm: float, stop_radius_mm: float) -> float:
    """The exact sensor position focusing `distance_mm` (from the sensor; inf allowed): for
    unit focusing the whole extension, for a lens with focusing groups only the small residual
    on the moved lens (focused_lens).

    Raises FocusError nearer than the closest focus (callers clamp first).
    """
    return lens_sensor_z_mm(focused_lens(entry, distance_mm), distance_mm, stop_radius_mm)


def lens_sensor_z_mm(lens, distance_mm: float, stop_radius_mm: float) -> float:
    """core.focus.focus_sensor_z of a lens as it stands at stop radius `stop_radius_mm`,
    cached by (lens content, distance, stop radius)."""
    from ..core.focus import focus_sensor_z

    d = float(distance_mm)
    key = (lens.content_hash(), "inf" if math.isinf(d) else round(d, 6),
           round(float(stop_radius_mm), 9))
    z = _FOCUS.get_lru(key)
    if z is None:
        stats["focus_solves"] += 1
        z = float(focus_sensor_z(lens, d, stop_radius=float(stop_radius_mm)))
        _FOCUS.put(key, z)
    return z
