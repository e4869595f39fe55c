"""`python -m trainer fit LENS --out MODEL [...]` and `python -m trainer evaluate MODEL --lens LENS`."""

from __future__ import annotations

import argparse
import sys

from neurolens_addon.core.arguments import int_in
from neurolens_addon.core.errors import NeuroLensError
from neurolens_addon.core.jsonout import dumps


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m trainer", description="NeuroLens trainer")
    sub = ap.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("fit", help="learn a lens from its prescription")
    f.add_argument("lens")
    f.add_argument("--out", required=True, help="model directory (NAME.neurolens)")
    f.add_argument("--theta", type=int_in(1, 4096), default=None, help="largest hidden width")
    f.add_argument("--ensemble", type=int_in(1, 64), default=None, help="networks per cell")
    f.add_argument("--skip-degree", type=int_in(0, 8), default=None,
                   help="degree of the polynomial skip")
    f.add_argument("--skip-basis", choices=["sparse", "full"], default=None,
                   help="skip monomials: full (default) or sparse (mirror-symmetric, pruned: faster)")
    f.add_argument("--threshold", type=float, default=None,
                   help="test error a cell must reach before it stops splitting: RMS displacement "
                        "of its rays 1 m away, in mm (default 0.01)")
    f.add_argument("--max-depth", type=int_in(0, 12), default=None)
    f.add_argument("--method", choices=["lm", "adam"], default=None)
    f.add_argument("--rays", type=int_in(1, 50_000_000), default=400_000,
                   help="exact training rays")
    f.add_argument("--no-dispersion", action="store_true", help="learn at the d line only")
    f.add_argument("--seed", type=int_in(0, 2 ** 31 - 1), default=0)
    f.add_argument("--zoom", type=float, default=None, metavar="MM",
                   help="a zoom lens: train at this focal length (within its range)")
    f.add_argument("--focus-groups-at", type=float, default=None, metavar="MM",
                   help="a lens with focusing groups: train with them at this tabulated "
                        "focus distance (from the sensor)")
    t = sub.add_parser("fit-table", help="learn a lens from an external .npz ray table")
    t.add_argument("table")
    t.add_argument("--out", required=True)
    t.add_argument("--theta", type=int_in(1, 4096), default=None)
    t.add_argument("--ensemble", type=int_in(1, 64), default=None)
    t.add_argument("--skip-degree", type=int_in(0, 8), default=None)
    t.add_argument("--skip-basis", choices=["sparse", "full"], default=None,
                   help="skip monomials: full (default) or sparse (mirror-symmetric, pruned: faster)")
    t.add_argument("--threshold", type=float, default=None)
    t.add_argument("--max-depth", type=int_in(0, 12), default=None)
    t.add_argument("--method", choices=["lm", "adam"], default=None)
    t.add_argument("--seed", type=int_in(0, 2 ** 31 - 1), default=0)
    sc = sub.add_parser("fit-scene", help="train (or reuse from the cache) a model for just "
                                          "what a scene's render settings need")
    sc.add_argument("lens")
    sc.add_argument("--models-dir", required=True, help="user models directory (cache root)")
    sc.add_argument("--resolution", required=True, help="WIDTHxHEIGHT in pixels")
    sc.add_argument("--percentage", type=float, default=100.0)
    sc.add_argument("--sensor-width", type=float, default=36.0)
    sc.add_argument("--sensor-height", type=float, default=24.0)
    sc.add_argument("--sensor-fit", choices=["AUTO", "HORIZONTAL", "VERTICAL"], default="AUTO")
    sc.add_argument("--border", default=None, help="render region x0,y0,x1,y1 in [0, 1]")
    for axis in ("x", "y"):
        sc.add_argument(f"--pixel-aspect-{axis}", type=float, default=1.0)
        sc.add_argument(f"--shift-{axis}", type=float, default=0.0,
                        help="Blender's lens shift (in units of the larger film side)")
    sc.add_argument("--fstop", type=float, action="append", default=[],
                    help="an f-number the frames use (repeat for several)")
    sc.add_argument("--focus", type=float, action="append", default=[],
                    help="a focus distance in metres the frames use (repeat for several)")
    sc.add_argument("--no-dispersion", action="store_true")
    sc.add_argument("--pixel-fraction", type=float, default=0.5,
                    help="error budget in pixels (default 0.5)")
    sc.add_argument("--rays", type=int_in(1, 50_000_000), default=200_000)
    sc.add_argument("--max-depth", type=int_in(0, 12), default=2)
    sc.add_argument("--seed", type=int_in(0, 2 ** 31 - 1), default=0)
    e = sub.add_parser("evaluate", help="accuracy and speed against the exact trace")
    e.add_argument("model")
    e.add_argument("--lens", required=True)
    e.add_argument("--rays", type=int_in(1, 50_000_000), default=1_170_000)
    e.add_argument("--json", action="store_true")
    e.add_argument("--zoom", type=float, default=None, metavar="MM",
                   help="a zoom lens: the focal length the model was trained at")
    e.add_argument("--focus-groups-at", type=float, default=None, metavar="MM",
                   help="a lens with focusing groups: the focus distance it was trained at")
    e.add_argument("--record", action="store_true",
                   help="store the figures in the model's model.json (read by model choice)")
    c = sub.add_parser("cost", help="what a camera ray costs in the NEUROLENS engine through "
                                    "the model and through the exact trace, on this machine")
    c.add_argument("model")
    c.add_argument("--lens", required=True)
    c.add_argument("--zoom", type=float, default=None, metavar="MM",
                   help="a zoom lens: the focal length the model was trained at")
    c.add_argument("--focus-groups-at", type=float, default=None, metavar="MM",
                   help="a lens with focusing groups: the focus distance it was trained at")
    c.add_argument("--record", action="store_true",
                   help="store the figures in the model's model.json (read by model choice)")
    return ap


#: the commands that fit networks with torch (`evaluate` needs numpy and onnxruntime only)
TRAINING = ("fit", "fit-table", "fit-scene")


def torch_missing() -> str | None:
    """Why this Python cannot train (one line), or None: torch is not installed here, as in
    Blender's own Python or the add-on's Blender 5.2 environment (Python 3.13)."""
    import importlib.util
    if importlib.util.find_spec("torch") is not None:
        return None
    v = sys.version_info
    return (f"training needs torch, which this Python ({v.major}.{v.minor}, {sys.executable}) "
            "does not have: run the trainer with the project's Python 3.11 environment "
            "(make venv, then .venv/bin/python -m trainer ...)")


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if args.cmd in TRAINING and (why := torch_missing()) is not None:
        print(f"error: {why}", file=sys.stderr)
        return 2
    from neurolens_addon.core.atomic import exit_on_sigterm
    exit_on_sigterm()
    try:
        if args.cmd == "fit":
            return _fit(args)
        if args.cmd == "fit-table":
            return _fit_table(args)
        if args.cmd == "fit-scene":
            return _fit_scene(args)
        if args.cmd == "cost":
            return _cost(args)
        return _evaluate(args)
    except BrokenPipeError:
        raise                  # the reader went away: run_command ends quietly
    except (NeuroLensError, OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def _config(args):
    from dataclasses import replace

    from .fit import FitConfig
    cfg = FitConfig(seed=args.seed, progress=True)
    for name, key in (("theta", "theta"), ("ensemble", "ensemble"), ("skip_degree", "skip_degree"),
                      ("threshold", "error_threshold"), ("max_depth", "max_depth"),
                      ("method", "method"), ("skip_basis", "skip_basis")):
        val = getattr(args, name)
        if val is not None:
            cfg = replace(cfg, **{key: val})
    return cfg


def needs_from_args(args):
    """The RenderNeeds `fit-scene` trains for (the add-on's scene_needs_bpy.cli_arguments
    writes these options)."""
    from neurolens_addon.core.scene_needs import RenderNeeds
    try:
        w, h = (int(v) for v in args.resolution.lower().split("x"))
        border = (0.0, 0.0, 1.0, 1.0) if args.border is None else tuple(
            float(v) for v in args.border.split(","))
    except ValueError:
        raise ValueError(f"--resolution WIDTHxHEIGHT and --border x0,y0,x1,y1 expected, got "
                         f"{args.resolution!r} and {args.border!r}") from None
    return RenderNeeds(w, h, args.sensor_width, args.sensor_height, args.sensor_fit,
                       args.percentage, border, tuple(args.fstop), tuple(args.focus),
                       not args.no_dispersion, args.pixel_fraction, args.pixel_aspect_x,
                       args.pixel_aspect_y, args.shift_x, args.shift_y)


def _fit_scene(args) -> int:
    from neurolens_addon.core.lensfile import load_lens

    from .fit import FitConfig
    from .scene import fit_for_scene
    needs = needs_from_args(args)
    base = FitConfig(seed=args.seed, max_depth=args.max_depth)
    path, trained = fit_for_scene(load_lens(args.lens), needs, args.models_dir, base=base,
                                  n_rays=args.rays)
    print(dumps({"model": str(path), "trained": trained, "budget_um": needs.error_budget_um()}))
    return 0


def _fit_table(args) -> int:
    from .pipeline import fit_table
    fit_table(args.table, args.out, _config(args))
    return 0


def zoomed(lens, focal_length_mm):
    """The lens set to a focal length (a zoom lens: core.variable_gaps); unchanged for None."""
    if focal_length_mm is None:
        return lens
    from neurolens_addon.core.errors import LensError
    from neurolens_addon.core.variable_gaps import lens_at, zoom_position
    try:                        # (zoom_position checks the table and the range)
        s = zoom_position(lens, focal_length_mm)
    except ValueError as exc:
        raise LensError(f"--zoom {focal_length_mm:g}: {exc}", path=lens.path) from None
    return lens_at(lens, zoom=s)


def grouped(lens, distance_mm):
    """The lens with its focusing groups at a tabulated focus distance; unchanged for None."""
    if distance_mm is None:
        return lens
    from neurolens_addon.core.errors import LensError
    from neurolens_addon.core.variable_gaps import lens_at
    from neurolens_addon.core.variable_gaps import tabulated_index, tabulated_position
    table = lens.focus_gaps
    k = None if table is None else tabulated_index(table.positions, distance_mm)
    if k is None:
        raise LensError(f"--focus-groups-at {distance_mm:g}: not a distance of the lens's "
                        "[focus] table", path=lens.path)
    if tabulated_position(lens, lens.zoom_gaps) not in (None, 0):
        raise LensError("--focus-groups-at: the [focus] table holds the spacings at the first "
                        "zoom position; a zoom elsewhere has no tabulated focus state",
                        path=lens.path)
    return lens_at(lens, focus=float(k))


def _fit(args) -> int:
    from neurolens_addon.core.lensfile import load_lens

    from .pipeline import fit_lens
    cfg = _config(args)
    lens = grouped(zoomed(load_lens(args.lens), args.zoom), args.focus_groups_at)
    fit_lens(lens, args.out, cfg, n_rays=args.rays, dispersion=not args.no_dispersion)
    return 0


def _evaluate(args) -> int:
    from neurolens_addon.core.lensfile import load_lens
    from neurolens_addon.neural.model import LearnedLens

    from .evaluate import evaluate_model
    lens = grouped(zoomed(load_lens(args.lens), args.zoom), args.focus_groups_at)
    model = LearnedLens.load(args.model, lens=lens)
    res = evaluate_model(model, lens, n=args.rays)
    if args.record:
        from .evaluate import record_evaluation
        record_evaluation(args.model, {**res, "rays": args.rays})
    if args.json:
        print(dumps(res, indent=2))
    else:
        for k, v in res.items():
            print(f"{k:22s} {v}")
    return 0


def _cost(args) -> int:
    from neurolens_addon.core.lensfile import load_lens

    from .cost import measure, record_costs, summary
    lens = grouped(zoomed(load_lens(args.lens), args.zoom), args.focus_groups_at)
    costs = measure(args.model, lens)
    if args.record:
        record_costs(args.model, costs)
    print(summary(costs))
    return 0


if __name__ == "__main__":
    from neurolens_addon.core.errors import run_command
    sys.exit(run_command(main, "trainer"))

