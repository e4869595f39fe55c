"""Whether model AUTO picks the faster frame: every preset, both renderers, the exact lens
against each shipped learned model AUTO weighed, and AUTO's pick from the recorded costs
(benchmarks/model_costs.py).

The demo scene (presets/scenes/demo.blend) through every preset at the demo camera's focus
and f-number (clamped to what the lens can), WIDTH x HEIGHT, SAMPLES samples, rendered by the
command line with `--model exact` and `--model DIR` for each learned model of the lens AUTO
considered (the full model, and the sparse one of a lens of 25 surfaces or more), in the
NEUROLENS engine (one colour ray, not denoised) and in Cycles (CPU, the project's OSL camera),
interleaved, REPEATS each (their best); the frame time is the one each command prints (scene
sync, BVH, the learned model's session or the shader's OSL compilation included: what a still
frame costs). AUTO's pick: `--show-setup --model auto` for the same frame on each renderer
(its "model" and "model_dir"). Within 10 %: the frame with AUTO's pick takes at most 1.1
times the fastest of the models that meet the frame's budget (issue 30's target).

    python -m benchmarks.run auto_choice
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

from .common import ROOT, md_table, preset_paths

WIDTH, HEIGHT, SAMPLES = 128, 72, 64
REPEATS = 2
TOLERANCE = 1.10
SCENE = ROOT / "presets" / "scenes" / "demo.blend"
_TIME = re.compile(r"focus [^,]+ m, ([0-9.]+) s")
RENDERERS = ("neurolens", "cycles")


def _args(lens: str, model: str, engine: str, scene: Path = SCENE) -> list:
    extra = ["--colour-rays", "1", "--no-denoise"] if engine == "neurolens" else []
    return [sys.executable, "-m", "neurolens_addon.render", str(scene), "--lens", lens,
            "--model", model, "--engine", engine, "--samples", str(SAMPLES), "--resolution",
            f"{WIDTH}x{HEIGHT}", "--quiet", *extra]


def _seconds(lens: str, model: str, engine: str, out: Path, scene: Path) -> float | None:
    try:
        p = subprocess.run(_args(lens, model, engine, scene) + ["--out", str(out)], cwd=ROOT,
                           capture_output=True, text=True, timeout=1200)
    except subprocess.TimeoutExpired:
        return None
    m = _TIME.search(p.stdout + p.stderr)
    return float(m.group(1)) if p.returncode == 0 and m else None


def _setup(lens: str, model: str, engine: str, scene: Path) -> dict:
    """`--show-setup` of the frame ({} where the command failed)."""
    try:
        p = subprocess.run(_args(lens, model, engine, scene) + ["--show-setup"], cwd=ROOT,
                           capture_output=True, text=True, timeout=600)
    except subprocess.TimeoutExpired:
        return {}
    start = next((i for i, line in enumerate(p.stdout.splitlines()) if line.startswith("{")),
                 None)
    if p.returncode != 0 or start is None:
        return {}
    text = "\n".join(p.stdout.splitlines()[start:])
    return json.JSONDecoder().raw_decode(text)[0]


def _learned_considered(auto: dict) -> dict:
    """{model directory: whether it meets the frame's budget} of the shipped learned models
    AUTO weighed (its `choice_considered`)."""
    out = {}
    for name, why in auto.get("choice_considered", ()):
        if name.startswith("learned model "):
            stem = name.removeprefix("learned model ")
            out[str(ROOT / "presets" / "models" / f"{stem}.neurolens")] = not why
    return out


def _kept(scene: str) -> dict:
    """The section's last figures per preset on `scene` ({} if none), an earlier run's one
    learned model in today's form."""
    stem = "auto_choice" if scene == "demo" else f"auto_choice_{scene}"
    try:
        old = json.loads((ROOT / "docs" / "bench" / f"{stem}.json").read_text())["presets"]
    except (OSError, ValueError, KeyError):
        return {}
    for f in old.values():
        for c in f.values():
            if "learned" not in c:              # before each learned model was timed
                name = Path(c.pop("learned_model_dir", "") or "").name.removesuffix(
                    ".neurolens")
                c["learned"] = {name: {"s": c.pop("learned_s", None),
                                       "qualifies": c.pop("learned_qualifies", False)}
                                } if name else {}
                c["auto_model"] = Path(c.pop("auto_model_dir", "") or "").name.removesuffix(
                    ".neurolens")
    return old


def _progress_path(scene: str) -> Path:
    """Where a run keeps the presets measured so far (build/, not committed): a long section
    (the million-triangle scene: one to two minutes a preset here) goes on where it stopped."""
    return ROOT / "build" / "bench" / f"auto_choice_{scene}.progress.json"


def _save_progress(path: Path, figs: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(figs, indent=1))
    tmp.replace(path)                               # whole or not at all


def run(scene: str = "demo", resume: bool = False, only=None):
    """The section on the demo scene, or on an agreement scene (testdata/agreement_scenes.py)
    named `scene`, its own camera placement with each preset; with `only` (preset stems) only
    those presets are rendered and every other keeps its last figures. Each preset's figures
    are kept as they come (_progress_path); with `resume` the presets an unfinished run
    measured are not measured again."""
    subprocess.run([sys.executable, "-m", "neurolens_addon.engine.kernel_warmup"], cwd=ROOT,
                   check=True, capture_output=True)
    kept = _kept(scene) if only is not None else {}
    progress = _progress_path(scene)
    done = {}
    if resume and progress.exists():
        done = json.loads(progress.read_text())
    figs = {}
    with tempfile.TemporaryDirectory() as tmp:
        blend = SCENE
        if scene != "demo":
            from testdata import agreement_scenes
            blend = agreement_scenes.write(scene, Path(tmp))
        for path in preset_paths():
            lens = path.stem
            if only is not None and lens not in only and lens in kept:
                figs[lens] = kept[lens]
                continue
            if lens in done and (only is None or lens not in only):
                figs[lens] = done[lens]
                continue
            f = {}
            for engine in RENDERERS:
                auto = _setup(lens, "auto", engine, blend)
                learned = _learned_considered(auto)
                times = {m: [] for m in ["exact", *learned]}
                for _ in range(REPEATS):
                    for model in times:
                        t = _seconds(lens, model, engine, Path(tmp) / "frame.exr", blend)
                        if t is not None:
                            times[model].append(t)
                f[engine] = {"exact_s": min(times["exact"], default=None),
                             "learned": {Path(d).name.removesuffix(".neurolens"):
                                         {"s": min(times[d], default=None), "qualifies": ok}
                                         for d, ok in learned.items()},
                             "auto": auto.get("model", "failed"),
                             "auto_model": Path(auto.get("model_dir") or "").name
                                           .removesuffix(".neurolens"),
                             "why": auto.get("choice_why") or ""}
            figs[lens] = done[lens] = f
            _save_progress(progress, done)
            print(f"[auto_choice] {lens}: {f}", flush=True)
    progress.unlink(missing_ok=True)                # the section is whole: its report says it
    return report(figs, scene)


def run_still_life(resume: bool = False, only=None):
    return run("still_life", resume, only)


def run_environment(resume: bool = False, only=None):
    return run("environment", resume, only)


def run_far_lights(resume: bool = False, only=None):
    return run("far_lights", resume, only)


def run_backlit_street(resume: bool = False, only=None):
    return run("backlit_street", resume, only)


def run_million(resume: bool = False, only=None):
    return run("million", resume, only)


def judge(c: dict) -> tuple[str, bool | None]:
    """(AUTO's pick, whether its frame is within TOLERANCE of the fastest model that meets
    the budget; None: not judged, AUTO picked a model that was not timed)."""
    pick = c["auto"]
    if pick == "learned":
        pick = c.get("auto_model") or "learned"
        auto_t = c["learned"].get(pick, {}).get("s")
        if pick not in c["learned"]:
            return pick, None
    else:
        auto_t = c.get(f"{pick}_s")
    candidates = [c["exact_s"]] + [m["s"] for m in c["learned"].values() if m["qualifies"]]
    candidates = [t for t in candidates if t is not None]
    return pick, bool(candidates) and auto_t is not None and auto_t <= TOLERANCE * min(
        candidates)


def report(figs: dict, scene: str = "demo"):
    """(markdown, figures) of the renders ({preset: {renderer: figures}}) on `scene`."""
    rows, within = [], {r: [] for r in RENDERERS}
    for lens, f in figs.items():
        row = [lens]
        for engine in RENDERERS:
            c = f[engine]
            pick, ok = judge(c)
            c["within_10pct"] = ok
            if ok is not None:
                within[engine].append(ok)

            def t(v):
                return "n/a" if v is None else f"{v:.2f}"
            learned = ", ".join(
                f"{name.removeprefix(lens).lstrip('.') or 'full'} {t(m['s'])}"
                + ("" if m["qualifies"] else " (outside)") for name, m in c["learned"].items())
            short = (pick.removeprefix(lens).lstrip(".") or "full") if pick.startswith(lens) \
                else pick
            row += [t(c["exact_s"]), learned or "-", short,
                    "-" if ok is None else "yes" if ok else "**no**"]
        rows.append(row)
    counts = {r: f"{sum(v)} of {len(v)}" for r, v in within.items()}
    text = "\n".join([
        "## AUTO's pick against the faster frame, per preset and renderer"
        + ("" if scene == "demo" else f": the {scene.replace('_', ' ')}"),
        "",
        ("The demo scene" if scene == "demo" else
         f"The agreement scene {scene} (testdata/agreement_scenes.py)")
        + f" through every preset (`benchmarks/auto_choice.py`), {WIDTH}x{HEIGHT}, "
        f"{SAMPLES} samples, by the command line: the frame time each command prints (set-up "
        "included: the learned model's onnxruntime session or OSL compilation), best of "
        f"{REPEATS} interleaved runs, with the exact lens and each shipped learned model AUTO "
        "weighed (full: the full-basis model at the lens's position, sparse: the sparse "
        "one-network model of a lens of 25 surfaces or more), in "
        "the engine (one colour ray, not denoised) and in Cycles (CPU, the project's OSL "
        "camera); AUTO: the model `--show-setup --model auto` names for that frame (from the "
        "costs recorded by model_costs). Within 10 %: AUTO's frame takes at most 1.1 times "
        "the fastest of the models that meet the frame's budget (the exact trace, and the "
        "learned models AUTO found cover the scene and meet the budget; "
        "\"outside\": one that does not, timed all the same): the engine "
        f"{counts['neurolens']} presets, Cycles {counts['cycles']} (n/a: Cycles renders no "
        "learned anamorphic lens).",
        "",
        md_table(["preset", "engine exact (s)", "engine learned (s)", "engine AUTO",
                  "within 10 %", "Cycles exact (s)", "Cycles learned (s)", "Cycles AUTO",
                  "within 10 %"], rows),
    ])
    return text, {"scene": scene, "presets": figs, "within_10pct": counts}
