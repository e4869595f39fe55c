"""Model AUTO: the cheapest way through a lens, on the renderer that renders the frame, that
meets the scene's error budget.

The scene's render settings (core.scene_needs.RenderNeeds) give an error budget and the
region of the lens's input space the frames use; among the lens's learned models whose
recorded image error (p99) meets the budget and whose domain covers the region,
neural.choice.choose_model picks the one cheaper per camera ray than the exact trace on that
renderer (the engine or Cycles: model.json's measured costs), else the exact trace. Only the
widest and narrowest f-number and the nearest and farthest focus distance decide the region
(best focus moves monotonically with either), so a choice costs at most four focus solves
however long the animation. Choices are cached by (lens content hash, those needs, the
candidate models' model.json stat, the renderer), so redrawing the panel costs a few stat()
calls.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path

from ..core.errors import NeuroLensError
from ..core.scene_needs import RenderNeeds, TrainingRegion, training_region
from .focusing import focus_sensor_z_mm, not_nearer_m
from .lru import cache
from .models import model_dirs, models_of_lens

EXACT_NAME = "exact trace"
_CHOICES = cache(256)      # (lens hash, needs, candidate stats, renderer) -> ModelChoice


@dataclass(frozen=True)
class ModelChoice:
    """What model AUTO uses for a camera, its expected error and why (for the panel)."""

    kind: str                       # "learned" | "exact"
    name: str                       # shown in the panel
    path: str | None                # the model directory (learned)
    error_um_p99: float             # the model's recorded image error, 99th percentile (um)
    budget_um: float                # the scene's budget (um on the sensor); nan: unknown
    pixel_fraction: float           # the budget in pixels
    reason: str
    trainable: bool = False         # exact because no learned model meets the budget
    notes: tuple = ()               # how the render settings were read (animation, focus object)
    considered: tuple = ()          # ((model name, why it does not qualify or ""), ...)
    needs: object = None            # the RenderNeeds (reduced to the region's) it was made for
    renderer: str = "neurolens"     # the renderer it was made for (neural.choice.RENDERER_NAMES)
    cost_us: float | None = None    # a camera ray through what it chose (us; the exact
                                    # trace's when it chose that); None: not measured
    exact_cost_us: float | None = None   # through the exact trace, in the run that measured it

    @property
    def summary(self) -> str:
        budget = (f"budget {self.budget_um:.3g} \u00b5m = {self.pixel_fraction:g} px"
                  if math.isfinite(self.budget_um) else f"budget {self.pixel_fraction:g} px")
        cost = (f"; {self.cost_us:.3g} \u00b5s a camera ray" if self.cost_us is not None
                else "")
        return (f"Using: {self.name} \u2014 expected error p99 {self.error_um_p99:.3g} \u00b5m "
                f"({budget}{cost})")

    def instead_exact(self, reason: str, *, trainable: bool | None = None,
                      unfit: str | None = None, all_unfit: bool = False) -> "ModelChoice":
        """This choice overruled: the exact trace is used, for `reason`. The model it had
        chosen (or, with all_unfit, every learned model it weighed) is listed as not
        qualifying, for `unfit`."""
        considered = self.considered
        if unfit is not None:
            chosen = display_name(Path(self.path)) if self.path else None
            considered = tuple((name, unfit if not why and (all_unfit or name == chosen)
                                else why) for name, why in considered)
        return dataclasses.replace(
            self, kind="exact", name=EXACT_NAME, path=None, error_um_p99=0.0, reason=reason,
            trainable=self.trainable if trainable is None else trainable,
            cost_us=self.exact_cost_us, considered=considered)


def region_needs(needs: RenderNeeds, entry) -> RenderNeeds:
    """`needs` reduced to what decides the region on the lens of `entry` (module docstring),
    focus distances clamped to the closest focus as the render clamps them, the film the
    lens's own (an anamorphic lens's: narrowed by its squeeze)."""
    fs = sorted(set(needs.f_numbers))
    f = (fs[0], fs[-1]) if len(fs) > 1 else tuple(fs)
    ds = sorted({not_nearer_m(entry, d) for d in needs.focus_distances_m})
    focus = (ds[0], ds[-1]) if len(ds) > 1 else tuple(ds)
    return dataclasses.replace(needs, f_numbers=f, focus_distances_m=focus,
                               squeeze=float(entry.squeeze))


def scene_region(entry, needs: RenderNeeds) -> TrainingRegion:
    """The input region `needs` (from region_needs) uses on the lens of `entry`, with the
    focus solves going through the shared cache; trainer.scene trains on the same region."""
    return training_region(entry.lens, needs, focus_z=lambda _lens, d_mm, stop:
                           focus_sensor_z_mm(entry, d_mm, stop))


def display_name(path: Path) -> str:
    from ..neural.cache import CACHE_DIR
    stem = path.name.removesuffix(".neurolens")
    if path.parent.name == CACHE_DIR:
        return f"scene model {stem.rsplit('-', 1)[-1][:8]}"
    return f"learned model {stem}"


def choose_for_scene(entry, needs: RenderNeeds | None, candidates, *,
                     needs_error: str | None = None, pixel_fraction: float = 0.5,
                     renderer: str = "neurolens") -> ModelChoice:
    """The model AUTO uses for a lens (`entry`) in a scene rendered by `renderer` ("neurolens"
    or "cycles"; cached; module docstring). `needs` None: the render settings describe no
    image (`needs_error` says why)."""
    if needs is None:
        return ModelChoice("exact", EXACT_NAME, None, 0.0, math.nan, pixel_fraction,
                           f"exact trace: the render settings describe no image ({needs_error})",
                           renderer=renderer)
    notes = tuple(needs.extras.get("notes", ()))
    rneeds = region_needs(needs, entry)
    found = model_dirs(candidates)
    key = (entry.content_hash, json.dumps(rneeds.as_dict(), sort_keys=True),
           tuple(k for _d, k in found), renderer)
    hit = _CHOICES.get_lru(key)
    if hit is None:
        hit = _CHOICES.put(key, _choose(entry, rneeds, candidates, renderer))
    return dataclasses.replace(hit, notes=notes) if notes else hit


def _choose(entry, needs: RenderNeeds, candidates, renderer: str) -> ModelChoice:
    from ..neural.choice import choose_model

    pf = needs.pixel_fraction
    budget = needs.error_budget_um()
    # a scene model can pay in the engine; in Cycles the learned camera costs more a ray than
    # the exact one for every lens measured (docs/bench/model_costs.md): no offer to train
    trainable = renderer == "neurolens"
    offer = " (train a model for this scene to render faster)" if trainable else ""
    mine = models_of_lens(entry.content_hash, candidates)
    if not mine:
        # nothing to judge: the scene's region of the lens (image-circle traces, a second or
        # so on a long zoom at each new focal length) is not worked out
        return ModelChoice("exact", EXACT_NAME, None, 0.0, budget, pf,
                           f"No learned model of '{entry.name}' yet: the exact trace is "
                           f"used{offer}", trainable=trainable, needs=needs, renderer=renderer)
    try:
        region = scene_region(entry, needs)
    except NeuroLensError as exc:
        return ModelChoice("exact", EXACT_NAME, None, 0.0, budget, pf,
                           f"exact trace: the scene's region of the lens is unknown ({exc})",
                           needs=needs, renderer=renderer)
    c = choose_model(mine, needs, region, entry.content_hash, renderer)
    considered = tuple((display_name(o.path), o.why_not) for o in c.considered)
    o = c.option
    costs = dict(renderer=renderer, cost_us=o.cost_us, exact_cost_us=o.exact_cost_us)
    if o.kind == "learned":
        return ModelChoice("learned", display_name(o.path), str(o.path),
                           float(o.image_error_um_p99), c.budget_um, pf,
                           f"The cheapest model within the budget: {c.reason}",
                           considered=considered, needs=needs, **costs)
    if any(not why for _name, why in considered):
        # a model meets the budget: the exact trace is the cheaper (or the only priced) way
        reason = c.reason[:1].upper() + c.reason[1:]
        return ModelChoice("exact", EXACT_NAME, None, 0.0, c.budget_um, pf, reason,
                           considered=considered, needs=needs, **costs)
    if not c.considered:
        reason = f"No learned model of '{entry.name}' yet: the exact trace is used{offer}"
    else:
        reason = "No learned model meets the budget: " + "; ".join(
            f"{name}: {why}" for name, why in considered)
    return ModelChoice("exact", EXACT_NAME, None, 0.0, c.budget_um, pf, reason,
                       trainable=trainable, considered=considered, needs=needs, **costs)
