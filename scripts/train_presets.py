"""Train and record the learned model of every preset (`make models`; resumable).

    python scripts/train_presets.py [STEM ...] [--force]

For each preset (or the named ones) the model `presets/models/STEM.neurolens` is trained
(and, for a lens of 25 surfaces or more, `STEM.sparse.neurolens`: one network a cell, the
sparse skip basis, cheaper in Cycles than the exact camera)
(`python -m trainer fit`), and its measured error and speed (`trainer evaluate --record`) and
what a camera ray costs through it and through the exact trace in the engine on this
machine (`trainer cost --record`; Cycles' figures: benchmarks/model_costs.py) recorded in its
model.json, where automatic model choice
reads them. A zoom lens gets one model per
tabulated focal length, `STEM.zoomFmm.neurolens` beside the wide end's, and a lens with focusing
groups one per tabulated close distance, `STEM.focusDmm.neurolens`: a model is found by the
content hash of the lens it learned (camera.models), so at a tabulated position the camera
uses that position's model and between positions the exact trace. A model whose recorded lens
hash matches the file's is kept unless --force (and evaluated, or its costs measured, when
it has no evaluation or costs yet).

Depth of the kd-tree: 3 (600k rays) for lenses that see 100 degrees or more (fisheyes, ultra
wides) and the Petzval (strong field curvature), 1 (400k rays) for the rest.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from neurolens_addon.camera.lens_kinds import full_frame_field_deg  # noqa: E402
from neurolens_addon.core.lensfile import load_lens  # noqa: E402
from neurolens_addon.core.variable_gaps import position_lenses  # noqa: E402

MODELS = ROOT / "presets" / "models"
#: the trainer option that puts a lens at a tabulated position of each kind
OPTION = {"zoom": "--zoom", "focus": "--focus-groups-at"}
#: a lens this long also gets a sparse model (one network a cell, the sparse skip basis):
#: in Cycles its camera ray costs 0.4-0.6x the exact camera's where the full model costs
#: 1.3-3x (docs/learned-lenses.md)
SPARSE_SURFACES = 25
SPARSE = ["--skip-basis", "sparse", "--ensemble", "1"]
#: a lens trained deep (settings: depth 3) gets its sparse model one level shallower: the
#: 14 mm ultrawide's at depth 3 cost 1.33x the exact camera in Cycles (p99 5.0 um), at depth 2
#: 0.97x (p99 7.5 um; skip degree 4 at depth 3: 0.97x but 23.5 um), measured 2026-11-28
SPARSE_DEEP_DEPTH = 2


def plan(path: Path):
    """[(model directory, the position's trainer options, lens it learns, fit-only options)]
    for one preset: the full-basis model at each position and, for a lens of SPARSE_SURFACES
    or more, the sparse one beside it."""
    lens = load_lens(path)
    positions = [("", [], lens)]
    for key, k, moved in position_lenses(lens):
        at = (lens.zoom_gaps if key == "zoom" else lens.focus_gaps).positions[k]
        positions.append((f".{key}{at:g}mm", [OPTION[key], repr(at)], moved))
    out = []
    for tag, extra, moved in positions:
        out.append((MODELS / f"{path.stem}{tag}.neurolens", extra, moved, []))
        if len(lens.surfaces) >= SPARSE_SURFACES:
            out.append((MODELS / f"{path.stem}{tag}.sparse.neurolens", extra, moved, SPARSE))
    return out


def settings(lens, stem: str) -> tuple[int, int]:
    """(kd-tree depth, training rays)."""
    field = lens.field_of_view_deg or full_frame_field_deg(lens)
    # the 2x anamorphic's front group (attachment and prime's front half, a 6-input cartesian
    # stage) at its 1 m focus: image error p99 159 um at depth 1, 71 um at depth 3
    deep = field >= 100.0 or stem.startswith("petzval") or stem == "anamorphic_2x_60mm_f1_9"
    return (3, 600_000) if deep else (1, 400_000)


def state(model: Path, lens) -> str:
    """"missing" (train it), "trained" (evaluate it), "evaluated" (measure its costs) or
    "done"."""
    try:
        meta = json.loads((model / "model.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return "missing"
    if meta.get("lens", {}).get("content_hash") != lens.content_hash():
        return "missing"
    if "evaluation" not in meta:
        return "trained"
    return "done" if "neurolens" in (meta.get("costs") or {}) else "evaluated"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("stems", nargs="*")
    ap.add_argument("--force", action="store_true")
    args = ap.parse_args(argv)
    files = sorted((ROOT / "presets" / "lenses").glob("*.toml"))
    if args.stems:
        files = [f for f in files if f.stem in args.stems]
    py = sys.executable
    for path in files:
        for model, extra, lens, fit_only in plan(path):
            now = "missing" if args.force else state(model, lens)
            if now == "done":
                print(f"{model.name}: up to date")
                continue
            depth, rays = settings(lens, path.stem)
            if fit_only and depth > SPARSE_DEEP_DEPTH:
                depth = SPARSE_DEEP_DEPTH
            fit = ["-m", "trainer", "fit", str(path), "--out", str(model),
                   "--max-depth", str(depth), "--rays", str(rays)] + extra + fit_only
            evaluate = ["-m", "trainer", "evaluate", str(model), "--lens", str(path),
                        "--rays", "300000", "--record"] + extra
            # what a camera ray costs in each renderer on this machine (model AUTO's choice)
            cost = ["-m", "trainer", "cost", str(model), "--lens", str(path), "--record"] + extra
            todo = {"missing": [fit, evaluate, cost], "trained": [evaluate, cost],
                    "evaluated": [cost]}[now]
            for cmd in todo:
                print(" ".join(["python"] + cmd), flush=True)
                subprocess.run([py] + cmd, cwd=ROOT, check=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
