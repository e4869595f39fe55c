"""What a camera ray costs through every shipped model and through the exact trace, per
renderer, and what model AUTO therefore picks on each.

For every model in presets/models, `trainer.cost.measure` (its docstring: the engine's lens
stage on 65,536 camera rays of the model's domain, best of 3; Cycles' OSL cameras against an
empty sky, net of Blender's perspective camera and of a one-sample render) on this machine,
recorded into the model's model.json ("costs"), where neural.choice reads them: the shipped
models carry the figures of the machine that ran this section last. The model's lens: its
preset, at the focal length (`.zoomXmm`) or focus (`.focusXmm`) its name says. AUTO on a
renderer takes the model where its cost is below the exact trace's (the image error budget
permitting), else the exact trace.

    python -m benchmarks.run model_costs
"""

from __future__ import annotations

import re

from .common import ROOT, md_table

MODELS = ROOT / "presets" / "models"
LENSES = ROOT / "presets" / "lenses"
_VARIANT = re.compile(r"^(?P<lens>[a-z0-9_]+)(\.(?P<kind>zoom|focus)(?P<mm>[0-9.]+)mm)?"
                      r"(\.lean)?\.neurolens$")


def model_lens(model_dir):
    """(the lens a shipped model was trained for, its preset name)."""
    from neurolens_addon.core.lensfile import load_lens
    from trainer.__main__ import grouped, zoomed
    m = _VARIANT.match(model_dir.name)
    if m is None:
        raise ValueError(f"{model_dir.name}: not a shipped model's name")
    lens = load_lens(LENSES / f"{m['lens']}.toml")
    mm = float(m["mm"]) if m["mm"] else None
    if m["kind"] == "zoom":
        lens = zoomed(lens, mm)
    elif m["kind"] == "focus":
        lens = grouped(lens, mm)
    return lens, m["lens"]


def run(renderers=("neurolens", "cycles")):
    from trainer.cost import measure, record_costs

    figs, rows = {}, []
    for model_dir in sorted(MODELS.glob("*.neurolens")):
        lens, preset = model_lens(model_dir)
        costs = measure(model_dir, lens, renderers)
        record_costs(model_dir, costs)
        print(f"[model_costs] {model_dir.name}: {costs}", flush=True)
        figs[model_dir.name] = costs
        row = [model_dir.name.removesuffix(".neurolens"), len(lens.surfaces)]
        for r in renderers:
            c = costs[r]
            ratio = c["learned_us"] / c["exact_us"]
            row += [f"{c['exact_us']:.3g}", f"{c['learned_us']:.3g}", f"{ratio:.2f}x",
                    "learned" if ratio < 1.0 else "exact"]
        rows.append(row)
    cheaper = {r: sum(1 for c in figs.values() if c[r]["learned_us"] < c[r]["exact_us"])
               for r in renderers}
    header = ["model", "surfaces"]
    for r in renderers:
        name = "engine" if r == "neurolens" else "Cycles"
        header += [f"{name} exact (us)", f"{name} learned (us)", f"{name} learned / exact",
                   f"AUTO in {name}"]
    text = "\n".join([
        "## What a camera ray costs, per renderer, and what AUTO picks",
        "",
        "Every shipped model (`benchmarks/model_costs.py`, `trainer/cost.py`): microseconds of "
        "wall clock a camera ray, all threads, through the exact trace and through the "
        "learned model, measured in one run: the engine's lens stage (65,536 camera rays of "
        "the model's domain in one batch, the compiled exact trace against onnxruntime on "
        "the CPU, best of 3) and Cycles' OSL cameras (160x120, 64 samples against an empty "
        "sky, net of Blender's perspective camera and a one-sample render, best of 3). The "
        "figures are recorded in each model's model.json, where AUTO reads them: it takes "
        "the learned model on a renderer only where it costs less than the exact trace there "
        "(and meets the frame's error budget). Learned cheaper than exact: "
        + ", ".join(f"{'the engine' if r == 'neurolens' else 'Cycles'} {cheaper[r]} of "
                    f"{len(figs)} models" for r in renderers) + ".",
        "",
        md_table(header, rows),
    ])
    return text, {"models": figs, "learned_cheaper": cheaper}
