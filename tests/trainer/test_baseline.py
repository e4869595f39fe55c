"""The polynomial baseline (trainer.baseline): least-squares polynomials around the stop, no
networks, in the ordinary model format (real training on small data, real onnxruntime)."""

from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.neural import reference
from neurolens_addon.neural.model import LearnedLens
from trainer.baseline import choose_degree, fit_polynomial_baseline
from trainer.fit import FitConfig

pytestmark = pytest.mark.slow          # fits models

ROOT = Path(__file__).resolve().parents[2]
COOKE = ROOT / "presets" / "lenses" / "cooke_triplet_f4.toml"


def test_01_degree_is_the_lowest_that_meets_the_trainers_threshold():
    """The chosen degree meets the cell threshold and the one below it does not."""
    lens = load_lens(COOKE)
    p, errors = choose_degree(lens, n_rays=40_000, log=lambda *a: None)
    target = FitConfig().error_threshold
    assert errors[p] <= target or p == min(errors, key=errors.get)
    assert all(errors[q] > target for q in errors if q < p)
    assert errors[2] > errors[p]                      # a higher degree did buy accuracy


def test_02_baseline_is_a_polynomial_in_the_model_format(tmp_path):
    """One cell, one member per stage whose network output is exactly zero; onnxruntime and
    the float64 reference agree; the model traces camera rays like any learned lens."""
    lens = load_lens(COOKE)
    meta = fit_polynomial_baseline(lens, tmp_path / "poly.neurolens", degree=3, n_rays=30_000,
                                   log=lambda *a: None)
    for st in meta["stages"]:
        if st.get("propagate"):
            continue
        assert len(st["cells"]) == 1 and len(st["cells"][0]["members"]) == 1
        assert not np.any(st["cells"][0]["members"][0]["W3"])
    model = LearnedLens.load(tmp_path / "poly.neurolens", lens=lens)
    rng = np.random.default_rng(0)
    n = 2000
    hi = np.asarray(meta["stages"][0]["bounds"]["hi"])
    r = rng.uniform(0, 0.5 * hi[0], n)
    u = rng.uniform(-0.3, 0.3, n) * hi[1]
    rays = np.stack([r, np.zeros(n), u, np.zeros(n), np.sqrt(1 - u * u),
                     rng.uniform(450, 650, n)], axis=1)
    stop, out, spread, ok = model.evaluate(rays)
    ref = reference.evaluate(meta, rays)
    assert ok.mean() > 0.5
    np.testing.assert_allclose(out[ok, :2], ref[1][ok, :2], atol=5e-4)
    np.testing.assert_allclose(out[ok, 2:4], ref[1][ok, 2:4], atol=5e-6)
    assert not spread[ok].any()                        # one member: no ensemble spread
