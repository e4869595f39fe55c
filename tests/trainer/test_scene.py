"""Scene models: trained on just the region a scene's render settings use, cached by content
hash, and chosen as the cheapest model that meets the scene's error budget (real torch
training on small data, real onnxruntime)."""

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core.lensfile import load_lens, loads_lens
from neurolens_addon.core.rays import Rays, RayStatus
from neurolens_addon.core.scene_needs import RenderNeeds, training_region
from neurolens_addon.neural.cache import cached_models, cached_scene_model
from neurolens_addon.neural.choice import choose_model
from neurolens_addon.neural.model import LearnedLens
from trainer.fit import FitConfig
from trainer.pipeline import model_storage_bytes
from trainer.scene import cache_config, fit_for_scene, scene_config

pytestmark = pytest.mark.slow          # trains models

ROOT = Path(__file__).resolve().parents[2]
COOKE = ROOT / "presets" / "lenses" / "cooke_triplet_f4.toml"
SMALL = FitConfig(theta=4, ensemble=3, max_depth=1, min_cell_samples=2000, member_samples=3000,
                  lm_iterations=8, cell_time_budget_s=20)
RAYS = 30_000


def cooke_needs(border=(0.0, 0.0, 1.0, 1.0)):
    """4000 px across a 36 mm frame at f/4, focused at 3 m, budget 0.37 px (3.3 um): the
    full frame needs a split cell, the centre does not."""
    return RenderNeeds(4000, 2666, 36.0, 24.0, border=border, f_numbers=(4.0,),
                       focus_distances_m=(3.0,), pixel_fraction=0.37)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    lens = load_lens(COOKE)
    root = tmp_path_factory.mktemp("models")
    full, t1 = fit_for_scene(lens, cooke_needs(), root, base=SMALL, n_rays=RAYS,
                             eval_rays=60_000, log=lambda *a: None)
    crop, t2 = fit_for_scene(lens, cooke_needs((0.4, 0.4, 0.6, 0.6)), root, base=SMALL,
                             n_rays=RAYS, eval_rays=60_000, log=lambda *a: None)
    assert t1 and t2
    return lens, root, full, crop


def test_01_cropped_model_is_smaller_and_meets_its_budget(trained):
    """The model of the centre region has fewer cells and bytes than the full frame's, and its
    measured image error (on that region) is within the scene's budget."""
    lens, root, full, crop = trained
    mf = json.loads((full / "model.json").read_text())
    mc = json.loads((crop / "model.json").read_text())
    cells = lambda m: sum(len(s.get("cells", [])) for s in m["stages"])
    assert cells(mc) < cells(mf)
    assert model_storage_bytes(crop) < model_storage_bytes(full)
    budget = cooke_needs((0.4, 0.4, 0.6, 0.6)).error_budget_um()
    assert mc["evaluation"]["image_error_um_p99"] <= budget
    assert mc["domain"]["film_radius_mm"] < 0.3 * mf["domain"]["film_radius_mm"]


def test_02_rays_outside_the_cropped_area_are_flagged(trained):
    """Film points beyond the region's radius come back OUT_OF_DOMAIN, never as rays; those
    inside pass; an aperture wider than the scene's is refused with a clear error."""
    lens, root, full, crop = trained
    model = LearnedLens.load(crop, lens=lens)
    r_max = model.domain["film_radius_mm"]
    z = 0.5 * sum(model.domain["sensor_z_range"])
    n = 2000
    x = np.concatenate([np.full(n, 0.5 * r_max), np.full(n, 2.0 * r_max)])
    o = np.stack([x, np.zeros(2 * n), np.full(2 * n, z)])
    rng = np.random.default_rng(0)
    d = np.stack([rng.uniform(-0.03, 0.03, 2 * n), rng.uniform(-0.03, 0.03, 2 * n),
                  np.ones(2 * n)])
    d /= np.linalg.norm(d, axis=0)
    res = model.trace_from_sensor(Rays(o, d, np.full(2 * n, 550.0)), sensor_z=z)
    assert (res.status[n:] == RayStatus.OUT_OF_DOMAIN).all()
    assert not res.rays.o[:, n:].any()
    assert res.valid[:n].mean() > 0.2
    with pytest.raises(Exception, match="trained for stop radii up to"):
        model.trace_from_sensor(Rays(o, d, np.full(2 * n, 550.0)), sensor_z=z,
                                stop_radius=2.0 * model.domain["stop_radius_mm"])


def test_03_cache_is_reused_by_a_new_process_and_invalidated_by_a_lens_edit(trained):
    """A fresh interpreter (as after a Blender restart) finds the cached model without
    training; an edited prescription (new content hash) has no cached model."""
    lens, root, full, crop = trained
    code = (
        "import sys, json; sys.path.insert(0, %r)\n"
        "from neurolens_addon.core.lensfile import load_lens\n"
        "from trainer.scene import fit_for_scene\n"
        "from tests.trainer.test_scene import SMALL, RAYS, cooke_needs\n"
        "p, trained = fit_for_scene(load_lens(%r), cooke_needs(), %r, base=SMALL, n_rays=RAYS,"
        " log=lambda *a: None)\n"
        "print(json.dumps([str(p), trained]))\n") % (str(ROOT), str(COOKE), str(root))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    path, trained_now = json.loads(out.stdout.strip().splitlines()[-1])
    assert Path(path) == full and trained_now is False
    edited = loads_lens(COOKE.read_text().replace("radius = 23.713", "radius = 23.8", 1))
    cfg = cache_config(scene_config(edited, cooke_needs(), SMALL), RAYS)
    region = training_region(edited, cooke_needs())
    assert edited.content_hash() != lens.content_hash()
    assert cached_scene_model(root, edited, region, cfg) is None
    assert sorted(cached_models(root)) == sorted([full, crop])


def test_04_choice_takes_the_cheapest_model_that_meets_the_budget(trained):
    """For the centre region both models cover it: the trainer recorded what a camera ray
    costs in the engine through each and through the exact trace, and the qualifying one
    cheapest against the exact trace is chosen where it is the cheaper, else the exact trace
    (saying so); for the full frame only the full model covers it; when the budget is
    tighter than every model, the exact trace is chosen and the reason names why."""
    lens, root, full, crop = trained
    models = cached_models(root)
    centre = cooke_needs((0.4, 0.4, 0.6, 0.6))
    c = choose_model(models, centre, training_region(lens, centre), lens.content_hash())
    qualifying = [o for o in c.considered if o.covers]
    assert {o.path for o in qualifying} == {full, crop}
    assert all(o.cost_us > 0 and o.exact_cost_us > 0 for o in qualifying)
    best = min(qualifying, key=lambda o: o.cost_us / o.exact_cost_us)
    if best.cost_us < best.exact_cost_us:
        assert c.option.kind == "learned" and c.option.path == best.path
    else:
        assert c.option.kind == "exact" and c.reason.startswith(
            f"exact trace: cheaper in the NEUROLENS engine than {best.name}")
    assert c.renderer == "neurolens"
    whole = cooke_needs()
    cw = choose_model(models, whole, training_region(lens, whole), lens.content_hash())
    names = {o.path: o for o in cw.considered}
    assert not names[crop].covers and "film radius" in names[crop].why_not
    strict = replace(whole, pixel_fraction=1e-4)
    cs = choose_model(models, strict, training_region(lens, strict), lens.content_hash())
    assert cs.option.kind == "exact" and "no learned model meets the budget" in cs.reason
    other = choose_model(models, whole, training_region(lens, whole), "f" * 16)
    assert other.option.kind == "exact" and not other.considered
