"""Extreme rays through presets, exact and learned (the small version of the robustness count
in `make bench`): no valid ray ever carries a NaN or an infinity, and invalid rays carry
nothing."""

from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.trace import trace
from neurolens_addon.neural.model import LearnedLens
from testdata.extreme_rays import FAMILIES, count_bad, extreme_rays

ROOT = Path(__file__).resolve().parents[2]
LENSES = ["fisheye_f4", "double_gauss_50mm_f2", "noct_58mm_f0_95_aspheric", "telephoto_f5_6"]


@pytest.mark.parametrize("stem", LENSES)
def test_01_extreme_rays_are_finite_or_flagged(stem):
    """6,000 rays of every extreme family, full aperture and f/64: valid rays are finite in the
    exact and the learned lens; flagged rays are all zero in the learned one; every family
    has rays, and some rays pass (the families reach the lens)."""
    lens = load_lens(ROOT / "presets" / "lenses" / f"{stem}.toml")
    model = LearnedLens.load(ROOT / "presets" / "models" / f"{stem}.neurolens", lens=lens)
    rays, zs, fam = extreme_rays(lens, 6000, seed=3)
    assert set(np.unique(fam)) == set(range(len(FAMILIES)))
    for stop in (None, lens.stop_radius_mm * lens.f_number / 64.0):
        ex = trace(lens, rays, sensor_z=None, stop_radius=stop)
        lr = model.trace_from_sensor(rays, sensor_z=zs, stop_radius=stop)
        assert count_bad(ex.rays, ex.valid) == 0 and count_bad(lr.rays, lr.valid) == 0
        assert not lr.rays.o[:, ~lr.valid].any() and not lr.rays.d[:, ~lr.valid].any()
        assert np.isfinite(lr.rays.o).all() and np.isfinite(lr.rays.d).all()
    assert trace(lens, rays, sensor_z=None).valid.mean() > 0.01


def test_02_nan_and_infinite_inputs_are_flagged():
    """NaN, infinite and zero-length directions and NaN wavelengths come back invalid with
    zero outputs, exact and learned, and the good rays beside them are unaffected."""
    lens = load_lens(ROOT / "presets" / "lenses" / "double_gauss_50mm_f2.toml")
    model = LearnedLens.load(ROOT / "presets" / "models" / "double_gauss_50mm_f2.neurolens",
                             lens=lens)
    rays, zs, _ = extreme_rays(lens, 600, seed=5)
    o, d, wl = rays.o.copy(), rays.d.copy(), rays.wavelength.copy()
    o[0, 0], d[1, 1], d[:, 2], wl[3], o[1, 4] = np.nan, np.inf, 0.0, np.nan, -np.inf
    bad = Rays(o, d, wl)
    ex = trace(lens, bad, sensor_z=None)
    lr = model.trace_from_sensor(bad, sensor_z=zs)
    for res in (ex, lr):
        assert not res.valid[:5].any()
        assert np.isfinite(res.rays.o).all() and np.isfinite(res.rays.d).all()
    good = model.trace_from_sensor(Rays(rays.o[:, 5:], rays.d[:, 5:], rays.wavelength[5:]),
                                   sensor_z=zs[5:])
    np.testing.assert_array_equal(good.valid, lr.valid[5:])
    np.testing.assert_array_equal(good.rays.o, lr.rays.o[:, 5:])
