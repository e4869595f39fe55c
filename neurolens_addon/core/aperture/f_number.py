"""The stop radius for an f-number.

f-number: the entrance pupil scales with the stop, so (paraxially, pupil magnification fixed)
    stop_radius(N) = design_stop_radius * design_N / N,
and N below the design's (wider than the lens opens) is refused, or clamped to it. An N within
a relative F_NUMBER_TOLERANCE below the design's is the design's: Blender stores f-numbers in
single precision (f/0.95 reads back as 0.9499999). An N above MAX_F_NUMBER is clamped to it:
there the stop is a few micrometres across and diffraction (an Airy disc of 2.44 lambda N =
1.4 mm on the film at f/1024) swamps any image, while a stored 3.4e38 (Blender's largest float)
would make a stop of 1e-38 mm that no sampled ray passes.
"""

from __future__ import annotations

import math

from ..errors import ApertureError

F_NUMBER_TOLERANCE = 1e-6
MAX_F_NUMBER = 1024.0


def _check_f(name: str, value) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise ApertureError(f"{name} must be a positive number, got {value!r}")
    return v


def stop_radius_for_f_number(design_stop_radius: float, design_f_number: float,
                             f_number: float) -> float:
    """Stop radius (mm) that gives `f_number`: design_stop_radius * design_f_number / f_number.

    Raises ApertureError (a ValueError) when f_number is wider (smaller) than the design's.
    """
    r0 = _check_f("design stop radius", design_stop_radius)
    n0 = _check_f("design f-number", design_f_number)
    n = _check_f("f-number", f_number)
    if n < n0 * (1.0 - F_NUMBER_TOLERANCE):
        raise ApertureError(f"f/{n:g} is wider than this lens allows: its widest aperture is "
                            f"f/{n0:g} (requested f-number {n:g} < design f-number {n0:g})")
    return r0 * n0 / max(n, n0)


def stop_radius_of(lens, f_number: float) -> float:
    """The stop radius (mm) of a lens as configured (its zoom and focusing groups set: core.
    variable_gaps.lens_at) at `f_number`: from its own stop and its own design f-number there,
    the one source of both. ApertureError when wider than the lens opens."""
    return stop_radius_for_f_number(lens.stop_radius_mm, lens.f_number, f_number)


def aperture_key(aperture) -> tuple:
    """The value key of a stop shape (None: the circle), the one every cache uses."""
    return ("circle",) if aperture is None else aperture.key


def clamp_f_number(f_number: float, design_f_number: float) -> tuple[float, str | None]:
    """(usable f-number, message or None): f-numbers wider than the design's are clamped to it."""
    n0 = _check_f("design f-number", design_f_number)
    n = _check_f("f-number", f_number)
    if n < n0:
        if n >= n0 * (1.0 - F_NUMBER_TOLERANCE):
            return n0, None           # the design's, as stored in single precision
        return n0, (f"f/{n:g} is wider than this lens allows; using its widest aperture "
                    f"f/{n0:g} (design f-number {n0:g})")
    top = max(MAX_F_NUMBER, n0)       # a lens designed slower than f/1024 keeps its own
    if n > top:
        return top, f"f/{n:g} is narrower than NeuroLens renders; using f/{top:g}"
    return n, None
