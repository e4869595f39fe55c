"""core.film, the one film conversion: sensor fit, pixel aspect, percentage, shift and render
region against the formulas Blender documents (and Cycles' own camera, in tests/cycles)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from neurolens_addon.core.film import FilmError, FilmSettings, film_from_settings, pixel_counts


def _expected(s: FilmSettings):
    """Blender's sensor fit written out directly (the reference the module must match)."""
    rx = max(1, int(s.resolution_x * s.percentage / 100.0))
    ry = max(1, int(s.resolution_y * s.percentage / 100.0))
    ax, ay = rx * s.pixel_aspect_x, ry * s.pixel_aspect_y
    fit = s.sensor_fit
    if fit == "AUTO":
        fit = "HORIZONTAL" if ax >= ay else "VERTICAL"
        size = s.sensor_width
    else:
        size = s.sensor_width if fit == "HORIZONTAL" else s.sensor_height
    w, h = (size, size * ay / ax) if fit == "HORIZONTAL" else (size * ax / ay, size)
    return rx, ry, w, h


CASES = [FilmSettings(sw, sh, fit, rx, ry, pct, pax, pay, shx, shy)
         for sw, sh in ((36.0, 24.0), (23.76, 13.365))
         for fit in ("AUTO", "HORIZONTAL", "VERTICAL")
         for rx, ry in ((1920, 1080), (1080, 1920), (640, 640), (1001, 333))
         for pct in (100.0, 50.0, 33.0)
         for pax, pay in ((1.0, 1.0), (2.0, 1.0))
         for shx, shy in ((0.0, 0.0), (0.1, -0.25))]


@pytest.mark.parametrize("s", CASES[::5] + CASES[1::7])
def test_film_follows_blenders_sensor_fit(s):
    film = film_from_settings(s)
    rx, ry, w, h = _expected(s)
    assert (film.width_px, film.height_px) == (rx, ry)
    assert film.size_mm == pytest.approx((w, h), rel=1e-12)
    big = max(w, h)
    assert (film.shift_x_mm, film.shift_y_mm) == pytest.approx((s.shift_x * big, s.shift_y * big))
    # pixel centres span the frame symmetrically about the (shifted) axis
    p, q = film.image_points(np.array([0, rx - 1]), np.array([0, ry - 1]), 0.5, 0.5)
    assert p[0] + p[1] == pytest.approx(2 * film.shift_x_mm)
    assert q[1] - q[0] == pytest.approx(h * (ry - 1) / ry)
    # the radius reaches the farthest corner, shift included
    corners = [math.hypot(x, y) for x in (film.rect_mm()[0], film.rect_mm()[2])
               for y in (film.rect_mm()[1], film.rect_mm()[3])]
    assert film.radius_mm == pytest.approx(max(corners))
    assert film.pixel_pitch_mm == pytest.approx(min(w / rx, h / ry))


def test_render_region_keeps_its_part_of_the_frame():
    full = film_from_settings(FilmSettings(36.0, 24.0, "HORIZONTAL", 1000, 500))
    quarter = film_from_settings(FilmSettings(36.0, 24.0, "HORIZONTAL", 1000, 500,
                                              border=(0.5, 0.5, 1.0, 1.0)))
    assert quarter.rect_mm() == pytest.approx((0.0, 0.0, 18.0, 9.0))
    assert quarter.radii_mm() == pytest.approx((0.0, math.hypot(18.0, 9.0)))
    off = film_from_settings(FilmSettings(36.0, 24.0, "HORIZONTAL", 1000, 500,
                                          border=(0.75, 0.75, 1.0, 1.0)))
    assert off.radii_mm()[0] == pytest.approx(math.hypot(9.0, 4.5))
    assert full.radii_mm() == pytest.approx((0.0, math.hypot(18.0, 9.0)))


@pytest.mark.parametrize("bad, word", [
    (dict(sensor_fit="DIAGONAL"), "sensor fit"),
    (dict(resolution_x=0), "resolution_x"),
    (dict(percentage=float("nan")), "percentage"),
    (dict(sensor_width=-1.0), "sensor size"),
    (dict(shift_x=float("inf")), "shift"),
    (dict(border=(0.5, 0.0, 0.5, 1.0)), "render region"),
    (dict(pixel_aspect_y=0.0), "pixel aspect"),
])
def test_settings_that_describe_no_image_are_refused_by_name(bad, word):
    with pytest.raises(FilmError, match=word):
        film_from_settings(FilmSettings(**bad))


def test_pixel_counts_truncate_as_blender_does():
    assert pixel_counts(1001, 333, 50.0) == (500, 166)
    assert pixel_counts(3, 3, 1.0) == (1, 1)


def test_pixels_of_inverts_image_points_and_refuses_points_off_the_frame():
    """pixels_of (the flare's splat) gives back the pixel whose area image_points spans, with a
    lens shift and on an anamorphic lens's narrower film too, and -1 just outside."""
    f = film_from_settings(FilmSettings(resolution_x=64, resolution_y=36, shift_x=0.1))
    for film in (f, f.on_lens(2.0)):
        rng = np.random.default_rng(2)
        ix, iy = rng.integers(0, 64, 500), rng.integers(0, 36, 500)
        p, q = film.image_points(ix, iy, rng.uniform(0.01, 0.99, 500),
                                 rng.uniform(0.01, 0.99, 500))
        np.testing.assert_array_equal(film.pixels_of(p, q), iy * 64 + ix)
        x0, y0, x1, y1 = film.rect_mm()
        assert (film.pixels_of([x0 - 1e-6, x1 + 1e-6, 0.0], [0.0, 0.0, y1 + 1e-6]) == -1).all()
    assert f.pixel_area_mm2 == pytest.approx(2.0 * f.on_lens(2.0).pixel_area_mm2)
