"""Surface reflectances (core.coatings) against textbook values: Fresnel at normal incidence,
Brewster's angle and total internal reflection; the quarter-wave single layer at its design
wavelength; tabulated multi-layer curves."""

from __future__ import annotations

import math

import numpy as np
import pytest

from neurolens_addon.core.coatings import (
    MGF2_INDEX,
    Coating,
    fresnel_reflectance,
    quarter_half_quarter,
    single_layer_reflectance,
)


@pytest.mark.parametrize("n", [1.5, 1.52, 1.7, 1.9])
def test_01_bare_surface_at_normal_incidence_reflects_the_fresnel_share(n):
    """((n - 1) / (n + 1))^2 from air (4.0 % for 1.5, 7.4 % for 1.9), the same from the glass
    side (reciprocity), and the transmitted share completes it to 1."""
    want = ((n - 1.0) / (n + 1.0)) ** 2
    assert fresnel_reflectance(1.0, n, 1.0) == pytest.approx(want, rel=1e-12)
    assert fresnel_reflectance(n, 1.0, 1.0) == pytest.approx(want, rel=1e-12)
    assert Coating("bare").reflectance(1.0, n, 1.0, 550.0) == pytest.approx(want, rel=1e-12)


def test_02_brewster_grazing_and_total_internal_reflection():
    """At Brewster's angle (tan = n) the p wave is not reflected: R = R_s / 2, R_s
    = cos^2(2 theta_B) for n = 1.5 (Hecht's example: 14.8 % / 2); towards grazing R -> 1;
    beyond the critical angle from the glass side (41.8 degrees for 1.5) R = 1."""
    n = 1.5
    tb = math.atan(n)
    rs = math.cos(2 * tb) ** 2          # r_s = -sin(i - t) / sin(i + t), i + t = 90 degrees
    assert fresnel_reflectance(1.0, n, math.cos(tb)) == pytest.approx(0.5 * rs, rel=1e-9)
    assert fresnel_reflectance(1.0, n, 1e-6) > 0.999
    crit = math.asin(1.0 / n)
    assert fresnel_reflectance(n, 1.0, math.cos(crit + 0.01)) == 1.0
    assert fresnel_reflectance(n, 1.0, math.cos(crit - 0.01)) < 1.0


@pytest.mark.parametrize("ns", [1.52, 1.62, 1.8])
def test_03_quarter_wave_layer_at_its_design_wavelength(ns):
    """A quarter-wave film at its design wavelength and normal incidence reflects
    ((n_s - n_1^2) / (n_s + n_1^2))^2 (MgF2 on 1.52: 1.26 %), less than the bare surface,
    nothing when n_1 = sqrt(n_s); away from the design wavelength it reflects more; at
    zero thickness it is the bare surface."""
    c = Coating("single")
    n1 = MGF2_INDEX
    want = ((ns - n1 * n1) / (ns + n1 * n1)) ** 2
    got = c.reflectance(1.0, ns, 1.0, 550.0)
    assert got == pytest.approx(want, rel=1e-9)
    assert got < fresnel_reflectance(1.0, ns, 1.0)
    assert c.reflectance(1.0, ns, 1.0, 420.0) > got and c.reflectance(1.0, ns, 1.0, 700.0) > got
    perfect = Coating("single", film_index=math.sqrt(ns))
    assert perfect.reflectance(1.0, ns, 1.0, 550.0) == pytest.approx(0.0, abs=1e-15)
    assert single_layer_reflectance(1.0, ns, 0.8, 500.0, n1, 0.0) == pytest.approx(
        fresnel_reflectance(1.0, ns, 0.8), rel=1e-12)
    # the textbook's number (n_1 = 1.38 on 1.52)
    assert (Coating("single", film_index=1.38).reflectance(1.0, 1.52, 1.0, 550.0)
            == pytest.approx(0.0126, abs=1e-4))


def test_04_tabulated_multilayer_and_equal_media():
    """A tabulated curve is read linearly between its points and held at its ends; total
    internal reflection stays total; a surface between equal indices reflects nothing; bad
    tables and kinds are refused in one line."""
    c = Coating("table", table_nm=(400.0, 500.0, 700.0), table_r=(0.01, 0.002, 0.006))
    np.testing.assert_allclose(c.reflectance(1.0, 1.6, 0.9, [380.0, 450.0, 600.0, 800.0]),
                               [0.01, 0.006, 0.004, 0.006])
    assert c.reflectance(1.6, 1.0, 0.1, 500.0) == 1.0
    assert Coating("bare").reflectance(1.5, 1.5, 0.7, 500.0) == 0.0
    for bad in (dict(kind="table", table_nm=(500.0,), table_r=(0.1,)),
                dict(kind="table", table_nm=(500.0, 400.0), table_r=(0.1, 0.1)),
                dict(kind="table", table_nm=(400.0, 500.0), table_r=(0.1, 1.5)),
                dict(kind="gold"), dict(kind="single", film_index=0.9)):
        with pytest.raises(ValueError):
            Coating(**bad)


def test_05_reflectances_stay_in_the_unit_interval_and_finite():
    """Over every angle, index pair and visible wavelength: 0 <= R <= 1, never NaN."""
    rng = np.random.default_rng(5)
    n0 = rng.choice([1.0, 1.5, 1.9], 5000)
    ns = rng.choice([1.0, 1.45, 1.8], 5000)
    cos_i = rng.random(5000)
    lam = rng.uniform(380.0, 780.0, 5000)
    for c in (Coating("bare"), Coating("single"), Coating("multi"),
              Coating("table", table_nm=(400.0, 700.0), table_r=(0.0, 0.01))):
        r = c.reflectance(n0, ns, cos_i, lam)
        assert np.all(np.isfinite(r)) and np.all((r >= 0.0) & (r <= 1.0))


def test_06_multilayer_stacks():
    """A one-layer stack is the single layer; the quarter-half-quarter broadband design
    (MgF2 / ZrO2 / Al2O3 on 1.52) averages under 0.5 % over 430-670 nm, below the single
    MgF2 layer's average, at normal incidence; it reflects the same from either side at
    normal incidence (reciprocity); stacks with an index below 1 are refused."""
    from neurolens_addon.core.coatings import quarter_half_quarter, stack_reflectance
    lam = np.linspace(430.0, 670.0, 49)
    one = stack_reflectance(1.0, 1.52, 0.9, lam, ((1.38, 99.6),))
    np.testing.assert_allclose(one, single_layer_reflectance(1.0, 1.52, 0.9, lam, 1.38, 99.6),
                               rtol=1e-12)
    qhq = Coating("multi").reflectance(1.0, 1.52, 1.0, lam)
    mgf2 = Coating("single").reflectance(1.0, 1.52, 1.0, lam)
    assert qhq.mean() < 0.005 < mgf2.mean()
    back = Coating("multi").reflectance(1.52, 1.0, 1.0, lam)
    np.testing.assert_allclose(back, qhq, rtol=1e-9)
    assert len(quarter_half_quarter()) == 3
    with pytest.raises(ValueError):
        Coating("multi", layers=((0.9, 100.0),))


def test_07_cemented_interfaces_stay_bare():
    """Between two glasses (a cemented doublet) every coating kind reflects the bare Fresnel
    share (no maker coats a cemented face); against air it is coated."""
    for kind in ("single", "multi"):
        c = Coating(kind)
        assert c.reflectance(1.52, 1.72, 1.0, 550.0) == pytest.approx(
            fresnel_reflectance(1.52, 1.72, 1.0), rel=1e-12)
        assert c.reflectance(1.0, 1.72, 1.0, 550.0) < fresnel_reflectance(1.0, 1.72, 1.0)


@pytest.mark.parametrize("layers", [((1.3777, 550.0 / (4 * 1.3777)),), quarter_half_quarter(),
                                    ((2.05, 0.0),)])
@pytest.mark.parametrize("n0,ns", [(1.0, 1.62), (1.62, 1.0), (1.0, 1.9), (1.7, 1.5)])
def test_08_the_compiled_stack_equals_the_numpy_reference(layers, n0, ns):
    """core.coatings_kernels' per-ray stack (the light tracer's and ghost samples' weights)
    gives the numpy reference's reflectance to 1e-14 over every angle (past the critical one
    too) and the visible, arrays broadcast against scalars."""
    from neurolens_addon.core.coatings import stack_reflectance
    pytest.importorskip("numba")
    rng = np.random.default_rng(4)
    cos_i = np.concatenate([rng.random(5000), [0.0, 1.0]])
    lam = rng.uniform(380.0, 780.0, cos_i.size)
    ref = stack_reflectance(n0, ns, cos_i, lam, layers, kernels="numpy")
    got = stack_reflectance(n0, ns, cos_i, lam, layers, kernels="compiled")
    assert got.shape == ref.shape
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-14)
    assert ((got >= 0) & (got <= 1)).all()
