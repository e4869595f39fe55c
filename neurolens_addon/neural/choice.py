"""Which lens model a scene should use: the cheapest that meets its error budget.

A learned model qualifies for a scene when
  * its training domain covers the scene's region (core.scene_needs.TrainingRegion): film
    radii, sensor positions (focus range), stop radius (widest f-number), wavelengths;
  * its measured image-space error (model.json "evaluation", written by
    `python -m trainer evaluate MODEL --lens LENS --record`) has a 99th percentile within the
    budget, e = pixel_fraction * pixel pitch (core.scene_needs.RenderNeeds.error_budget_um).
Among qualifying models the fastest (measured onnx_rays_per_s) wins. The exact trace has no
model error and is always available: it is the choice when no learned model qualifies (and the
reason says why, so the panel can offer to train a scene model). Blender's thin lens is never
chosen automatically: it is a different lens, not an approximation with a known error.

Scene models trained for one region live in a cache keyed by content hash (neural.cache).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..core.errors import ModelError
from ..core.scene_needs import RenderNeeds, TrainingRegion
from .modelfile import read_header

REL_TOL = 1e-6


@dataclass(frozen=True)
class ModelOption:
    """One lens model a camera could use."""

    kind: str                          # "learned" | "exact"
    name: str
    path: Path | None
    image_error_um_p99: float          # 0 for the exact trace
    rays_per_s: float | None           # measured; None when not measured
    covers: bool
    why_not: str = ""                  # why it does not qualify ("" when it does)


@dataclass(frozen=True)
class Choice:
    option: ModelOption
    budget_um: float
    reason: str
    considered: tuple[ModelOption, ...]


def _covers(domain: dict, region: TrainingRegion) -> str:
    """"" when a model's training domain holds the region, else what it lacks."""
    eps = lambda v: abs(v) * REL_TOL + 1e-9
    if float(domain.get("film_radius_mm", 0.0)) + eps(region.film_radius_mm) < region.film_radius_mm:
        return (f"film radius {domain.get('film_radius_mm'):.3g} mm < the scene's "
                f"{region.film_radius_mm:.3g} mm")
    if float(domain.get("film_radius_min_mm", 0.0)) > region.film_radius_min_mm + 1e-9:
        return "trained on a ring that misses the centre of the rendered film"
    lo, hi = (float(v) for v in domain.get("sensor_z_range", (0.0, 0.0)))
    zlo, zhi = region.sensor_z_range
    if lo > zlo + eps(zlo) or hi < zhi - eps(zhi):
        return "focus range narrower than the scene's focus distances"
    stop = domain.get("stop_radius_mm")
    if stop is not None and float(stop) + eps(region.stop_radius_mm) < region.stop_radius_mm:
        return "trained for a smaller aperture than the scene's widest f-number"
    wlo, whi = (float(v) for v in domain.get("wavelength_range_nm", (0.0, 0.0)))
    slo, shi = region.wavelength_range_nm
    if wlo > slo + 1e-6 or whi < shi - 1e-6:
        return "wavelength range narrower than the scene's"
    return ""


def learned_option(model_dir: Path, region: TrainingRegion, budget_um: float,
                   lens_hash: str | None = None) -> ModelOption | None:
    """A model directory as an option for this region (None: not a readable model or made
    for another lens). Only its header is read: loading the graphs waits for the choice."""
    try:
        header = read_header(model_dir)
    except ModelError:
        return None
    if lens_hash is not None and header.lens_content_hash != lens_hash:
        return None
    p99 = header.image_error_um_p99
    why = _covers(header.domain, region)
    if not why and p99 is None:
        why = "never evaluated (python -m trainer evaluate MODEL --lens LENS --record)"
    elif not why and p99 > budget_um:
        why = f"image error p99 {p99:.3g} um > budget {budget_um:.3g} um"
    return ModelOption("learned", Path(model_dir).name, Path(model_dir),
                       float("inf") if p99 is None else p99, header.onnx_rays_per_s, not why,
                       why)


def choose_model(model_dirs, needs: RenderNeeds, region: TrainingRegion,
                 lens_hash: str | None = None, exact_rays_per_s: float | None = None) -> Choice:
    """The cheapest option meeting the scene's budget among `model_dirs` and the exact trace."""
    budget = needs.error_budget_um()
    options = [o for o in (learned_option(Path(d), region, budget, lens_hash)
                           for d in model_dirs) if o is not None]
    good = [o for o in options if o.covers]
    exact = ModelOption("exact", "exact trace", None, 0.0, exact_rays_per_s, True)
    if good:
        best = max(good, key=lambda o: (o.rays_per_s or 0.0, -o.image_error_um_p99))
        reason = (f"{best.name}: image error p99 {best.image_error_um_p99:.3g} um within the "
                  f"budget {budget:.3g} um ({needs.pixel_fraction:g} px)")
        if exact_rays_per_s and best.rays_per_s and best.rays_per_s <= exact_rays_per_s:
            best, reason = exact, (f"exact trace: as fast as the best learned model "
                                   f"({reason})")
        return Choice(best, budget, reason, tuple(options))
    why = "; ".join(f"{o.name}: {o.why_not}" for o in options) or "no learned model"
    return Choice(exact, budget, f"exact trace: no learned model meets the budget "
                                 f"{budget:.3g} um ({why})", tuple(options))
