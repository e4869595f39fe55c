"""core.projection: scene points placed on the film by the chief ray, checked against the
chief ray solved independently from the scene side (testdata.chief_rays.scene_point_image:
aimed at the stop's centre by a 2-D Newton, traced to the sensor)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core.film import Film
from neurolens_addon.core.focus import focus_sensor_z
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.projection import FilmPlacement, film_radius
from neurolens_addon.core.stmap import chief_ray_table
from testdata.chief_rays import scene_point_image

LENSES = Path(__file__).resolve().parents[2] / "presets" / "lenses"


def _points(lens, table, n=120, near=300.0, seed=0):
    """n lens-space points from `near` to 20 m beyond the front vertex, anywhere in the
    table's field (3, N)."""
    rng = np.random.default_rng(seed)
    dist = rng.uniform(near, 20000.0, n)
    field = rng.uniform(0.0, min(float(table.theta[-1]), math.radians(85.0)), n)
    az = rng.uniform(0.0, 2.0 * math.pi, n)
    rho = dist * np.sin(field)
    return np.stack([rho * np.cos(az), rho * np.sin(az),
                     lens.front_vertex_z + dist * np.cos(field)]), az


@pytest.mark.parametrize("stem", ["double_gauss_50mm_f2", "ultrawide_14mm_f2_8", "fisheye_f4"])
@pytest.mark.parametrize("focus_mm", [math.inf, 1000.0])
def test_01_a_point_lands_where_its_chief_ray_does(stem, focus_mm):
    """Points from 0.3 to 20 m, anywhere in the field: the film radius within 1e-5 mm of the
    independent scene-side chief ray's (a thousandth of a 10 um pixel), at the point's own
    azimuth; the entrance pupil moving with the field (the 14 mm's moves millimetres) is what
    makes near points land right."""
    lens = load_lens(LENSES / f"{stem}.toml")
    z = focus_sensor_z(lens, focus_mm)
    table = chief_ray_table(lens, z, 21.6 if stem != "fisheye_f4" else 12.0)
    pts, az = _points(lens, table)
    p, q, ok = scene_point_image(lens, z, pts)
    r, placed = film_radius(table, np.hypot(pts[0], pts[1]), pts[2])
    both = ok & placed
    assert both.sum() >= 0.7 * both.size
    assert np.abs(np.hypot(p, q) - r)[both].max() < 1e-5
    far = both & (r > 0.1)
    turn = np.angle(np.exp(1j * (np.arctan2(q, p) - az)))
    assert np.abs(turn[far]).max() < 1e-9
    span = np.ptp(table.axis_z)
    if stem == "ultrawide_14mm_f2_8":
        assert span > 1.0                    # the pupil moves: a fixed one would misplace


def test_02_points_the_lens_does_not_image_are_not_placed():
    """Behind the entrance pupil, beyond the table's field, and on the axis (placed at the
    centre)."""
    lens = load_lens(LENSES / "double_gauss_50mm_f2.toml")
    z = focus_sensor_z(lens, math.inf)
    table = chief_ray_table(lens, z, 21.6)
    zc = float(table.axis_z[0])
    r, placed = film_radius(table, np.array([10.0, 1e6, 0.0]),
                            np.array([zc - 5.0, zc + 10.0, zc + 1000.0]))
    assert placed.tolist() == [False, False, True]
    assert r.tolist()[:2] == [0.0, 0.0] and r[2] == 0.0


def test_03_pixels_follow_the_film():
    """A point on the axis lands on the frame's centre, shifted with the lens shift; a point
    to the right and above lands right of and above it (rows from the bottom)."""
    lens = load_lens(LENSES / "double_gauss_50mm_f2.toml")
    z = focus_sensor_z(lens, math.inf)
    table = chief_ray_table(lens, z, 25.0)
    place = FilmPlacement(table, Film(480, 320, 36.0, 24.0))
    shifted = FilmPlacement(table, Film(480, 320, 36.0, 24.0, shift_x_mm=3.6))
    pts = np.array([[0.0, 0.0, 5000.0], [500.0, 300.0, 5000.0]])
    px, ok = place.pixels(pts)
    assert ok.all() and px[0].tolist() == [240.0, 160.0]
    assert px[1, 0] > 240.0 and px[1, 1] > 160.0
    # the pinhole of the same focal length puts it within the lens's small distortion
    f = table.f_p_mm
    pin = 240.0 + f * 500.0 / (5000.0 - table.axis_z[0]) / 36.0 * 480.0
    assert px[1, 0] == pytest.approx(pin, rel=0.01)
    spx, _ = shifted.pixels(pts)
    assert spx[0, 0] == pytest.approx(240.0 - 48.0)
