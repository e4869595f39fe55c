"""Train (or reuse) a learned lens for just what one scene needs.

From the render settings (core.scene_needs.RenderNeeds) come the error budget e (micrometres
on the sensor) and the region of the input space the scene uses. The cell criterion of the
trainer is an RMS displacement 1 m in front of the lens (trainer.fit); a displacement D there
images to about D f / 1000 on the sensor (magnification f / 1000 at 1 m), so the cells are
fitted to
    threshold = SAFETY * e / f      (mm at 1 m; e in um, f the focal length in mm),
with SAFETY = 0.3 leaving room between the RMS the trainer controls and the 99th percentile
the budget bounds. After training the model is evaluated on its own region, what a camera
ray costs through it and through the exact trace in the engine is measured on this machine
(trainer.cost), and the figures are recorded in its model.json, where neural.choice reads
them.

The region is core.scene_needs.training_region (which holds the sensor positions that focus
the scene's distances at its own f-numbers, so a model covers the camera it was trained for),
the same one the add-on's automatic choice asks for.
"""

from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path

from neurolens_addon.core.prescription import Lens
from neurolens_addon.core.scene_needs import RenderNeeds, training_region
from neurolens_addon.neural.cache import cached_scene_model, scene_model_path
from neurolens_addon.neural.modelfile import read_header

from .data import Domain
from .fit import FitConfig

SAFETY = 0.3
TRAINER_VERSION = 1            # part of the cache key: bump when training changes its output


def scene_config(lens: Lens, needs: RenderNeeds, base: FitConfig | None = None) -> FitConfig:
    """The fit settings for a scene: the base config with the cell threshold from the budget."""
    base = base or FitConfig()
    threshold = SAFETY * needs.error_budget_um() / max(lens.focal_length_mm, 1e-9)
    return replace(base, error_threshold=threshold, progress=False)


def cache_config(cfg: FitConfig, n_rays: int) -> dict:
    """What of the fit settings decides the model (part of the cache key)."""
    d = asdict(cfg)
    d.pop("progress", None)
    d.pop("cell_time_budget_s", None)
    return {**d, "n_rays": n_rays, "trainer_version": TRAINER_VERSION}


def fit_for_scene(lens: Lens, needs: RenderNeeds, models_dir, *, base: FitConfig | None = None,
                  n_rays: int = 200_000, eval_rays: int = 200_000,
                  log=print) -> tuple[Path, bool]:
    """(model directory, trained now?) for the scene: the cached model when one exists for the
    same lens, region and settings, else a new one trained, evaluated and recorded."""
    from .pipeline import fit_lens
    cfg = scene_config(lens, needs, base)
    region = training_region(lens, needs)
    key_cfg = cache_config(cfg, n_rays)
    hit = cached_scene_model(models_dir, lens, region, key_cfg)
    if hit is not None:
        log(f"scene model cached: {hit}")
        header = read_header(hit)
        if header.evaluation is None:
            _evaluate_and_record(hit, lens, needs, eval_rays, log)   # training was cut short
        if header.ray_cost_us("neurolens") is None:
            _measure_and_record(hit, lens, log)
        return hit, False
    out = scene_model_path(models_dir, lens, region, key_cfg)
    out.parent.mkdir(parents=True, exist_ok=True)
    log(f"training a scene model for '{lens.name}': film r <= {region.film_radius_mm:.3g} mm, "
        f"stop r <= {region.stop_radius_mm:.3g} mm, budget {needs.error_budget_um():.3g} um "
        f"(cell threshold {cfg.error_threshold:.3g} mm at 1 m)")
    fit_lens(lens, out, cfg, n_rays=n_rays, dispersion=region.dispersion,
             domain=Domain.from_region(region), log=log)
    _evaluate_and_record(out, lens, needs, eval_rays, log)
    _measure_and_record(out, lens, log)
    return out, True


def _measure_and_record(out: Path, lens: Lens, log) -> None:
    from .cost import measure, record_costs, summary
    costs = measure(out, lens)
    record_costs(out, costs)
    log(f"scene model {out.name}: {summary(costs)}")


def _evaluate_and_record(out: Path, lens: Lens, needs: RenderNeeds, eval_rays: int, log) -> dict:
    from neurolens_addon.neural.model import LearnedLens

    from .evaluate import evaluate_model, record_evaluation
    model = LearnedLens.load(out, lens=lens)
    res = evaluate_model(model, lens, n=eval_rays, speed_rays=min(eval_rays, 200_000))
    record_evaluation(out, {**res, "rays": eval_rays, "budget_um": needs.error_budget_um()})
    log(f"scene model {out.name}: image error p99 {res['image_error_um_p99']:.3g} um "
        f"(budget {needs.error_budget_um():.3g} um), {res['onnx_rays_per_s'] / 1e6:.2f} M rays/s")
    return res
