"""Gaps that move: internal focusing and zooming, as lens designs tabulate them.

A lens file may give the thickness of some surfaces (air gaps) at n >= 2 focus positions,
object distances D_0 = inf > D_1 > ... from the sensor (patents tabulate infinity and the
closest focus), or at n >= 2 zoom positions, the stated focal lengths f_0 < f_1 < ... A
position parameter s in [0, n - 1] (s = k: the k-th tabulated position) sets every moving gap
by monotone piecewise-cubic Hermite interpolation through its tabulated values (Fritsch and
Carlson 1980, slopes d_k from the secants delta_k with the harmonic-mean rule, d = 0 where the
secants change sign; two positions: linear):
    g(s) = h00(t) g_k + h10(t) d_k + h01(t) g_(k+1) + h11(t) d_(k+1),  t = s - k,  k = floor(s)
so the table is reproduced exactly at s = k, gaps are C1-smooth between, and a gap that grows
between two positions never overshoots them (a group does not travel past where the design
puts it).

Focusing: for an object at D (from the sensor), s solves z_img(s, D) = 0, the paraxial image
of the axial object point on the design image plane, by bisection on [0, n - 1]: the sensor
stays put while the group moves, as in the real lens (core.focus then finds the small exact
best-focus residual on the moved lens). The closest focus is the last tabulated distance.
Zoom: for a focal length f in [f_0, f_(n-1)], s solves efl(s) = F(f), F mapping the stated
focal lengths piecewise linearly onto the paraxial ones at the tabulated positions, so that the
stated f_k gives s = k and the tabulated gaps exactly.

Zoom stops: a constant-aperture zoom opens its iris as it zooms (its entrance pupil grows with
the focal length). A [zoom] table may carry the stop's semi-diameter per position r_k (r_0 the
stop surface's own); lens_at interpolates it as it does the gaps, r(s) = pchip(r, s). A lens
that lens_at(..., zoom=s) returns carries its own design (widest) f-number there:
    N(s) = N_file * P(lens at s) / P(file lens)
P the paraxial f-number at infinity (efl / entrance pupil diameter), N_file the file's stated
f_number. With a stop solved per position for the stated f-numbers N_k (P_k = N_k) this gives
N_k at s = k (between two positions it is what the interpolated stop and gaps give, not held
at the stated values: within 2.5 % for the zoom presets, 4.6 % for the Nikon 24-70's wide
24.78 -> 51.92 mm interval; tests/core/test_zoom_stops.py); without a stop table it
is a variable-aperture zoom's f-number (the full stop's P changes along the zoom). So
stop_radius_for_f_number(moved.stop_radius_mm, moved.f_number, N) sets any f-number on the
moved lens. The table may also list the stated f-numbers
(`f_numbers`, N_0 = the file's f_number): information, checked by the tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .errors import FocusError, LensError
from .prescription import Lens

#: bisection stops below this change of the position parameter
POSITION_TOLERANCE = 1e-12
#: the most positions a table may hold (patents tabulate 2 to 5; a .zmx file's
#: configurations are positions too): every position is validated when a lens is loaded, and
#: a lens's per-position models are looked up position by position
MAX_POSITIONS = 64


def _slope(y, k: int) -> float:
    """The Fritsch-Carlson slope at knot k of unit-spaced values y (module docstring), from
    its neighbours alone: evaluating the interpolant costs the same at any table length (a
    loop over every position stays linear in the positions)."""
    n = len(y)
    if n == 2:
        return float(y[1]) - float(y[0])
    if 0 < k < n - 1:
        a, b = float(y[k]) - float(y[k - 1]), float(y[k + 1]) - float(y[k])
        return 0.0 if a * b <= 0.0 else 2.0 * a * b / (a + b)
    # one-sided three-point ends, limited so that monotone data stays monotone
    if k == 0:
        a, b = float(y[1]) - float(y[0]), float(y[2]) - float(y[1])
    else:
        a, b = float(y[-1]) - float(y[-2]), float(y[-2]) - float(y[-3])
    e = (3.0 * a - b) / 2.0
    if e * a <= 0.0:
        e = 0.0
    elif a * b <= 0.0 and abs(e) > abs(3.0 * a):
        e = 3.0 * a
    return e


def pchip(values, s: float) -> float:
    """The monotone cubic Hermite interpolant through values at 0, 1, ..., n - 1, at s."""
    n = len(values)
    s = min(max(float(s), 0.0), n - 1.0)
    k = min(int(math.floor(s)), n - 2)
    t = s - k
    y0, y1 = float(values[k]), float(values[k + 1])
    if t == 0.0:
        return y0                  # (the table itself: h00 = 1, every other basis 0)
    d0, d1 = _slope(values, k), _slope(values, k + 1)
    h00 = 2 * t ** 3 - 3 * t ** 2 + 1
    h10 = t ** 3 - 2 * t ** 2 + t
    h01 = -2 * t ** 3 + 3 * t ** 2
    h11 = t ** 3 - t ** 2
    return float(h00 * y0 + h10 * d0 + h01 * y1 + h11 * d1)


@dataclass(frozen=True)
class VariableGaps:
    """Thicknesses of some surfaces per tabulated position (focus distances or focal lengths)."""

    positions: tuple[float, ...]                # focus: mm from the sensor (inf first); zoom: mm
    surfaces: tuple[int, ...]                   # 0-based indices of the moving gaps
    thickness_mm: tuple[tuple[float, ...], ...]  # per moving surface, per position
    #: zoom only: the stop's semi-diameter per position (mm; the first is the stop surface's)
    stop_semi_diameter_mm: tuple[float, ...] | None = None
    #: zoom only: the stated f-number per position (information; the first is the file's)
    f_numbers: tuple[float, ...] | None = None

    def __post_init__(self):
        # bounded by design: the readers refuse longer tables naming the file; a table built
        # in code is held to the same cap
        if len(self.positions) > MAX_POSITIONS:
            raise LensError(f"{len(self.positions)} positions; a [focus] or [zoom] table holds "
                            f"at most {MAX_POSITIONS}")

    @property
    def count(self) -> int:
        return len(self.positions)

    def gaps(self, s: float) -> dict[int, float]:
        """Surface index -> thickness at position parameter s."""
        return {i: pchip(t, s) for i, t in zip(self.surfaces, self.thickness_mm)}

    def stop_radius(self, s: float) -> float | None:
        """The stop's semi-diameter at position parameter s; None without a stop column."""
        if self.stop_semi_diameter_mm is None:
            return None
        return pchip(self.stop_semi_diameter_mm, s)


def lens_at(lens: Lens, *, focus: float | None = None, zoom: float | None = None,
            design_f_number: bool = True) -> Lens:
    """The lens with its moving gaps at the given position parameters (None: the file's); a
    zoom also sets the stop's semi-diameter (when the table has a stop column) and the
    lens's f_number to its design f-number there (module docstring). `design_f_number=False`
    skips that f-number (two paraxial traces) and leaves the lens's own: for searches that
    only need the gaps (zoom_position's and focus_position's bisections)."""
    table = lens.zoom_gaps if zoom is not None else None
    zoom_changes = table.gaps(zoom) if table is not None else {}
    stop_r = table.stop_radius(zoom) if table is not None else None
    focus_changes = (lens.focus_gaps.gaps(focus)
                     if lens.focus_gaps is not None and focus is not None else {})
    if not zoom_changes and stop_r is None and not focus_changes:
        return lens
    stop = lens.stop_index if stop_r is not None else -1

    def moved(changes):
        return lens.with_surfaces(
            replace(sf, thickness_mm=changes.get(i, sf.thickness_mm),
                    semi_diameter_mm=stop_r if i == stop else sf.semi_diameter_mm)
            if i in changes or i == stop else sf for i, sf in enumerate(lens.surfaces))
    out = moved({**zoom_changes, **focus_changes})
    if table is not None and design_f_number:
        from .paraxial import paraxial_data
        zoomed = moved(zoom_changes) if focus_changes else out
        n = float(lens.f_number) * paraxial_data(zoomed).f_number / paraxial_data(lens).f_number
        out = replace(out, f_number=n)
    return out


#: a value within this relative distance of a tabulated one is that position: Blender keeps
#: focal lengths and focus distances in float32 (24.7 reads back as 24.70000076), and a
#: position's learned model matches only its tabulated gaps (camera.models: by content hash)
TABULATED_REL_TOL = 1e-6


def tabulated_index(positions, value: float) -> int | None:
    """The index of the tabulated position `value` names (within TABULATED_REL_TOL), or None."""
    for k, p in enumerate(positions):
        if math.isclose(float(p), float(value), rel_tol=TABULATED_REL_TOL):
            return k
    return None


def tabulated_position(lens: Lens, table: "VariableGaps | None") -> int | None:
    """The tabulated position k whose gaps the lens stands at (lens_at(..., k)), or None."""
    if table is None:
        return None
    for k in range(table.count):
        if all(math.isclose(lens.surfaces[i].thickness_mm, col[k], rel_tol=1e-12, abs_tol=1e-12)
               for i, col in zip(table.surfaces, table.thickness_mm)):
            return k
    return None


def position_lenses(lens: Lens):
    """The lens at each tabulated zoom and focus position other than the file's own, one at a
    time: ("zoom" | "focus", k, lens_at(...)) (the lenses per-position models learn). Made as
    asked, so a search stops at the position it looks for."""
    for key, table in (("zoom", lens.zoom_gaps), ("focus", lens.focus_gaps)):
        if table is not None:
            for k in range(1, table.count):
                yield key, k, lens_at(lens, **{key: float(k)})


def _bisect(f, lo: float, hi: float) -> float:
    flo = f(lo)
    for _ in range(200):
        if hi - lo < POSITION_TOLERANCE:
            break
        mid = 0.5 * (lo + hi)
        fm = f(mid)
        if (fm > 0) == (flo > 0):
            lo, flo = mid, fm
        else:
            hi = mid
    return 0.5 * (lo + hi)


def focus_position(lens: Lens, distance_mm: float, zoom: float | None = None) -> float:
    """The focus position parameter that images an object `distance_mm` from the sensor on
    the design image plane (inf: 0). FocusError nearer than the last tabulated distance."""
    from .paraxial import paraxial_image_z
    table = lens.focus_gaps
    if table is None:
        raise FocusError(f"lens '{lens.name}' has no focusing group (it focuses as a unit)")
    d = float(distance_mm)
    if math.isinf(d):
        return 0.0
    near = table.positions[-1]
    if not d >= near * (1.0 - TABULATED_REL_TOL):
        raise FocusError(f"lens '{lens.name}' focuses no closer than {near / 1000.0:.3f} m "
                         f"(asked for {d / 1000.0:.3f} m)")

    # a tabulated distance is that position exactly: the patent's own state (its distances
    # are printed rounded, so the paraxial solve lands a hair off the tabulated gaps); the
    # table holds the first zoom position's spacings, so only a lens standing there snaps
    at_first_zoom = not zoom and tabulated_position(lens, lens.zoom_gaps) in (None, 0)
    k = tabulated_index(table.positions, d) if at_first_zoom else None
    if k is not None:
        return float(k)

    def image_z(s):
        return paraxial_image_z(lens_at(lens, focus=s, zoom=zoom, design_f_number=False), d)
    last = table.count - 1.0
    lo, hi = image_z(0.0), image_z(last)
    if lo == 0.0:
        return 0.0
    if (lo > 0) == (hi > 0):
        # the design does not bracket this distance on its sensor: take the nearer end
        return 0.0 if abs(lo) <= abs(hi) else last
    return _bisect(image_z, 0.0, last)


def zoom_position(lens: Lens, focal_length_mm: float) -> float:
    """The zoom position parameter of a focal length within the stated range."""
    from .paraxial import paraxial_data
    table = lens.zoom_gaps
    if table is None:
        raise ValueError(f"lens '{lens.name}' does not zoom")
    stated = np.asarray(table.positions, dtype=np.float64)
    f = float(focal_length_mm)
    if not stated[0] * (1 - TABULATED_REL_TOL) <= f <= stated[-1] * (1 + TABULATED_REL_TOL):
        raise ValueError(f"lens '{lens.name}' zooms from {stated[0]:g} to {stated[-1]:g} mm, "
                         f"not {f:g} mm")
    k = tabulated_index(stated, f)
    if k is not None:
        return float(k)
    f = min(max(f, float(stated[0])), float(stated[-1]))

    def efl(s):
        return paraxial_data(lens_at(lens, zoom=s, design_f_number=False)).efl_mm
    paraxial = np.array([efl(float(i)) for i in range(table.count)])
    target = float(np.interp(f, stated, paraxial))
    j = int(np.searchsorted(stated, f) - 1)
    return _bisect(lambda s: efl(s) - target, float(j), float(j + 1))
