"""Paraxial data, exact focusing with breathing, and pupil-aware sampling."""

import math

import numpy as np
import pytest

from neurolens_addon.core.errors import FocusError
from neurolens_addon.core.focus import (closest_focus_mm, focus_sensor_z,
                                        focused_distance_mm)
from neurolens_addon.core.paraxial import paraxial_data, working_f_number
from neurolens_addon.core.pupil import RearPupilSampler, valid_fraction
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.trace import trace

from tests.core.lenses import double_gauss, singlet


def test_01_thick_lens_principal_planes_match_formula():
    """Principal planes of a thick singlet sit where the thick-lens formulas put them:
    h' = -f (n-1) t / (n R1) from the rear vertex, h = -f (n-1) t / (n R2) from the front."""
    n, r, t = 1.6, 40.0, 8.0
    lens = singlet(radius=r, thickness=t, nd=n)
    pd = paraxial_data(lens)
    f = pd.efl_mm
    z_front, z_rear = lens.vertex_z[1], lens.vertex_z[2]
    h_rear = -f * (n - 1) * t / (n * r)          # from the rear vertex, along the light
    h_front = -f * (n - 1) * t / (n * -r)        # from the front vertex, along the light
    assert pd.rear_principal_z_mm == pytest.approx(z_rear - h_rear, abs=1e-9)
    assert pd.front_principal_z_mm == pytest.approx(z_front - h_front, abs=1e-9)
    assert pd.rear_focal_z_mm == pytest.approx(0.0, abs=1e-9)


def test_02_front_stop_is_the_entrance_pupil():
    """With the stop in front of everything, the entrance pupil is the stop itself and the
    f-number is EFL / stop diameter."""
    lens = singlet(stop_radius=4.0)
    pd = paraxial_data(lens)
    assert pd.entrance_pupil.z_mm == pytest.approx(lens.vertex_z[0])
    assert pd.entrance_pupil.diameter_mm == pytest.approx(8.0)
    assert pd.f_number == pytest.approx(pd.efl_mm / 8.0)


def test_03_double_gauss_first_order_data():
    """The 50 mm F/2 double Gauss has EFL 50 +- 1 %, F/2 +- 3 %, and pupils inside the lens."""
    lens = double_gauss()
    pd = paraxial_data(lens)
    assert pd.efl_mm == pytest.approx(50.0, rel=0.01)
    assert pd.f_number == pytest.approx(2.0, rel=0.03)
    assert lens.rear_vertex_z < pd.entrance_pupil.z_mm < lens.front_vertex_z
    assert lens.rear_vertex_z < pd.exit_pupil.z_mm < lens.front_vertex_z
    assert working_f_number(lens, math.inf) == pytest.approx(pd.f_number)
    assert working_f_number(lens, 1000.0) > pd.f_number


def test_04_focus_at_infinity_and_breathing():
    """Focusing nearer moves the sensor away from the lens, monotonically, by about the Newton
    extension f^2 / x; the inverse recovers the distance."""
    lens = double_gauss()
    z_inf = focus_sensor_z(lens, math.inf)
    assert abs(z_inf) < 0.05
    dists = [10000.0, 3000.0, 1000.0, 600.0]
    zs = [focus_sensor_z(lens, d) for d in dists]
    assert all(a > b for a, b in zip([z_inf] + zs, zs))
    f = paraxial_data(lens).efl_mm
    ext_1m = z_inf - zs[2]
    assert ext_1m == pytest.approx(f * f / (1000.0 - 2 * f), rel=0.15)
    assert focused_distance_mm(lens, zs[1]) == pytest.approx(3000.0, rel=1e-4)


def test_05_focused_point_gives_a_small_spot():
    """At the solved sensor position the spot of an axial point at 1 m is far smaller than with
    the sensor left at the infinity position."""
    lens = double_gauss()
    z = focus_sensor_z(lens, 1000.0, stop_radius=4.0)
    def rms(sensor_z):
        phi = np.linspace(0, 2 * np.pi, 64, endpoint=False)
        r = 3.0
        pd = paraxial_data(lens)
        tgt = np.stack([r * np.cos(phi), r * np.sin(phi), np.full(64, pd.entrance_pupil.z_mm)])
        o = np.zeros((3, 64))
        o[2] = z + 1000.0
        d = tgt - o
        d /= np.linalg.norm(d, axis=0)
        res = trace(lens, Rays(o, d, np.full(64, 587.56)), from_sensor=False, stop_radius=4.0,
                    sensor_z=sensor_z)
        assert res.valid.all()
        return np.sqrt(np.mean(res.rays.o[0] ** 2 + res.rays.o[1] ** 2))
    assert rms(z) < 0.01
    assert rms(0.0) > 10 * rms(z)


def test_06_nearer_than_closest_focus_is_refused():
    """Asking for focus nearer than the closest focus raises FocusError with both distances."""
    lens = double_gauss()
    near = closest_focus_mm(lens)
    assert 250.0 < near < 800.0
    focus_sensor_z(lens, near * 1.01)
    with pytest.raises(FocusError, match="no closer than"):
        focus_sensor_z(lens, near * 0.5)
    with pytest.raises(FocusError):
        focus_sensor_z(lens, -1.0)


def test_07_pupil_sampler_wastes_few_rays_at_the_centre():
    """At full aperture at least 80 % of rays sampled for the image centre leave the lens."""
    lens = double_gauss()
    s = RearPupilSampler(lens, film_radius_mm=21.6)
    assert valid_fraction(lens, s, 0.0, 0.0) >= 0.8
    assert valid_fraction(lens, s, 15.0, 0.0) >= 0.6


def test_08_pupil_sampler_covers_every_valid_ray():
    """No valid ray lies outside the occupied cells: uniform sampling of the whole rear plane
    and the sampler's estimate of the passing area agree within 3 %."""
    lens = double_gauss()
    s = RearPupilSampler(lens, film_radius_mm=21.6, grid=64)
    rng = np.random.default_rng(8)
    n = 200000
    for sx in (0.0, 12.0):
        half = s.wide
        tx, ty = rng.uniform(-half, half, (2, n))
        o = np.stack([np.full(n, sx), np.zeros(n), np.zeros(n)])
        d = np.stack([tx - sx, ty, np.full(n, s.plane_z)])
        d /= np.linalg.norm(d, axis=0)
        res = trace(lens, Rays(o, d, np.full(n, 587.56)))
        area_valid = res.valid.mean() * (2 * half) ** 2
        band = s.band_of(np.array([sx]))[0]
        iy, ix, in_box = s.cell_index(band, tx, ty)
        inside = s.occupied[band][iy, ix] & in_box
        assert inside[res.valid].mean() > 0.999
        assert s.occupied_area(band) >= area_valid
        assert s.occupied_area(band) < 1.3 * area_valid


def test_09_irradiance_falls_off_towards_the_corner():
    """The sampler's irradiance estimate (mean weight x validity) falls from centre to corner
    (cos^4 and vignetting) and is positive everywhere on the film."""
    lens = double_gauss()
    s = RearPupilSampler(lens, film_radius_mm=21.6)
    rng = np.random.default_rng(9)
    e = []
    for x in (0.0, 10.0, 20.0):
        n = 40000
        u = rng.random((3, n))
        smp = s.sample(np.full(n, x), np.zeros(n), u[0], u[1], u[2], 587.56)
        res = trace(lens, smp.rays)
        e.append(np.mean(smp.weight * res.valid))
    assert e[0] > e[1] > e[2] > 0
