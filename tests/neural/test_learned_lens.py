"""A real learned lens end to end: trained from exact traces (small, fast), exported, loaded
with onnxruntime, and compared with the exact trace it learned."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core.errors import ModelError
from neurolens_addon.core.field import film_radius_mm
from neurolens_addon.core.irf import propagate_to_z
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.rays import Rays, RayStatus
from neurolens_addon.core.trace import trace
from neurolens_addon.neural.model import LearnedLens
from trainer.data import default_domain
from trainer.evaluate import camera_rays_at_focus
from trainer.fit import FitConfig
from trainer.pipeline import fit_lens

from tests.neural.synthetic import reference_jacobian_fd

ROOT = Path(__file__).resolve().parents[2]
COOKE = ROOT / "presets" / "lenses" / "cooke_triplet_f4.toml"


def field_domain(lens):
    """The default domain held to the lens's stated field: a one-cell model this small fits it
    to the tolerances below (the shipped models, deeper, also cover full-frame corners)."""
    return dataclasses.replace(default_domain(lens), film_radius_mm=film_radius_mm(lens))


@pytest.fixture(scope="module")
def learned(tmp_path_factory):
    lens = load_lens(COOKE)
    out = tmp_path_factory.mktemp("models") / "cooke"
    cfg = FitConfig(theta=4, ensemble=2, skip_degree=4, max_depth=0, member_samples=6000,
                    lm_iterations=10, cell_time_budget_s=30)
    fit_lens(lens, out, cfg, n_rays=80000, domain=field_domain(lens), log=lambda *a: None)
    return lens, LearnedLens.load(out.with_name("cooke.neurolens"), lens=lens)


def test_01_learned_rays_match_the_exact_trace(learned):
    """Camera rays focused at 2 m: the learned lens agrees with the exact trace on which rays
    pass (>= 97 %) and, where both pass, to 0.05 mm on Pi_2 and 1e-3 in direction."""
    lens, model = learned
    dom = field_domain(lens)
    rays, z_s = camera_rays_at_focus(lens, dom, 20000, 2000.0, seed=1)
    ex = trace(lens, rays)
    le = model.trace_from_sensor(rays, sensor_z=z_s)
    assert (ex.valid == le.valid).mean() >= 0.97
    v = ex.valid & le.valid
    assert v.mean() > 0.8
    eo = propagate_to_z(ex.rays.o[:, v], ex.rays.d[:, v], model.planes["output_z"])
    assert np.abs(eo[:2] - le.rays.o[:2, v]).max() < 0.05
    assert np.abs(ex.rays.d[:, v] - le.rays.d[:, v]).max() < 1e-3


def test_02_a_model_for_another_lens_is_refused(learned):
    """Loading the Cooke model for the Tessar prescription raises ModelError naming both."""
    lens, model = learned
    other = load_lens(ROOT / "presets" / "lenses" / "tessar_f4_5.toml")
    with pytest.raises(ModelError, match="Cooke"):
        LearnedLens.load(model.directory, lens=other)


def test_03_rays_outside_the_learned_domain_are_flagged(learned):
    """Film points far beyond the image circle and wavelengths beyond 780 nm come back flagged
    OUT_OF_DOMAIN with zero rays, never extrapolated."""
    lens, model = learned
    o = np.array([[0.0, 80.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    tgt = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [lens.rear_vertex_z] * 3])
    d = tgt - o
    d /= np.linalg.norm(d, axis=0)
    res = model.trace_from_sensor(Rays(o, d, np.array([550.0, 550.0, 900.0])), sensor_z=0.0)
    assert res.valid.tolist() == [True, False, False]
    assert (res.status[1:] == RayStatus.OUT_OF_DOMAIN).all()
    assert not res.rays.o[:, 1:].any()


def test_04_jacobian_of_the_real_model_matches_finite_differences(learned):
    """The in-graph Jacobian of the trained model agrees with central differences of its own
    float64 reference within 2 % of the Jacobian's scale."""
    lens, model = learned
    meta = json.loads((model.directory / "model.json").read_text())
    dom = field_domain(lens)
    rays, z_s = camera_rays_at_focus(lens, dom, 200, 2000.0, seed=2)
    p1 = propagate_to_z(np.array(rays.o), rays.d, model.planes["input_z"])
    x = np.stack([p1[0], p1[1], rays.d[0], rays.d[1], rays.d[2], rays.wavelength], 1)
    stop, out, spread, ok, J = model.evaluate(x, jacobian=True)
    x = x[ok]
    J = J[ok]
    fd = reference_jacobian_fd(meta, x, h=1e-5)
    scale = np.abs(fd).max(axis=(1, 2), keepdims=True)
    assert np.abs(J - fd).max() / scale.max() < 0.02
    assert np.median(np.abs(J - fd) / scale) < 1e-3


def test_06_a_model_without_dispersion_learns_the_d_line(tmp_path):
    """--no-dispersion: networks take 4 inputs (no wavelength), the model follows the exact
    d-line trace, and it is achromatic: any wavelength gets the d-line rays."""
    lens = load_lens(ROOT / "presets" / "lenses" / "tessar_f4_5.toml")
    cfg = FitConfig(theta=4, ensemble=2, skip_degree=4, max_depth=0, member_samples=5000,
                    lm_iterations=8, cell_time_budget_s=20)
    meta = fit_lens(lens, tmp_path / "t", cfg, n_rays=60000, dispersion=False,
                    log=lambda *a: None)
    assert np.asarray(meta["stages"][0]["cells"][0]["members"][0]["W1"]).shape[1] == 4
    model = LearnedLens.load(tmp_path / "t.neurolens", lens=lens)
    dom = default_domain(lens, dispersion=False)
    rays, z_s = camera_rays_at_focus(lens, dom, 5000, 2000.0, seed=3)
    assert np.all(rays.wavelength == 587.5618)
    ex, le = trace(lens, rays), model.trace_from_sensor(rays, sensor_z=z_s)
    v = ex.valid & le.valid
    assert v.mean() > 0.8
    assert np.abs(ex.rays.d[:, v] - le.rays.d[:, v]).max() < 1e-3
    blue = model.trace_from_sensor(Rays(rays.o, rays.d, np.full(rays.n, 450.0)), sensor_z=z_s)
    np.testing.assert_array_equal(blue.valid, le.valid)
    np.testing.assert_array_equal(blue.rays.d, le.rays.d)
