"""Non-negative channel responses: white, first moments, exact sampling, bounded weights."""

import numpy as np
import pytest

from neurolens_addon.core.np_compat import trapezoid
from neurolens_addon.core.sensor_response import (
    sample_linear_density,
    sensor_response,
    signed_means_nm,
)
from neurolens_addon.core.spectrum import cmf_rgb, rgb_normalisation

RANGES = [(380.0, 780.0), (400.0, 700.0), (382.5, 777.0)]


@pytest.mark.parametrize("lo,hi", RANGES)
def test_01_responses_are_non_negative_and_integrate_to_one(lo, hi):
    """Each response is >= 0 and integrates to 1 (a flat spectrum is white), for any range."""
    r = sensor_response(lo, hi)
    assert r.knots[0] == lo and r.knots[-1] == hi
    assert r.values.min() >= 0.0
    lam = np.linspace(lo, hi, 200001)
    np.testing.assert_allclose(trapezoid(r.at(lam), lam, axis=0), 1.0, atol=1e-6)


@pytest.mark.parametrize("lo,hi", RANGES)
def test_02_first_moments_equal_the_signed_curves(lo, hi):
    """Each response's mean wavelength is the signed k rgb_bar's (lateral colour kept to first
    order), checked by independent fine quadrature of both."""
    r = sensor_response(lo, hi)
    lam = np.linspace(lo, hi, 400001)
    signed = cmf_rgb(lam) * rgb_normalisation(lo, hi)
    want = trapezoid(signed * lam[:, None], lam, axis=0) / trapezoid(signed, lam, axis=0)
    got = trapezoid(r.at(lam) * lam[:, None], lam, axis=0)
    np.testing.assert_allclose(got, want, atol=0.01)
    np.testing.assert_allclose(signed_means_nm(lo, hi), want, atol=0.01)
    # clipping alone would pull red and blue towards green: the tilt is what keeps them apart
    clipped = np.maximum(signed, 0.0)
    plain = trapezoid(clipped * lam[:, None], lam, axis=0) / trapezoid(clipped, lam, axis=0)
    assert plain[0] < want[0] - 10.0 and plain[2] > want[2] + 5.0


def test_03_responses_peak_in_their_own_band():
    """Red peaks beyond 590 nm, green in 520-570 nm, blue below 470 nm."""
    r = sensor_response()
    peaks = r.knots[np.argmax(r.values, axis=0)]
    assert peaks[0] > 590 and 520 < peaks[1] < 570 and peaks[2] < 470


@pytest.mark.parametrize("channel", [0, 1, 2])
def test_04_channel_sampling_follows_its_response(channel):
    """Wavelengths drawn for a channel have that response as density (histogram, 80 bins)."""
    r = sensor_response()
    lam = r.sample_channel(np.random.default_rng(channel).random(400_000), channel)
    hist, edges = np.histogram(lam, bins=80, range=(380.0, 780.0), density=True)
    mid = 0.5 * (edges[1:] + edges[:-1])
    expected = r.at(mid)[:, channel]
    assert np.abs(hist - expected).max() < 0.03 * expected.max()


def test_05_sensor_sampling_is_white_non_negative_and_sums_to_three():
    """The one-ray weights average to (1, 1, 1), are >= 0 and sum to 3 on every ray."""
    u = (np.arange(200_000) + 0.5) / 200_000
    lam, w = sensor_response().sample_sensor(u)
    np.testing.assert_allclose(w.mean(axis=0), 1.0, atol=1e-3)
    assert w.min() >= 0.0
    np.testing.assert_allclose(w.sum(axis=1), 3.0, rtol=1e-12)
    assert np.all(np.diff(lam) >= 0)          # monotone in u: stratified u stay stratified


def test_06_linear_density_inverse_cdf_is_exact():
    """On a single linear segment the inverse CDF solves the quadratic exactly, including a
    density that starts at 0 and a flat one; bad u are clamped, never NaN."""
    knots = np.array([0.0, 2.0])
    for dens in ([0.0, 1.0], [1.0, 1.0], [3.0, 1.0]):
        d = np.array(dens)
        mass = 0.5 * (d[0] + d[1]) * 2.0
        cdf = np.array([0.0, 1.0])
        x = np.linspace(0.0, 2.0, 101)
        f = (d[0] * x + (d[1] - d[0]) * x * x / 4.0) / mass          # CDF at x
        np.testing.assert_allclose(sample_linear_density(f[:-1], knots, d, cdf), x[:-1],
                                   atol=1e-9)
    out = sample_linear_density([np.nan, -1.0, 2.0], knots, np.array([1.0, 1.0]),
                                np.array([0.0, 1.0]))
    assert np.all(np.isfinite(out)) and out[0] == 0.0 and out[2] <= 2.0


def test_07_lateral_colour_stays_as_strong_as_the_signed_curves_give():
    """On the double Gauss and the wide angle at 70 % of the half field, the red-to-blue
    image distance under the responses is within 10 % of that under the signed k rgb_bar
    (clipping the negative lobes alone loses more than 20 %)."""
    from pathlib import Path

    from neurolens_addon.core.field import half_field_deg, lateral_colour_mm
    from neurolens_addon.core.lensfile import load_lens
    root = Path(__file__).resolve().parents[2] / "presets" / "lenses"
    k = rgb_normalisation()
    for name in ("double_gauss_50mm_f2", "wide_angle_f3_4"):
        lens = load_lens(root / f"{name}.toml")
        field = 0.7 * half_field_deg(lens)
        signed = lateral_colour_mm(lens, field, lambda lam: cmf_rgb(lam) * k)
        ours = lateral_colour_mm(lens, field, sensor_response().at)
        clipped = lateral_colour_mm(lens, field, lambda lam: np.maximum(cmf_rgb(lam) * k, 0))
        assert abs(signed) > 1e-3
        assert abs(ours / signed - 1.0) < 0.10, (name, ours, signed)
        assert clipped / signed < 0.8, (name, clipped, signed)
