"""Learned zoom lenses: one model per tabulated position, or one model with the position as an
input? Measured on the same rays, the same network family and the same training budget.

Both learn the whole lens of a zoom preset at infinity focus, the d line, from the sensor
plane z = 0 (which stays put while the lens zooms) to one plane in front of the lens at every
position, in the input ray's radial frame (core.irf), with the trainer's kd-tree of MLP
ensembles (trainer.fit.fit_stage):
  per position   a model for each tabulated focal length, inputs (r, u_r, u_t, w), N rays each;
  position input one model, inputs (r, u_r, u_t, w, s) with s the zoom position parameter
                 (core.variable_gaps), N rays per tabulated position in all, spread over 41
                 positions, a kd-tree one level deeper (up to 4 cells against 2 per
                 position).
Held-out rays at every tabulated position and half-way between measure each (trainer.fit.
displacement_error_mm: RMS position error on the output plane plus the direction error seen
1 m on, in mm); a per-position model serves a position between two tabulated ones with the
nearer one's model (what it would render there; the add-on uses the exact trace instead).
"""

from __future__ import annotations

import time

import numpy as np

from neurolens_addon.core.irf import propagate_to_z, stage_targets
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.trace import trace
from neurolens_addon.core.variable_gaps import lens_at
from neurolens_addon.neural.reference import net_forward, route, stage_inputs
from trainer.data import Domain, sensor_rays
from trainer.fit import FitConfig, displacement_error_mm, fit_stage

from .common import PRESETS, md_table

LENSES = ("zoom_rf_24_70mm_f2_8", "zoom_70_200mm_f2_8")
D_LINE = 587.5618
RAYS_PER_POSITION = 60_000
FILM_RADIUS_MM = 21.63


def samples(lens, s_values, n, seed, out_z):
    """(X with the position column, Y) of n rays at each position in s_values."""
    xs, ys = [], []
    for j, s in enumerate(s_values):
        moved = lens_at(lens, zoom=float(s))
        dom = Domain(FILM_RADIUS_MM, (0.0, 0.0), (D_LINE, D_LINE), False)
        o, d, wl = sensor_rays(moved, dom, n, np.random.default_rng([seed, j]))
        res = trace(moved, Rays(o, d, wl))
        v = res.valid
        x, rot = stage_inputs(o[:, v].T, d[:, v].T, wl[v], False)
        out = propagate_to_z(res.rays.o[:, v], res.rays.d[:, v], out_z)
        xs.append(np.column_stack([x, np.full(x.shape[0], float(s))]))
        ys.append(stage_targets(out, res.rays.d[:, v], rot))
    return np.concatenate(xs), np.concatenate(ys)


def predict(stage, X):
    leaf = route(stage.tree, X)
    Y = np.zeros((X.shape[0], 4))
    for k, cell in enumerate(stage.cells):
        sel = leaf == k
        if sel.any():
            mx, sx = np.asarray(cell["x_norm"]["mean"]), np.asarray(cell["x_norm"]["scale"])
            my, sy = np.asarray(cell["y_norm"]["mean"]), np.asarray(cell["y_norm"]["scale"])
            xn = (X[sel] - mx) / sx
            Y[sel] = np.mean([net_forward(m, xn) * sy + my for m in cell["members"]], axis=0)
    return Y


def parameters(stage) -> int:
    return sum(sum(np.asarray(v).size for k, v in m.items() if k in
                   ("W1", "b1", "W2", "b2", "W3", "b3", "L"))
               for cell in stage.cells for m in cell["members"])


def compare(stem):
    lens = load_lens(PRESETS / f"{stem}.toml")
    n_pos = lens.zoom_gaps.count
    out_z = max(lens_at(lens, zoom=float(k)).front_vertex_z for k in range(n_pos)) + 5.0
    cfg = FitConfig(max_depth=1, seed=0)
    # per position
    t0 = time.perf_counter()
    per = []
    for k in range(n_pos):
        X, Y = samples(lens, [k], RAYS_PER_POSITION, 1, out_z)
        per.append(fit_stage(X[:, :4], Y, cfg, stage=k, log=lambda *_: None))
    t_per = time.perf_counter() - t0
    # one model with the position as an input
    t0 = time.perf_counter()
    grid = np.linspace(0.0, n_pos - 1.0, 41)
    X, Y = samples(lens, grid, RAYS_PER_POSITION * n_pos // len(grid), 2, out_z)
    joint = fit_stage(X, Y, FitConfig(max_depth=2, seed=0), stage=9, log=lambda *_: None)
    t_joint = time.perf_counter() - t0
    rows, figs = [], []
    for s in np.linspace(0.0, n_pos - 1.0, 2 * n_pos - 1):
        Xt, Yt = samples(lens, [s], 20_000, 3, out_z)
        nearest = per[int(round(s))]
        e_per = displacement_error_mm(predict(nearest, Xt[:, :4]), Yt)
        e_joint = displacement_error_mm(predict(joint, Xt), Yt)
        f = lens.zoom_gaps.positions[int(s)] if float(s).is_integer() else None
        where = f"{f:g} mm (tabulated)" if f is not None else f"s = {s:g} (between)"
        rows.append([where, f"{e_per:.4f}", f"{e_joint:.4f}"])
        figs.append({"s": float(s), "per_position_mm": e_per, "position_input_mm": e_joint})
    summary = {"lens": stem, "positions": n_pos, "rows": figs,
               "per_position_parameters": sum(parameters(p) for p in per),
               "position_input_parameters": parameters(joint),
               "per_position_train_s": t_per, "position_input_train_s": t_joint}
    return rows, summary


def run():
    text = ["## Learned zoom lenses: per position, or the position as an input", "",
            "Each zoom preset's whole lens (infinity focus, d line) learned from the sensor "
            "plane (fixed while the lens zooms) to one plane in front of the lens, with the "
            "trainer's kd-tree of MLP ensembles: **per position**, one model per tabulated "
            f"focal length ({RAYS_PER_POSITION} rays each, kd depth 1; the network family "
            "`make models` ships, there with 400k rays through the two-stage model), "
            "against **position as input**, one model with the zoom position "
            "parameter s as a fifth input (as many rays in all, over 41 positions, kd depth "
            "2). Error: trainer.fit.displacement_error_mm (RMS position error on the output "
            "plane plus the direction error 1 m on, mm) on held-out rays at each tabulated "
            "position and half-way between, where a per-position model set serves the "
            "nearer position's model (the add-on traces exactly there instead). "
            "`benchmarks/zoom_models.py`.", ""]
    figs = []
    for stem in LENSES:
        if not (PRESETS / f"{stem}.toml").is_file():
            continue
        rows, summary = compare(stem)
        figs.append(summary)
        text += [f"**{stem}** ({summary['positions']} tabulated positions): error in mm at 1 m "
                 f"(per-position models: {summary['per_position_parameters']} parameters, "
                 f"{summary['per_position_train_s']:.0f} s to train; position input: "
                 f"{summary['position_input_parameters']} parameters, "
                 f"{summary['position_input_train_s']:.0f} s)", "",
                 md_table(["position", "per-position models", "position as input"], rows), ""]
    return "\n".join(text), figs
