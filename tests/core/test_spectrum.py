"""Spectrum -> RGB: CIE table, white normalisation, wavelength sampling."""

import numpy as np
import pytest

from neurolens_addon.core import spectrum as sp


def test_01_table_shape_and_range():
    """The CIE table covers 360-830 nm at 5 nm with 95 rows of 3 non-negative values."""
    wl, xyz = sp.cie_table()
    assert wl.shape == (95,) and xyz.shape == (95, 3)
    assert wl[0] == 360 and wl[-1] == 830 and np.all(np.diff(wl) == 5)
    assert np.all(xyz >= 0)


def test_02_table_checksums():
    """The 380-780 nm sums match the published CIE 5 nm checksums 21.371524/21.371327/21.371540."""
    wl, xyz = sp.cie_table()
    sel = (wl >= 380) & (wl <= 780)
    np.testing.assert_allclose(xyz[sel].sum(axis=0), [21.371524, 21.371327, 21.371540],
                               atol=2e-6)


def test_03_cmf_known_values():
    """CMF values at known wavelengths match the table (y_bar(555) = 1, x_bar(600) = 1.0622)."""
    v = sp.cmf_xyz([555.0, 600.0, 445.0, 380.0])
    np.testing.assert_allclose(v[0], [0.5120501, 1.0, 0.005749999], rtol=1e-7)
    np.testing.assert_allclose(v[1], [1.0622, 0.631, 0.0008], rtol=1e-7)
    np.testing.assert_allclose(v[2], [0.34806, 0.0298, 1.7826], rtol=1e-7)
    np.testing.assert_allclose(v[3], [0.001368, 0.000039, 0.006450001], rtol=1e-7)


def test_04_cmf_interpolates_linearly_and_is_zero_outside():
    """Between rows the CMF is the linear interpolant; outside 360-830 nm and for NaN it is 0."""
    a, b = sp.cmf_xyz([550.0, 555.0])
    np.testing.assert_allclose(sp.cmf_xyz(552.5), 0.5 * (a + b), rtol=1e-12)
    out = sp.cmf_xyz(np.array([300.0, 359.9, 830.1, 1000.0, np.nan, np.inf]))
    assert out.shape == (6, 3) and np.all(out == 0)


def test_05_matrix_maps_d65_to_white():
    """XYZ of D65 (x 0.3127, y 0.3290, Y 1) maps to linear sRGB (1, 1, 1)."""
    x, y = 0.3127, 0.3290
    d65 = np.array([x / y, 1.0, (1 - x - y) / y])
    np.testing.assert_allclose(sp.XYZ_TO_LINEAR_SRGB @ d65, [1, 1, 1], atol=1e-12)
    np.testing.assert_allclose(sp.XYZ_TO_LINEAR_SRGB[0], [3.2406, -1.5372, -0.4986], atol=6e-4)


def test_06_flat_spectrum_white_by_quadrature():
    """A flat spectrum integrates to RGB (1, 1, 1) within 1e-3 by quadrature (pdf = 1)."""
    for lo, hi in [(380.0, 780.0), (400.0, 700.0), (360.0, 830.0)]:
        lam = np.linspace(lo, hi, 20001)
        w = sp.wavelength_rgb_weights(lam, pdf=1.0, lo=lo, hi=hi)
        rgb = np.trapz(w, lam, axis=0)
        np.testing.assert_allclose(rgb, [1, 1, 1], atol=1e-3)


@pytest.mark.parametrize("method", ["uniform", "visible"])
def test_07_flat_spectrum_white_by_monte_carlo(method):
    """200k sampled wavelengths average to (1, 1, 1) within 5 standard errors, both methods."""
    rng = np.random.default_rng(7)
    lam, pdf = sp.sample_wavelengths(rng.random(200_000), method=method)
    w = sp.wavelength_rgb_weights(lam, pdf)
    mean = w.mean(axis=0)
    se = w.std(axis=0) / np.sqrt(len(w))
    assert np.all(np.abs(mean - 1.0) < 5 * se), (mean, se)
    assert np.all(np.abs(mean - 1.0) < 0.03)


def test_08_visible_sampling_reduces_colour_noise():
    """Importance sampling ("visible") has a smaller per-channel weight spread than uniform."""
    u = np.random.default_rng(8).random(100_000)
    stds = {}
    for m in ("uniform", "visible"):
        lam, pdf = sp.sample_wavelengths(u, method=m)
        stds[m] = sp.wavelength_rgb_weights(lam, pdf).std(axis=0)
    assert np.all(stds["visible"] < 0.9 * stds["uniform"])


@pytest.mark.parametrize("method", ["uniform", "visible"])
def test_09_pdf_integrates_to_one(method):
    """The sampling density integrates to 1 over [lo, hi] and is 0 outside."""
    lo, hi = 380.0, 780.0
    lam = np.linspace(lo, hi, 400_001)[:-1] + 0.0005
    p = sp.wavelength_pdf(lam, lo, hi, method)
    assert abs(p.sum() * 0.001 - 1.0) < 1e-9
    assert np.all(sp.wavelength_pdf([379.0, 781.0, np.nan], lo, hi, method) == 0)


@pytest.mark.parametrize("method", ["uniform", "visible"])
def test_10_samples_in_range_and_pdf_consistent(method):
    """sample_wavelengths stays in [lo, hi), is monotone in u, and returns the density's value."""
    u = np.concatenate([[0.0, np.nextafter(1.0, 0), 1.0, -0.5, 2.0, np.nan],
                        np.random.default_rng(10).random(10_000)])
    lam, pdf = sp.sample_wavelengths(u, 400.0, 700.0, method)
    assert np.all(np.isfinite(lam)) and np.all((lam >= 400.0) & (lam < 700.0))
    np.testing.assert_allclose(pdf, sp.wavelength_pdf(lam, 400.0, 700.0, method), rtol=1e-12)
    us = np.linspace(0, 1, 5001)[:-1]
    assert np.all(np.diff(sp.sample_wavelengths(us, method=method)[0]) >= 0)


def test_11_visible_histogram_matches_pdf():
    """A histogram of "visible" samples follows the density (chi-square over 40 bins)."""
    rng = np.random.default_rng(11)
    n = 200_000
    lam, _ = sp.sample_wavelengths(rng.random(n), method="visible")
    edges = np.linspace(380, 780, 41)
    counts, _ = np.histogram(lam, edges)
    fine = np.linspace(380, 780, 400_001)
    p = sp.wavelength_pdf(0.5 * (fine[1:] + fine[:-1]), method="visible")
    cdf = np.concatenate([[0], np.cumsum(p * np.diff(fine))])
    expected = n * np.diff(np.interp(edges, fine, cdf))
    chi2 = np.sum((counts - expected) ** 2 / expected)
    assert chi2 < 80  # 39 degrees of freedom: p < 1e-4


def test_12_stratified_wavelengths():
    """stratified_wavelengths puts exactly one sample in each of n equal-probability strata."""
    lam, pdf = sp.stratified_wavelengths(64, rng=3)
    strata = np.floor((lam - 380.0) / 400.0 * 64).astype(int)
    assert np.array_equal(np.sort(strata), np.arange(64))
    np.testing.assert_allclose(pdf, 1 / 400.0)
    lam2, _ = sp.stratified_wavelengths(64, rng=np.random.default_rng(3), shuffle=True)
    assert sorted(lam2.tolist()) != lam2.tolist() and len(set(lam2)) == 64


def test_13_weights_zero_out_of_range_and_negative_kept():
    """Weights are 0 outside [lo, hi] or for pdf <= 0, and red is negative near 500 nm."""
    w = sp.wavelength_rgb_weights([370.0, 790.0, np.nan, 550.0], pdf=[1, 1, 1, 0])
    assert np.all(w == 0)
    w500 = sp.wavelength_rgb_weights([500.0])[0]
    assert w500[0] < 0 and w500[1] > 0


def test_14_standard_lines():
    """The standard spectral lines have their catalogue values."""
    assert sp.WAVELENGTHS_NM["d"] == 587.5618
    assert sp.WAVELENGTHS_NM["F"] == 486.1327 and sp.WAVELENGTHS_NM["C"] == 656.2725
    assert sp.WAVELENGTHS_NM["g"] == 435.8343 and sp.WAVELENGTHS_NM["e"] == 546.0740


def test_15_display_rgb():
    """Display colours are in [0, 1]: 450 nm is blue, 530 nm green, 650 nm red."""
    c = sp.wavelength_to_display_rgb(np.array([450.0, 530.0, 650.0, 300.0, 900.0]))
    assert c.shape == (5, 3) and np.all((c >= 0) & (c <= 1))
    assert np.argmax(c[0]) == 2 and np.argmax(c[1]) == 1 and np.argmax(c[2]) == 0


def test_16_bad_arguments():
    """An empty range or an unknown sampling method raises ValueError naming the problem."""
    with pytest.raises(ValueError, match="lo < hi"):
        sp.sample_wavelengths([0.5], 700.0, 400.0)
    with pytest.raises(ValueError, match="method"):
        sp.sample_wavelengths([0.5], method="blue")
