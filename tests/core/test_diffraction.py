"""Diffraction at the stop (core.diffraction): the Fraunhofer pattern against the Airy pattern,
spike counts of bladed stops, spike length against wavelength, and kernels that keep the
image's energy."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core import diffraction as D
from neurolens_addon.core.aperture import CircularAperture, PolygonAperture
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.paraxial import paraxial_data, working_f_number

ROOT = Path(__file__).resolve().parents[2]


def bessel_j(n: int, x: float) -> float:
    """J_n(x) = (1/pi) int_0^pi cos(n t - x sin t) dt (Bessel's integral), by Simpson's rule."""
    t = np.linspace(0.0, math.pi, 4001)
    f = np.cos(n * t - x * np.sin(t))
    h = t[1] - t[0]
    return float(h / 3 * (f[0] + f[-1] + 4 * f[1:-1:2].sum() + 2 * f[2:-1:2].sum()) / math.pi)


def encircled(pattern, rho: np.ndarray) -> np.ndarray:
    """Share of the pattern's energy within each radius (midpoint rule in r and azimuth)."""
    r = np.linspace(0.0, rho.max(), 4001)[1:] - 0.5 * rho.max() / 4000
    phi = np.linspace(0.0, 2 * math.pi, 181)[:-1]
    ring = pattern.intensity(r[:, None] * np.cos(phi), r[:, None] * np.sin(phi)).mean(axis=1)
    cum = np.cumsum(ring * 2 * math.pi * r * (rho.max() / 4000))
    return np.interp(rho, r, cum) / pattern.area


def test_01_circular_stop_gives_the_airy_pattern():
    """The circle's pattern is the Airy pattern: its encircled energy matches Rayleigh's
    1 - J0(v)^2 - J1(v)^2, v = 2 pi rho, within 0.003 from the core (rho = 0.2) past the first
    dark ring (0.61, 84 %) to 8 cycles per pupil radius; a kernel with the pixel a tenth of
    a cycle holds 0.98 of the pattern's energy within 20 cycles."""
    p = D.pattern_for(None)
    rho = np.array([0.2, 0.4, 0.61, 0.8, 1.2, 2.0, 4.0, 8.0])
    want = [1.0 - bessel_j(0, 2 * math.pi * x) ** 2 - bessel_j(1, 2 * math.pi * x) ** 2
            for x in rho]
    np.testing.assert_allclose(encircled(p, rho), want, atol=3e-3)
    assert encircled(p, np.array([0.61]))[0] == pytest.approx(0.838, abs=0.005)
    k = D.monochrome_kernel(p, 0.1, 200)
    assert 0.98 < k.sum() / p.area < 1.001


def spike_azimuths(kernel: np.ndarray, lo: float, hi: float) -> list[float]:
    """Peaks (degrees) of a kernel's energy over azimuth (1 degree bins, smoothed over 3)
    between lo and hi pixels from its centre, standing above three times the median."""
    r = kernel.shape[0] // 2
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    rad = np.hypot(x, y)
    ring = (rad > lo) & (rad < hi)
    ang = np.degrees(np.arctan2(y, x))[ring] % 360.0
    h, _ = np.histogram(ang, bins=360, range=(0.0, 360.0), weights=kernel[ring])
    n, _ = np.histogram(ang, bins=360, range=(0.0, 360.0))
    h = h / np.maximum(n, 1)
    hs = (np.roll(h, 1) + h + np.roll(h, -1)) / 3.0
    med = np.median(hs)
    return [i + 0.5 for i in range(360)
            if hs[i] >= hs[i - 1] and hs[i] > hs[(i + 1) % 360] and hs[i] > 3.0 * med]


def kernel_of(aperture, cycles_per_px: float = 0.5, r: int = 160) -> np.ndarray:
    return D.monochrome_kernel(D.pattern_for(aperture), cycles_per_px, r)


@pytest.mark.parametrize("blades,expected", [(5, 10), (6, 6), (7, 14), (8, 8), (9, 18),
                                             (10, 10)])
@pytest.mark.slow
def test_02_straight_blades_give_n_spikes_for_even_n_and_2n_for_odd(blades, expected):
    """A polygon stop of N straight blades: N spikes for even N (opposite edges are parallel
    and share theirs), 2N for odd N, evenly spaced (360 / count within 2 degrees)."""
    found = spike_azimuths(kernel_of(PolygonAperture(blades)), 40, 150)
    assert len(found) == expected
    gaps = np.diff(np.r_[found, found[0] + 360.0])
    assert np.all(np.abs(gaps - 360.0 / expected) < 2.0)


@pytest.mark.slow
def test_03_spikes_turn_with_the_blades_and_round_blades_have_none():
    """A hexagon turned by 15 degrees turns its spikes by 15 degrees (spikes stand
    perpendicular to the edges); a round stop and fully curved blades show none."""
    base = np.array(spike_azimuths(kernel_of(PolygonAperture(6)), 40, 150))
    turned = np.array(spike_azimuths(kernel_of(PolygonAperture(6, rotation_deg=15.0)), 40, 150))
    assert len(base) == len(turned) == 6
    diff = (turned - base - 15.0 + 180.0) % 360.0 - 180.0
    assert np.all(np.abs(diff) < 2.0)
    assert spike_azimuths(kernel_of(CircularAperture()), 40, 150) == []
    assert spike_azimuths(kernel_of(PolygonAperture(7, curvature=1.0)), 40, 150) == []


def reach(kernel: np.ndarray, area: float, share: float) -> float:
    """Radius (pixels, interpolated) beyond which lies `share` of the pattern's whole energy:
    beyond the core that light is the spikes' (summed outside in, so the core's pixels do not
    enter)."""
    r = kernel.shape[0] // 2
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    rad = np.hypot(x, y).ravel()
    inside = rad <= r
    order = np.argsort(-rad[inside])
    beyond = np.cumsum(kernel.ravel()[inside][order]) / area
    return float(np.interp(share, beyond, rad[inside][order]))


@pytest.mark.slow
def test_04_spikes_reach_in_proportion_to_wavelength_and_the_working_f_number():
    """On the film the pattern at frequency f lies at x = 2 N_w lambda f: the hexagon's light
    at 650 nm reaches 650 / 450 as far as at 450 nm (the radius beyond which 2 % of it lies,
    within 2 %), twice as far at twice the working f-number, and the circle's first dark ring
    lies at 1.22 lambda N_w (5.73 um at 587.6 nm and f/8; the kernel's azimuthal mean has its
    minimum between the core and the first bright ring within 0.3 micrometre of it)."""
    p = D.pattern_for(PolygonAperture(6))
    per_px = 0.002 / (2 * 8.0 * 1e-6)                    # cycles * nm per pixel at f/8

    def far(cycles_per_px):          # out to 50 cycles whatever the scale
        k = D.monochrome_kernel(p, cycles_per_px, int(math.ceil(50.0 / cycles_per_px)))
        return reach(k, p.area, 0.02)
    blue, red, slow = far(per_px / 450.0), far(per_px / 650.0), far(per_px / 2.0 / 450.0)
    assert 10 < blue < 100
    assert red / blue == pytest.approx(650.0 / 450.0, rel=0.02)
    assert slow / blue == pytest.approx(2.0, rel=0.02)
    k = D.monochrome_kernel(D.pattern_for(None), 0.00025 / (2 * 8.0 * 587.5618e-6), 70)
    y, x = np.mgrid[-70:71, -70:71]
    rad = np.hypot(x, y) * 0.00025                         # mm
    starts = np.arange(0.003, 0.0075, 0.00025)
    prof = [k[(rad >= a) & (rad < a + 0.00025)].mean() for a in starts]
    assert starts[int(np.argmin(prof))] + 0.000125 == pytest.approx(1.22 * 587.5618e-6 * 8.0,
                                                                   abs=0.0003)


def test_05_kernels_keep_the_energy_and_convolve_places_them_at_each_pixel():
    """Each channel's kernel sums to 1; convolving an image of two points gives each its
    kernel (centred on it, scaled by its value), RGB apart, alpha untouched, no negative
    value; the frame's total is kept while the kernel stays inside it; an impossible working
    f-number is refused in one line."""
    k = D.film_kernel(D.pattern_for(PolygonAperture(5)), pixel_mm=0.006, working_f_number=11.0,
                      dispersion=True, max_radius_px=40)
    np.testing.assert_allclose(k.kernels.sum(axis=(1, 2)), 1.0, rtol=1e-12)
    r = k.kernels.shape[1] // 2
    img = np.zeros((3 * r, 4 * r, 4))
    img[r + 5, r + 7, :3] = (2.0, 3.0, 4.0)
    img[2 * r - 1, 3 * r - 1, :3] = 1.0
    img[..., 3] = 0.25
    out = D.convolve(img, k)
    assert out.min() >= 0.0
    np.testing.assert_allclose(out[..., 3], 0.25)
    np.testing.assert_allclose(out[..., :3].sum(axis=(0, 1)), img[..., :3].sum(axis=(0, 1)),
                               rtol=1e-6)
    patch = out[5:2 * r + 6, 7:2 * r + 8, 0]
    # the first point's red is 2 x the red kernel where the second point's light is absent
    np.testing.assert_allclose(patch[:r // 2, :r // 2], 2.0 * k.kernels[0][:r // 2, :r // 2],
                               atol=1e-9)
    with pytest.raises(ValueError, match="working f-number"):
        D.film_kernel(D.pattern_for(None), pixel_mm=0.006, working_f_number=0.0,
                      dispersion=False, max_radius_px=10)


@pytest.mark.parametrize("name", ["double_gauss_50mm_f2", "telephoto_f5_6", "fisheye_f4"])
def test_06_the_working_f_number_scales_with_the_stop(name):
    """The kernel's scale is the paraxial working f-number: the design f-number at infinity,
    larger when focused close, and inversely proportional to the stop radius."""
    lens = load_lens(ROOT / "presets" / "lenses" / f"{name}.toml")
    pd = paraxial_data(lens)
    r0 = lens.stop_radius_mm
    assert D.lens_working_f_number(lens, math.inf, 0.0, r0) == pytest.approx(pd.f_number)
    near = D.lens_working_f_number(lens, 20.0 * pd.efl_mm, 0.0, r0)
    assert near > pd.f_number
    assert D.lens_working_f_number(lens, 20.0 * pd.efl_mm, 0.0, 0.5 * r0) == pytest.approx(
        2.0 * near)
    assert near == pytest.approx(working_f_number(lens, 20.0 * pd.efl_mm))
