"""Which lens model a scene should use: the cheapest on the renderer that renders it, among
those that meet its error budget.

A learned model qualifies for a scene when
  * its training domain covers the scene's region (core.scene_needs.TrainingRegion): film
    radii, sensor positions (focus range), stop radius (widest f-number), wavelengths;
  * its measured image-space error (model.json "evaluation", written by
    `python -m trainer evaluate MODEL --lens LENS --record`) has a 99th percentile within the
    budget, e = pixel_fraction * pixel pitch (core.scene_needs.RenderNeeds.error_budget_um).
The exact trace has no model error and is always available. Cost: what a camera ray costs
through the model and through the exact trace on the renderer ("neurolens": the engine's lens
stage; "cycles": the OSL camera), both measured in one run on one machine (model.json
"costs": `python -m trainer cost MODEL --lens LENS --record` for the engine, the shipped
models' Cycles figures by benchmarks/model_costs.py); their ratio decides, so a
figure from another machine still ranks them. A qualifying model is chosen only where it is
cheaper than the exact trace on that renderer by more than the noise (MARGIN; the cheapest
of them); a model whose cost on that renderer was never measured is not chosen (the exact
trace is, and the reason says so).
Blender's thin lens is never chosen automatically: it is a different lens, not an
approximation with a known error.

Scene models trained for one region live in a cache keyed by content hash (neural.cache).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from ..core.errors import ModelError
from ..core.scene_needs import RenderNeeds, TrainingRegion
from .modelfile import read_header

REL_TOL = 1e-6


#: how the reasons name the renderers
RENDERER_NAMES = {"neurolens": "the NEUROLENS engine", "cycles": "Cycles"}
#: how a model's cost on a renderer is measured, for the reasons
HOW_MEASURED = {"neurolens": "python -m trainer cost MODEL --lens LENS --record, on a model in "
                             "your Trained Models folder",
                "cycles": "Cycles' figures come with the shipped models: benchmarks/"
                          "model_costs.py measures them in Blender's Python"}
#: a learned model is chosen only where a ray through it costs under this share of the exact
#: trace's: a model within measurement noise of the exact trace (5-10 % on a shared machine)
#: would make the pick flip between runs, and the exact trace has no model error
MARGIN = 0.95


@dataclass(frozen=True)
class ModelOption:
    """One lens model a camera could use."""

    kind: str                          # "learned" | "exact"
    name: str
    path: Path | None
    image_error_um_p99: float          # 0 for the exact trace
    covers: bool
    why_not: str = ""                  # why it does not qualify ("" when it does)
    cost_us: float | None = None       # a camera ray through this option on the renderer
                                       # (us; None: not measured)
    exact_cost_us: float | None = None  # through the exact trace, in the run that measured it


@dataclass(frozen=True)
class Choice:
    option: ModelOption
    budget_um: float
    reason: str
    considered: tuple[ModelOption, ...]
    renderer: str = "neurolens"


def _covers(domain: dict, region: TrainingRegion) -> str:
    """"" when a model's training domain holds the region, else what it lacks."""
    def eps(v):
        return abs(v) * REL_TOL + 1e-9

    film = float(domain.get("film_radius_mm", 0.0))
    if film + eps(region.film_radius_mm) < region.film_radius_mm:
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
                   lens_hash: str | None = None,
                   renderer: str = "neurolens") -> ModelOption | None:
    """A model directory as an option for this region on `renderer` (None: not a readable
    model or made for another lens). Only its header is read: loading the graphs waits for
    the choice."""
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
    cost = header.ray_cost_us(renderer)
    exact_us, learned_us = (None, None) if cost is None else cost
    return ModelOption("learned", Path(model_dir).name, Path(model_dir),
                       float("inf") if p99 is None else p99, not why, why, learned_us, exact_us)


def _costs(o: ModelOption, where: str) -> str:
    return (f"{o.cost_us:.3g} us a camera ray in {where} against the exact trace's "
            f"{o.exact_cost_us:.3g} us")


def choose_model(model_dirs, needs: RenderNeeds, region: TrainingRegion,
                 lens_hash: str | None = None, renderer: str = "neurolens") -> Choice:
    """The cheapest option on `renderer` meeting the scene's budget among `model_dirs` and
    the exact trace (module docstring)."""
    budget = needs.error_budget_um()
    where = RENDERER_NAMES[renderer]
    options = [o for o in (learned_option(Path(d), region, budget, lens_hash, renderer)
                           for d in model_dirs) if o is not None]
    good = [o for o in options if o.covers]
    priced = [o for o in good if o.cost_us is not None]
    # the exact trace's cost: as measured beside the chosen model, else the middle of the
    # lens's models' figures (one per measurement run)
    runs = sorted(o.exact_cost_us for o in options if o.exact_cost_us is not None)
    middle = runs[len(runs) // 2] if runs else None
    exact = ModelOption("exact", "exact trace", None, 0.0, True, cost_us=middle,
                        exact_cost_us=middle)

    def chose(option, reason):
        return Choice(option, budget, reason, tuple(options), renderer)

    if priced:
        # the ratio to the exact trace measured in the same run ranks them on any machine
        best = min(priced, key=lambda o: (o.cost_us / o.exact_cost_us, o.image_error_um_p99))
        error = (f"image error p99 {best.image_error_um_p99:.3g} um within the budget "
                 f"{budget:.3g} um ({needs.pixel_fraction:g} px)")
        if best.cost_us < MARGIN * best.exact_cost_us:
            return chose(best, f"{best.name}: {_costs(best, where)}; {error}")
        beside = replace(exact, cost_us=best.exact_cost_us, exact_cost_us=best.exact_cost_us)
        if best.cost_us < best.exact_cost_us:
            return chose(beside, f"exact trace: as cheap in {where} as {best.name} (within "
                                 f"{100 * (1 - MARGIN):.0f} %), and without model error "
                                 f"({_costs(best, where)}; {error})")
        return chose(beside, f"exact trace: cheaper in {where} than {best.name}, which meets "
                             f"the budget ({_costs(best, where)}; {error})")
    if good:
        names = ", ".join(o.name for o in good)
        return chose(exact, f"exact trace: {names} meet{'s' if len(good) == 1 else ''} the "
                            f"budget, but what a camera ray costs through "
                            f"{'it' if len(good) == 1 else 'them'} in {where} was never "
                            f"measured ({HOW_MEASURED[renderer]})")
    why = "; ".join(f"{o.name}: {o.why_not}" for o in options) or "no learned model"
    return chose(exact, f"exact trace: no learned model meets the budget {budget:.3g} um "
                        f"({why})")
