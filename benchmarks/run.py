"""`make bench`: run the benchmark sections and rewrite docs/BENCHMARKS.md.

`python -m benchmarks.run [--resume] [SECTION ...]` runs only the named sections; every
section's last text is kept in docs/bench/SECTION.md and docs/bench/SECTION.json, and
BENCHMARKS.md is assembled from all of them, so rerunning one section never drops another.
`--resume`: the sections that measure lens after lens (pareto, render_tradeoff) measure only the
lenses whose file or models changed since their kept figures (common.LensRecords), and
model_costs only the models whose model.json has no costs yet;
`--lenses STEM,STEM`: those sections (and auto_choice) measure only the named lenses and keep the
others' figures.

Blender: every section's machine line names the Blender (bpy) it ran in. The sections whose
figures come from Blender itself (Cycles, its BVH, the engine in its Python: BLENDER_SECTIONS)
can also run under another supported Blender, e.g. 5.2 LTS beside the main 5.0:
`.venv-5.2/bin/python -m benchmarks.run engine_vs_cycles cycles_overhead`. Their figures are
then kept as docs/bench/SECTION.blender-5.2.md (and .json), headed with that Blender, and
BENCHMARKS.md shows them right after the main Blender's, whose figures stay as they were
(Cycles' own speed changes between releases). Any other section run there replaces its figures,
its machine line saying so.
"""

from __future__ import annotations

import datetime
import json
import sys

import importlib

from .common import ROOT, blender_version, machine, main_blender

#: (section, its module, the function giving (markdown, figures)): modules are imported only
#: when their section runs, so a Python without torch (Blender 5.2's) runs the others
SECTIONS = [("exact_trace", "exact_trace", "run"),
            ("exact_compiled", "exact_compiled", "run"), ("learned", "learned", "run"),
            ("anamorphic_learned", "anamorphic_learned", "run"), ("pareto", "pareto", "run"),
            ("speed_floor", "speed_floor", "run"),
            ("osl_speed", "osl_speed", "run"),
            ("render_tradeoff", "render_tradeoff", "run"),
            ("robustness", "robustness", "run"),
            ("engine", "engine_bench", "section"),
            ("engine_scaling", "engine_scaling", "run"),
            ("engine_vs_cycles", "engine_vs_cycles", "section"),
            ("equal_quality", "equal_quality", "run"),
            ("lens_share", "lens_share", "run"),
            ("cycles_overhead", "cycles_overhead", "bench_section"),
            ("model_costs", "model_costs", "run"),
            ("auto_choice", "auto_choice", "run"),
            ("auto_choice_still_life", "auto_choice", "run_still_life"),
            ("auto_choice_environment", "auto_choice", "run_environment"),
            ("auto_choice_far_lights", "auto_choice", "run_far_lights"),
            ("auto_choice_backlit_street", "auto_choice", "run_backlit_street"),
            ("auto_choice_million", "auto_choice", "run_million"),
            ("flare", "flare", "run"),
            ("colour", "colour", "run"),
            ("zoom_models", "zoom_models", "run"),
            ("zoom_apertures", "zoom_apertures", "run"),
            ("lens_effects", "lens_effects", "run"),
            ("stmap", "stmap", "run"),
            ("memory_peak", "memory_peak", "run")]
#: the agreement scenes auto_choice is measured on besides the demo scene
AUTO_CHOICE_SCENES = ("still_life", "environment", "far_lights", "backlit_street", "million")
RESUMABLE = ("pareto", "render_tradeoff", "model_costs", "auto_choice",
             *(f"auto_choice_{s}" for s in AUTO_CHOICE_SCENES))
#: sections whose figures are Blender's own: Cycles, Blender's BVH and the engine in its Python
BLENDER_SECTIONS = ("osl_speed", "render_tradeoff", "engine", "engine_scaling",
                    "engine_vs_cycles", "equal_quality", "lens_share", "cycles_overhead",
                    "model_costs", "auto_choice",
                    *(f"auto_choice_{s}" for s in AUTO_CHOICE_SCENES), "flare", "colour",
                    "zoom_apertures", "lens_effects")


def stored_as(name: str) -> tuple[str, str | None]:
    """(the file stem a section's figures are kept under, the heading's Blender note or None):
    SECTION under the main Blender, SECTION.blender-X.Y under another one."""
    version = blender_version()
    if name not in BLENDER_SECTIONS or version is None:
        return name, None
    minor = ".".join(version.split(".")[:2])
    if minor == main_blender():
        return name, None
    return f"{name}.blender-{minor}", f"Blender {version}"


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    resume = "--resume" in argv
    argv = [a for a in argv if a != "--resume"]
    only = None
    if "--lenses" in argv:
        i = argv.index("--lenses")
        if i + 1 >= len(argv):
            print("--lenses needs a comma-separated list of preset names", file=sys.stderr)
            return 2
        only = [s for s in argv[i + 1].split(",") if s]
        del argv[i:i + 2]
        from .common import preset_paths
        unknown_lenses = set(only) - {p.stem for p in preset_paths()}
        if unknown_lenses:
            print(f"unknown preset(s): {', '.join(sorted(unknown_lenses))}", file=sys.stderr)
            return 2
    unknown = set(argv) - {name for name, _m, _f in SECTIONS}
    if unknown:
        print(f"unknown section(s): {', '.join(sorted(unknown))}", file=sys.stderr)
        return 2
    store = ROOT / "docs" / "bench"
    store.mkdir(parents=True, exist_ok=True)
    chosen = [s for s in SECTIONS if not argv or s[0] in argv]
    try:
        runs = [(name, getattr(importlib.import_module(f".{module}", __package__), function))
                for name, module, function in chosen]
    except ModuleNotFoundError as exc:
        where = (" (the trainer's: run that section with the project's Python 3.11 "
                 "environment, .venv)" if exc.name == "torch" else "")
        print(f"a section needs {exc.name}, which this Python does not have{where}",
              file=sys.stderr)
        return 2
    for name, run in runs:
        print(f"[bench] {name}", flush=True)
        if name in RESUMABLE and (resume or only is not None):
            text, figs = run(resume=True, only=only)
        else:
            text, figs = run()
        stamp = f"_Measured {datetime.date.today().isoformat()} on {machine()}._"
        stem, blender = stored_as(name)
        if blender is not None and text.startswith("## "):
            head, _, rest = text.partition("\n")
            text = f"{head}: under {blender}\n{rest}"
        (store / f"{stem}.md").write_text(text + "\n\n" + stamp + "\n")
        (store / f"{stem}.json").write_text(json.dumps(figs, indent=2))
    assemble()
    return 0


def assemble() -> None:
    """Rewrite docs/BENCHMARKS.md from the sections' last texts in docs/bench."""
    store = ROOT / "docs" / "bench"
    parts = []
    for name, _m, _f in SECTIONS:
        # the main Blender's figures, then those of any other Blender measured (stored_as)
        for path in [store / f"{name}.md", *sorted(store.glob(f"{name}.blender-*.md"))]:
            if path.exists():
                parts.append(path.read_text())
    head = ["# Benchmarks", "",
            "Regenerated by `make bench` (or `python -m benchmarks.run SECTION`). Every ratio is",
            "measured within one run on one machine; each section states when and where, and",
            "in which Blender (the bpy module: 5.0 unless the heading names another).", ""]
    out = ROOT / "docs" / "BENCHMARKS.md"
    out.write_text("\n".join(head) + "\n" + "\n\n".join(parts))
    print(f"[bench] wrote {out}")


if __name__ == "__main__":
    sys.exit(main())
