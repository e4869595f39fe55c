"""Spectrum -> RGB: CIE table, white normalisation, wavelength sampling."""

import numpy as np
import pytest

from neurolens_addon.core import spectrum as sp
from neurolens_addon.core.np_compat import trapezoid


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


def test_06_normalisation_makes_a_flat_spectrum_white():
    """k_c times the quadrature of rgb_bar_c over [lo, hi] is 1 for every channel and range."""
    for lo, hi in [(380.0, 780.0), (400.0, 700.0), (360.0, 830.0)]:
        lam = np.linspace(lo, hi, 20001)
        rgb = trapezoid(sp.cmf_rgb(lam), lam, axis=0) * sp.rgb_normalisation(lo, hi)
        np.testing.assert_allclose(rgb, [1, 1, 1], atol=1e-3)


def test_07_red_matching_function_is_negative_near_500_nm():
    """Spectral colours lie outside Rec.709: rgb_bar_R < 0 at 500 nm (why rendering uses
    core.sensor_response instead)."""
    r, g, _ = sp.cmf_rgb([500.0])[0]
    assert r < 0 < g


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
    """An empty or out-of-table range raises ValueError naming the problem."""
    with pytest.raises(ValueError, match="lo < hi"):
        sp.rgb_normalisation(700.0, 400.0)
    with pytest.raises(ValueError, match="outside the CIE table"):
        sp.rgb_normalisation(900.0, 1000.0)
