"""Gaps that move (core.variable_gaps, the [focus] and [zoom] tables of a lens file).

The interpolation reproduces every tabulated position exactly, is monotone and C1 between;
a rear-focusing double Gauss (its rear group moved forward, built here by solving the close
position's gaps independently) focuses by moving the group with the sensor fixed, breathes
(its focal length changes at close focus, which a unit-focusing lens's does not), and its
tables survive the TOML round trip and are checked with one-line errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from neurolens_addon.core.errors import FocusError, LensError
from neurolens_addon.core.focus import closest_focus_mm, focus_sensor_z
from neurolens_addon.core.lensfile import dump_lens, load_lens, loads_lens
from neurolens_addon.core.paraxial import paraxial_data, paraxial_image_z
from neurolens_addon.core.variable_gaps import (VariableGaps, focus_position, lens_at, pchip,
                                                zoom_position)
from neurolens_addon.camera.lenses import PRESETS_DIR

DGAUSS = PRESETS_DIR / "double_gauss_50mm_f2.toml"
CLOSE_MM = 2000.0
STOP_GAP, LAST_GAP = 5, 10          # 0-based: stop -> rear group, last surface -> sensor


def _moved(lens, delta):
    """The rear group moved forward by delta (sensor fixed)."""
    t = list(s.thickness_mm for s in lens.surfaces)
    return t[STOP_GAP] - delta, t[LAST_GAP] + delta


def rear_focusing_lens():
    """The double Gauss with a [focus] table: infinity and CLOSE_MM, the close gaps solved by
    bisection on the paraxial image here (independently of core.variable_gaps)."""
    lens = load_lens(DGAUSS)

    def image_z(delta):
        a, b = _moved(lens, delta)
        table = VariableGaps((math.inf, CLOSE_MM), (STOP_GAP, LAST_GAP), ((a, a), (b, b)))
        moved = lens_at(lens.__class__(**{**lens.__dict__, "focus_gaps": table}), focus=0.0)
        return paraxial_image_z(moved, CLOSE_MM)
    lo, hi = 0.0, 4.4                    # the stop gap is 4.5 mm
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if (image_z(mid) > 0) == (image_z(lo) > 0):
            lo = mid
        else:
            hi = mid
    assert 0.01 < lo < 4.39                      # the bracket holds the travel
    a, b = _moved(lens, 0.5 * (lo + hi))
    t0 = [s.thickness_mm for s in lens.surfaces]
    table = VariableGaps((math.inf, CLOSE_MM), (STOP_GAP, LAST_GAP),
                         ((t0[STOP_GAP], a), (t0[LAST_GAP], b)))
    return lens.__class__(**{**lens.__dict__, "focus_gaps": table})


def test_01_the_interpolation_reproduces_the_table_and_stays_monotone():
    y = [1.86, 25.27, 48.678, 30.0]
    for k, v in enumerate(y):
        assert pchip(y, k) == v
    s = np.linspace(0, 3, 301)
    g = np.array([pchip(y, x) for x in s])
    assert np.all(np.diff(g[:201]) >= 0)                   # rising data: no dip
    assert np.all(np.diff(g[200:]) <= 0)                   # falling data: no bump
    assert g.max() <= max(y) + 1e-12                       # no overshoot at the peak
    # C1: one-sided slopes agree at an inner knot
    h = 1e-6
    left = (pchip(y, 1) - pchip(y, 1 - h)) / h
    right = (pchip(y, 1 + h) - pchip(y, 1)) / h
    assert left == pytest.approx(right, rel=1e-3)
    assert pchip([2.0, 5.0], 0.25) == pytest.approx(2.75)  # two positions: linear


def test_02_focusing_moves_the_group_and_keeps_the_sensor():
    lens = rear_focusing_lens()
    assert focus_position(lens, math.inf) == 0.0
    assert focus_position(lens, CLOSE_MM) == pytest.approx(1.0, abs=1e-9)
    for d in (20000.0, 5000.0, 3000.0):
        s = focus_position(lens, d)
        assert 0.0 < s < 1.0
        assert paraxial_image_z(lens_at(lens, focus=s), d) == pytest.approx(0.0, abs=1e-9)
    # the exact best-focus sensor of the moved lens stays near where it is at infinity (the
    # aperture's own focus shift; aberrations change a little at close focus), while unit
    # focusing moves the sensor ten times as far
    moved = lens_at(lens, focus=focus_position(lens, 3000.0))
    at_inf = focus_sensor_z(lens, math.inf)
    unit = focus_sensor_z(load_lens(DGAUSS), 3000.0) - at_inf
    assert abs(focus_sensor_z(moved, 3000.0) - at_inf) < 0.1 * abs(unit)
    assert closest_focus_mm(lens) == CLOSE_MM
    with pytest.raises(FocusError, match="no closer than 2.000 m"):
        focus_position(lens, 1900.0)


def test_03_internal_focusing_breathes_where_unit_focusing_does_not():
    lens = rear_focusing_lens()
    f_inf = paraxial_data(lens).efl_mm
    f_close = paraxial_data(lens_at(lens, focus=1.0)).efl_mm
    assert abs(f_close / f_inf - 1.0) > 0.01               # the focal length changes
    # unit focusing moves the whole lens: its focal length stays
    assert paraxial_data(load_lens(DGAUSS)).efl_mm == pytest.approx(f_inf, rel=1e-12)


def test_04_the_tables_round_trip_through_toml_and_scale():
    lens = rear_focusing_lens()
    text = dump_lens(lens)
    assert "[focus]" in text and "distances_mm = [inf, 2000.0]" in text
    back = loads_lens(text)
    assert back.focus_gaps == lens.focus_gaps and back == lens
    assert back.content_hash() != load_lens(DGAUSS).content_hash()
    scaled = loads_lens(text.replace('name = ', 'scale = 2.0\nname = ', 1))
    assert scaled.focus_gaps.positions[1] == 2 * CLOSE_MM
    assert scaled.focus_gaps.thickness_mm[0][1] == pytest.approx(
        2 * lens.focus_gaps.thickness_mm[0][1])


@pytest.mark.parametrize("edit,match", [
    (lambda t: t.replace("distances_mm = [inf, 2000.0]", "distances_mm = [2000.0, inf]"),
     r"first focus position must be inf"),
    (lambda t: t.replace("distances_mm = [inf, 2000.0]", "distances_mm = [inf]"),
     r"at least 2 positions"),
    (lambda t: t.replace("thickness = { 6 = [", "thickness = { 60 = [", 1),
     r"'60' is not a surface number"),
    (lambda t: t.replace("thickness = { 6 = [4.5,", "thickness = { 6 = [4.6,", 1),
     r"surface 6.*differs from the surface's own thickness"),
    (lambda t: t.replace("[focus]", "[zoom]").replace("distances_mm", "focal_lengths_mm"),
     r"zoom.focal_lengths_mm"),
])
def test_05_bad_tables_give_one_line_errors(edit, match):
    text = dump_lens(rear_focusing_lens())
    with pytest.raises(LensError, match=match) as err:
        loads_lens(edit(text), path="if.toml")
    assert "\n" not in str(err.value)


def test_06_zoom_positions_reproduce_the_stated_focal_lengths():
    """A two-position 'zoom' made of the double Gauss with its central air space changed:
    the stated focal lengths give the tabulated positions exactly, and a focal length between
    lands on a position whose paraxial focal length is between the two."""
    lens = load_lens(DGAUSS)
    t = [s.thickness_mm for s in lens.surfaces]
    table = VariableGaps((50.0, 60.0), (4,), ((t[4], t[4] + 6.0),))
    zoomy = lens.__class__(**{**lens.__dict__, "zoom_gaps": table})
    assert zoom_position(zoomy, 50.0) == 0.0 and zoom_position(zoomy, 60.0) == 1.0
    f0 = paraxial_data(zoomy).efl_mm
    f1 = paraxial_data(lens_at(zoomy, zoom=1.0)).efl_mm
    s = zoom_position(zoomy, 55.0)
    f = paraxial_data(lens_at(zoomy, zoom=s)).efl_mm
    assert 0 < s < 1 and f == pytest.approx(f0 + 0.5 * (f1 - f0), rel=1e-9)
    with pytest.raises(ValueError, match="zooms from 50 to 60 mm"):
        zoom_position(zoomy, 70.0)
