"""Train (or reuse) a learned lens for just what one scene needs.

From the render settings (core.scene_needs.RenderNeeds) come the error budget e (micrometres
on the sensor) and the region of the input space the scene uses. The cell criterion of the
trainer is an RMS displacement 1 m in front of the lens (trainer.fit); a displacement D there
images to about D f / 1000 on the sensor (magnification f / 1000 at 1 m), so the cells are
fitted to
    threshold = SAFETY * e / f      (mm at 1 m; e in um, f the focal length in mm),
with SAFETY = 0.3 leaving room between the RMS the trainer controls and the 99th percentile
the budget bounds. After training the model is evaluated on its own region and the figures
are recorded in its model.json, where neural.choice reads them.

The region is core.scene_needs.training_region with its sensor range grown to hold the sensor
positions that focus the scene's distances *at its f-numbers* (`scene_region`): the render
focuses at the stop it uses and best focus moves with the aperture (about 1 mm for the
bi-convex singlet between f/4 and f/8), while training_region focuses at full aperture, so a
model trained on that alone is refused by the camera it was trained for. The add-on
(neurolens_addon.blender.scene_needs_bpy.scene_region) widens its region the same way.
"""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path

from neurolens_addon.core.prescription import Lens
from neurolens_addon.core.scene_needs import RenderNeeds, TrainingRegion, training_region
from neurolens_addon.neural.cache import cached_scene_model, scene_model_path

from .data import Domain
from .fit import FitConfig

SAFETY = 0.3
TRAINER_VERSION = 1            # part of the cache key: bump when training changes its output
SENSOR_PAD_MM = 1e-3           # as core.scene_needs pads the sensor range


def scene_region(lens: Lens, needs: RenderNeeds) -> TrainingRegion:
    """training_region, its sensor range grown to the positions focusing the extreme focus
    distances at the extreme f-numbers the scene uses (each at its own stop radius)."""
    from neurolens_addon.core.aperture import clamp_f_number, stop_radius_for_f_number
    from neurolens_addon.core.focus import focus_sensor_z
    region = training_region(lens, needs)
    fs = sorted({clamp_f_number(f, lens.f_number)[0] for f in needs.f_numbers})
    stops = [stop_radius_for_f_number(lens.stop_radius_mm, lens.f_number, f)
             for f in ((fs[0], fs[-1]) if fs else ())] or [lens.stop_radius_mm]
    ds = sorted(needs.focus_distances_m)
    zs = [float(focus_sensor_z(lens, 1000.0 * d, stop_radius=s))
          for d in ((ds[0], ds[-1]) if ds else ()) for s in stops]
    if not zs:
        return region
    lo, hi = region.sensor_z_range
    return replace(region, sensor_z_range=(min(lo, min(zs) - SENSOR_PAD_MM),
                                           max(hi, max(zs) + SENSOR_PAD_MM)))


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
                  n_rays: int = 200_000, eval_rays: int = 200_000, log=print) -> tuple[Path, bool]:
    """(model directory, trained now?) for the scene: the cached model when one exists for the
    same lens, region and settings, else a new one trained, evaluated and recorded."""
    from .pipeline import fit_lens
    cfg = scene_config(lens, needs, base)
    region = scene_region(lens, needs)
    key_cfg = cache_config(cfg, n_rays)
    hit = cached_scene_model(models_dir, lens, region, key_cfg)
    if hit is not None:
        log(f"scene model cached: {hit}")
        if "evaluation" not in json.loads((hit / "model.json").read_text()):
            _evaluate_and_record(hit, lens, needs, eval_rays, log)   # training was cut short
        return hit, False
    out = scene_model_path(models_dir, lens, region, key_cfg)
    out.parent.mkdir(parents=True, exist_ok=True)
    log(f"training a scene model for '{lens.name}': film r <= {region.film_radius_mm:.3g} mm, "
        f"stop r <= {region.stop_radius_mm:.3g} mm, budget {needs.error_budget_um():.3g} um "
        f"(cell threshold {cfg.error_threshold:.3g} mm at 1 m)")
    fit_lens(lens, out, cfg, n_rays=n_rays, dispersion=region.dispersion,
             domain=Domain.from_region(region), log=log)
    _evaluate_and_record(out, lens, needs, eval_rays, log)
    return out, True


def _evaluate_and_record(out: Path, lens: Lens, needs: RenderNeeds, eval_rays: int, log) -> dict:
    from neurolens_addon.neural.model import LearnedLens

    from .evaluate import evaluate_model, record_evaluation
    model = LearnedLens.load(out, lens=lens)
    res = evaluate_model(model, lens, n=eval_rays, speed_rays=min(eval_rays, 200_000))
    record_evaluation(out, {**res, "rays": eval_rays, "budget_um": needs.error_budget_um()})
    log(f"scene model {out.name}: image error p99 {res['image_error_um_p99']:.3g} um "
        f"(budget {needs.error_budget_um():.3g} um), {res['onnx_rays_per_s'] / 1e6:.2f} M rays/s")
    return res
