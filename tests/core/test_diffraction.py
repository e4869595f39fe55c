"""Diffraction at the stop (core.diffraction): the Fraunhofer table against the Airy pattern,
spike counts of bladed stops, the turn of a ray against its wavelength, and rays that stay
finite unit vectors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from neurolens_addon.core import diffraction as D
from neurolens_addon.core.aperture import CircularAperture, PolygonAperture
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.paraxial import paraxial_data

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def bessel_j(n: int, x: float) -> float:
    """J_n(x) = (1/pi) int_0^pi cos(n t - x sin t) dt (Bessel's integral), by Simpson's rule."""
    t = np.linspace(0.0, math.pi, 4001)
    f = np.cos(n * t - x * np.sin(t))
    h = t[1] - t[0]
    return float(h / 3 * (f[0] + f[-1] + 4 * f[1:-1:2].sum() + 2 * f[2:-1:2].sum()) / math.pi)


def test_01_circular_stop_gives_the_airy_pattern():
    """The circle's table holds the Airy pattern: its encircled energy at every radial edge up
    to 8.5 cycles per pupil radius matches Rayleigh's 1 - J0(v)^2 - J1(v)^2, v = 2 pi rho,
    within 0.003 (84 % inside the first dark ring, rho = 0.61), and the table holds > 99.5 %
    of the pattern's energy (Parseval)."""
    t = D.table_for(None)
    ee = np.cumsum(t.energy.sum(axis=1))
    checked = 0
    for k, rho in enumerate(t.rho_edges[1:]):
        if rho > 8.5:
            break
        v = 2.0 * math.pi * rho
        assert abs(ee[k] - (1.0 - bessel_j(0, v) ** 2 - bessel_j(1, v) ** 2)) < 3e-3, rho
        checked += 1
    assert checked > 30
    assert t.captured > 0.995


def spikes(aperture, rng, n=1_500_000):
    """Directions (degrees, 0..360) of the spikes: peaks of the pattern's azimuth histogram
    (1 degree bins, smoothed over 5) far beyond the core (10 to 150 cycles per radius, where
    spikes are narrow) standing more than three times above the median."""
    fx, fy = D.sample_frequency(D.table_for(aperture), rng.random(n), rng.random(n))
    r = np.hypot(fx, fy)
    far = (r > 10.0) & (r < 150.0)
    h, _ = np.histogram(np.degrees(np.arctan2(fy[far], fx[far])) % 360.0, bins=360,
                        range=(0.0, 360.0))
    hs = np.convolve(np.r_[h[-2:], h, h[:2]], np.ones(5) / 5.0, "same")[2:-2]
    med = np.median(hs)
    return [i + 0.5 for i in range(360)
            if hs[i] >= hs[i - 1] and hs[i] > hs[(i + 1) % 360] and hs[i] > 3.0 * med]


@pytest.mark.parametrize("blades,expected", [(5, 10), (6, 6), (7, 14), (8, 8), (9, 18),
                                             (10, 10)])
def test_02_straight_blades_give_n_spikes_for_even_n_and_2n_for_odd(blades, expected):
    """A polygon stop of N straight blades: N spikes for even N (opposite edges are parallel
    and share theirs), 2N for odd N, evenly spaced (360 / count within 2 degrees)."""
    found = spikes(PolygonAperture(blades), np.random.default_rng(blades))
    assert len(found) == expected
    gaps = np.diff(np.r_[found, found[0] + 360.0])
    assert np.all(np.abs(gaps - 360.0 / expected) < 2.0)


def test_03_spikes_turn_with_the_blades_and_round_blades_have_none():
    """A hexagon turned by 15 degrees turns its spikes by 15 degrees (spikes stand
    perpendicular to the edges); a round stop and fully curved blades show none."""
    rng = np.random.default_rng(3)
    base = np.array(spikes(PolygonAperture(6), rng))
    turned = np.array(spikes(PolygonAperture(6, rotation_deg=15.0), rng))
    assert len(base) == len(turned) == 6
    diff = (turned - base - 15.0 + 180.0) % 360.0 - 180.0
    assert np.all(np.abs(diff) < 2.0)
    assert spikes(CircularAperture(), rng) == []
    assert spikes(PolygonAperture(7, curvature=1.0), rng) == []


def test_04_the_turn_scales_with_wavelength_over_the_pupil_radius():
    """The same uniforms at 450 and 650 nm turn an axial ray by angles whose tangents are in
    the ratio 650 / 450 (to 1e-9), and the angle is lambda f / R_ep: the first dark ring of a
    circular pupil of radius 1 mm at 550 nm lies at 1.22 lambda / D = 3.36e-4 rad (the
    sampled angles' density has its minimum within the table's radial bin, 10 %, of it)."""
    rng = np.random.default_rng(4)
    n = 400_000
    u1, u2 = rng.random(n), rng.random(n)
    axis = np.tile(np.array([[0.0], [0.0], [1.0]]), (1, n))
    t = D.table_for(PolygonAperture(6))
    blue = D.diffract(axis, 450.0, 2.0, t, u1, u2)
    red = D.diffract(axis, 650.0, 2.0, t, u1, u2)
    tb = np.hypot(blue[0], blue[1]) / blue[2]
    tr = np.hypot(red[0], red[1]) / red[2]
    np.testing.assert_allclose(tr, tb * 650.0 / 450.0, rtol=1e-9)
    # the ray's own spike length: the 99th percentile of the turn grows as lambda
    assert np.percentile(tr, 99) / np.percentile(tb, 99) == pytest.approx(650 / 450, rel=1e-6)
    circ = D.diffract(axis, 550.0, 1.0, D.table_for(None), u1, u2)
    theta = np.arctan2(np.hypot(circ[0], circ[1]), circ[2])
    zero = 1.22 * 550e-6 / 2.0
    h, edges = np.histogram(theta, bins=80, range=(0.2 * zero, 1.6 * zero))
    ring = 2 * math.pi * 0.5 * (edges[1:] + edges[:-1])           # density per unit area
    found = 0.5 * (edges[np.argmin(h / ring)] + edges[np.argmin(h / ring) + 1])
    assert found == pytest.approx(zero, rel=0.1)


def test_05_tangent_frame_is_orthonormal_and_turned_rays_stay_finite_units():
    """e_1, e_2 and d are orthonormal for directions over the whole sphere but -z (grazing and
    backward-leaning included); diffract returns finite unit vectors there, for uniforms at
    0 and just below 1, and keeps an axial ray's frame the lens's x and y."""
    rng = np.random.default_rng(5)
    d = rng.normal(size=(3, 20000))
    d[:, :3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.6, -0.8]]
    d /= np.linalg.norm(d, axis=0)
    d = d[:, d[2] > -0.999]
    e1, e2 = D.tangent_frame(d)
    for a, b in ((e1, e1), (e2, e2)):
        np.testing.assert_allclose((a * b).sum(axis=0), 1.0, atol=1e-9)
    for a, b in ((e1, e2), (e1, d), (e2, d)):
        np.testing.assert_allclose((a * b).sum(axis=0), 0.0, atol=1e-9)
    x, y = D.tangent_frame(np.array([[0.0], [0.0], [1.0]]))
    np.testing.assert_allclose(x[:, 0], [1, 0, 0])
    np.testing.assert_allclose(y[:, 0], [0, 1, 0])
    n = d.shape[1]
    u = np.where(rng.random(n) < 0.5, 0.0, np.nextafter(1.0, 0.0))
    out = D.diffract(d, 780.0, 0.05, D.table_for(PolygonAperture(5)), u, u[::-1])
    assert np.isfinite(out).all()
    np.testing.assert_allclose(np.linalg.norm(out, axis=0), 1.0, atol=1e-12)


@pytest.mark.parametrize("name", ["double_gauss_50mm_f2", "telephoto_f5_6", "fisheye_f4"])
def test_06_pupil_radius_is_the_paraxial_entrance_pupils(name):
    """The pattern's scale R_ep is the paraxial entrance pupil: EFL / 2N at the design stop,
    and proportional to the stop radius (half the radius, half the pupil)."""
    lens = load_lens(ROOT / "presets" / "lenses" / f"{name}.toml")
    pd = paraxial_data(lens)
    r = D.entrance_pupil_radius_mm(lens, lens.stop_radius_mm)
    assert r == pytest.approx(pd.efl_mm / (2.0 * pd.f_number), rel=1e-9)
    assert D.entrance_pupil_radius_mm(lens, 0.5 * lens.stop_radius_mm) == pytest.approx(0.5 * r)


def test_07_tables_are_normalised_monotone_cdfs():
    """Every table is a CDF: the marginal and each row rise from 0 to 1 without falling."""
    for ap in (None, PolygonAperture(9, 10.0, 0.4)):
        t = D.table_for(ap)
        assert t.marginal[0] == 0.0 and t.marginal[-1] == 1.0
        assert np.all(np.diff(t.marginal) >= 0.0)
        assert np.all(t.conditional[:, 0] == 0.0) and np.all(t.conditional[:, -1] == 1.0)
        assert np.all(np.diff(t.conditional, axis=1) >= 0.0)
        assert t.rho_edges[-1] == D.RHO_MAX
