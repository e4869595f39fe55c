"""What a camera ray costs through every shipped model and through the exact trace, per
renderer, and what model AUTO therefore picks on each.

For every model in presets/models, `trainer.cost.measure` (the engine's lens stage on 65,536
camera rays of the model's domain, best of 3) and `neurolens_addon.blender.cycles_cost`
(Cycles' OSL cameras against an empty sky, net of Blender's perspective camera and of a
one-sample render) on this machine,
recorded into the model's model.json ("costs"), where neural.choice reads them: the shipped
models carry the figures of the machine that ran this section last. The model's lens: its
preset, at the focal length (`.zoomXmm`) or focus (`.focusXmm`) its name says. AUTO on a
renderer takes the model where its cost is below the exact trace's by more than the noise
(neural.choice.MARGIN; the image error budget permitting), else the exact trace.

    python -m benchmarks.run model_costs
"""

from __future__ import annotations

from .common import ROOT, lens_of_model, md_table

MODELS = ROOT / "presets" / "models"
LENSES = ROOT / "presets" / "lenses"
def model_lens(model_dir):
    """The lens a shipped model was trained for: its preset at the zoom or focus position its
    name says (common.lens_of_model, matched by the content hash the model records)."""
    from neurolens_addon.core.lensfile import load_lens
    preset = model_dir.name.split(".", 1)[0]
    return lens_of_model(load_lens(LENSES / f"{preset}.toml"), model_dir)


def _recorded(model_dir, renderers) -> dict | None:
    """The model's recorded costs when model.json has every renderer's, else None."""
    import json
    costs = json.loads((model_dir / "model.json").read_text()).get("costs") or {}
    return costs if all(r in costs for r in renderers) else None


def run(renderers=("neurolens", "cycles"), resume: bool = False, only=None):
    """Measure and record every shipped model's costs; with `resume`, only those of models
    whose model.json lacks a renderer's (a model Cycles cannot render is tried again, and
    says why at once); with `only` (preset stems), only those presets' models. The others'
    recorded figures fill the report."""
    from neurolens_addon.blender.cycles_cost import cycles_cost
    from neurolens_addon.core.errors import NeuroLensError
    from trainer.cost import measure, record_costs

    figs, unmeasured = {}, {}
    for model_dir in sorted(MODELS.glob("*.neurolens")):
        kept = _recorded(model_dir, renderers) if (resume or only is not None) else None
        if only is not None and model_dir.name.split(".", 1)[0] not in only:
            kept = _recorded(model_dir, ()) or {}
        if kept is not None:
            figs[model_dir.name] = kept
            continue
        lens = model_lens(model_dir)
        costs = measure(model_dir, lens)            # the engine's, stamped
        if "cycles" in renderers:
            try:
                costs["cycles"] = {**cycles_cost(model_dir, lens),
                                   **{k: costs["neurolens"][k] for k in ("date", "machine")}}
            except NeuroLensError as exc:           # a model Cycles cannot render
                unmeasured[model_dir.name] = str(exc)
        record_costs(model_dir, costs)
        print(f"[model_costs] {model_dir.name}: {costs}", flush=True)
        figs[model_dir.name] = costs
    return report(figs, unmeasured, renderers)


def report(figs: dict, unmeasured: dict, renderers=("neurolens", "cycles")):
    """(markdown, figures) of the costs measured ({model directory name: costs}), and why a
    renderer's were not ({name: reason})."""
    from neurolens_addon.core.lensfile import load_lens
    from neurolens_addon.neural.choice import MARGIN
    from neurolens_addon.neural.modelfile import read_header

    rows = []
    for name, costs in figs.items():
        surfaces = len(load_lens(LENSES / f"{name.split('.', 1)[0]}.toml").surfaces)
        p99 = read_header(MODELS / name).image_error_um_p99
        row = [name.removesuffix(".neurolens"), surfaces, "" if p99 is None else f"{p99:.3g}"]
        for r in renderers:
            c = costs.get(r)
            if c is None:           # Cycles cannot render it (said why)
                row += ["", "", "", f"exact ({unmeasured.get(name) or 'not measured'})"]
                continue
            ratio = c["learned_us"] / c["exact_us"]
            row += [f"{c['exact_us']:.3g}", f"{c['learned_us']:.3g}", f"{ratio:.2f}x",
                    "learned" if ratio < MARGIN else "exact"]
        rows.append(row)
    cheaper = {r: sum(1 for c in figs.values() if r in c
                      and c[r]["learned_us"] < MARGIN * c[r]["exact_us"]) for r in renderers}
    header = ["model", "surfaces", "image error p99 (um)"]
    for r in renderers:
        name = "engine" if r == "neurolens" else "Cycles"
        header += [f"{name} exact (us)", f"{name} learned (us)", f"{name} learned / exact",
                   f"{name}: learned or exact, on cost"]
    text = "\n".join([
        "## What a camera ray costs, per renderer, and what AUTO picks",
        "",
        "Every shipped model (`benchmarks/model_costs.py`, `trainer/cost.py`): microseconds of "
        "wall clock a camera ray, all threads, through the exact trace and through the "
        "learned model, measured in one run: the engine's lens stage (65,536 camera rays of "
        "the model's domain in one batch, the compiled exact trace against onnxruntime on "
        "the CPU, best of 3) and Cycles' OSL cameras (160x120, 64 samples against an empty "
        "sky, net of Blender's perspective camera and a one-sample render, best of 3), and "
        "the model's recorded image error (p99 on the sensor, `trainer evaluate`). The "
        "figures are recorded in each model's model.json, where AUTO reads them: it takes "
        f"the learned model on a renderer only where it costs under {MARGIN:g} times the "
        "exact trace there (measurement noise; and meets the frame's error budget), the "
        "cheapest such where a lens has several (a lens of 25 surfaces or more has a full "
        "model and a sparse one: one network a cell, the sparse skip basis). Learned "
        "that much cheaper than exact: "
        + ", ".join(f"{'the engine' if r == 'neurolens' else 'Cycles'} {cheaper[r]} of "
                    f"{len(figs)} models" for r in renderers) + ".",
        "",
        md_table(header, rows),
    ])
    return text, {"models": figs, "learned_cheaper": cheaper}
