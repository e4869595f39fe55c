"""Small random learned-lens models built in code, valid per the model.json schema.

Stage 1 maps Pi_1 (z = 0) to the stop plane (z = 30), stage 2 the stop plane to Pi_2 (z = 60).
Each cell normalises its box to [-1, 1] and scales outputs so rays stay well inside the unit
direction disc: y = my + sy * net(xn) with sy = (4, 0.5, 0.15, 0.05) (stage 1) or
(8, 1, 0.3, 0.1) (stage 2), my = (4, 0, 0, 0) / (0, 0, 0, 0).
Trees: 1 cell, or 3 cells (r < split -> cell 0, else u_r < 0 -> cell 1, else cell 2).
frame="cartesian": the stages see (x, y, u, v, w, lambda) (core.irf), boxes below; the same
trees split x at 55 % of its range, then y at 45 %.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from neurolens_addon.core.irf import FRAMES, RADIAL, model_frames
from neurolens_addon.neural import reference
from neurolens_addon.neural.reference import w_residual
from neurolens_addon.neural.modelfile import encode_occupancy, monomial_terms
from onnx_export import write_onnx_files

PLANES = {"input_z": 0.0, "stop_z": 30.0, "output_z": 60.0, "stop_radius_mm": 6.0}
WL_RANGE = [400.0, 760.0]
STAGE_BOX = {  # (lo, hi) over (r, u_r, u_t, w, lambda)
    "rear": ([0.0, -0.6, -0.6, 0.6, WL_RANGE[0]], [20.0, 0.6, 0.6, 1.0, WL_RANGE[1]]),
    "front": ([0.0, -1.0, -1.0, 0.0, WL_RANGE[0]], [40.0, 1.0, 1.0, 1.0, WL_RANGE[1]]),
}
CART_BOX = {  # (lo, hi) over (x, y, u, v, w, lambda)
    "rear": ([-20.0, -20.0, -0.6, -0.6, 0.6, WL_RANGE[0]], [20.0, 20.0, 0.6, 0.6, 1.0, WL_RANGE[1]]),
    "front": ([-40.0, -40.0, -1.0, -1.0, 0.0, WL_RANGE[0]], [40.0, 40.0, 1.0, 1.0, 1.0, WL_RANGE[1]]),
}
Y_NORM = {"rear": ([4.0, 0.0, 0.0, 0.0], [4.0, 0.5, 0.15, 0.05]),
          "front": ([0.0, 0.0, 0.0, 0.0], [8.0, 1.0, 0.3, 0.1])}
OCC_SHAPE = (4, 6, 6)
CART_OCC_SHAPE = (4, 5, 3, 4)


def sparse_skip_terms(d_in: int, degree: int, w_column: int = 3) -> list[tuple[int, ...]]:
    """The trainer's sparse skip basis (trainer.mlp.sparse_skip_terms), written out here so
    that the add-on's tests never import the trainer (which needs torch): the monomials up to
    `degree` with w (at `w_column`) at most linear and the wavelength feature (after it) at
    most squared and only below the top degree. tests/trainer/test_synthetic_models.py checks
    that both give the same terms."""
    return [t for t in monomial_terms(d_in, degree)
            if t.count(w_column) <= 1 and t.count(w_column + 1) <= 2
            and (t.count(w_column + 1) == 0 or len(t) < degree)]


def member(rng, d_in: int, hidden: int, skip_degree: int, sparse: bool = False,
           frame=RADIAL) -> dict:
    terms = (sparse_skip_terms(d_in, skip_degree, frame.w_column) if sparse
             else monomial_terms(d_in, skip_degree))
    n_terms = len(terms)
    extra = {"skip_terms": [list(t) for t in terms]} if sparse else {}
    return {**extra,"W1": (rng.uniform(-1, 1, (hidden, d_in)) * 2 / np.sqrt(d_in)).tolist(),
            "b1": rng.uniform(-1, 1, hidden).tolist(),
            "W2": (rng.uniform(-1, 1, (hidden, hidden)) * 2 / np.sqrt(hidden)).tolist(),
            "b2": rng.uniform(-1, 1, hidden).tolist(),
            "W3": (rng.uniform(-1, 1, (4, hidden)) / np.sqrt(hidden)).tolist(),
            "b3": rng.uniform(-0.2, 0.2, 4).tolist(),
            "L": (rng.uniform(-1, 1, (4, n_terms)) / n_terms).tolist(),
            "skip_degree": skip_degree}


def stage(rng, name: str, n_cells: int, d_in: int, ensemble: int, hidden: int,
          skip_degree: int, sparse: bool = False, frame=RADIAL) -> dict:
    box = (STAGE_BOX if frame is RADIAL else CART_BOX)[name]
    lo, hi = (np.asarray(a[:d_in]) for a in box)
    if n_cells == 1:
        tree = [{"cell": 0}]
    elif n_cells == 3:
        # (cartesian: x and y split off 0, where random_rays puts its on-axis rays)
        at = 0.5 if frame is RADIAL else 0.55
        tree = [{"axis": 0, "split": float(lo[0] + at * (hi[0] - lo[0])), "left": 1, "right": 2},
                {"cell": 0},
                {"axis": 1, "split": 0.0 if frame is RADIAL else float(lo[1] + 0.45 * (hi[1] - lo[1])),
                 "left": 3, "right": 4},
                {"cell": 1}, {"cell": 2}]
    else:
        raise ValueError("synthetic models have 1 or 3 cells per stage")
    my, sy = Y_NORM[name]
    cells = []
    for _ in range(n_cells):
        mean = 0.5 * (lo + hi) + rng.uniform(-0.05, 0.05, d_in) * (hi - lo)
        scale = 0.5 * (hi - lo) * rng.uniform(0.9, 1.1, d_in)
        x_norm = {"mean": mean.tolist(), "scale": scale.tolist()}
        if sparse and d_in == frame.d_in(True):    # the wavelength as mu = (550 / lambda)^2
            x_norm.update(wavelength_ref_nm=550.0)  # in 0.52..1.9
            x_norm["mean"][-1], x_norm["scale"][-1] = 1.2, 0.7
        if sparse:                                  # w as its residual, from 0 at q = 0
            wc = frame.w_column
            q = max(lo[wc - 2] ** 2, hi[wc - 2] ** 2) + max(lo[wc - 1] ** 2, hi[wc - 1] ** 2)
            low = float(w_residual(q, np.sqrt(max(1.0 - q, 0.0))))
            x_norm.update(w_residual_column=wc)
            x_norm["mean"][wc], x_norm["scale"][wc] = 0.5 * low, -0.5 * low
        cells.append({"x_norm": x_norm,
                      "y_norm": {"mean": list(my), "scale": list(sy)},
                      "members": [member(rng, d_in, hidden, skip_degree, sparse, frame)
                                  for _ in range(ensemble)]})
    occ = OCC_SHAPE if frame is RADIAL else CART_OCC_SHAPE
    nb = frame.base
    return {"name": name, "bounds": {"lo": lo.tolist(), "hi": hi.tolist()},
            "occupancy": encode_occupancy(np.ones(occ, dtype=bool), lo[:nb], hi[:nb]),
            "tree": tree, "cells": cells}


def make_model(*, dispersion: bool = True, cells: tuple[int, int] = (1, 3), ensemble: int = 3,
               hidden: int = 8, skip_degree: int = 2, seed: int = 0,
               lens_name: str = "synthetic", lens_hash: str = "0" * 16,
               sparse: bool = False, frame: str = "radial") -> dict:
    """A valid model dict (without "files") with random weights; `sparse`: the trainer's
    sparse skip basis (explicit skip_terms, the wavelength seen as (550 / lambda)^2); `frame`:
    core.irf's frame name (model.json's "frame" is written for the cartesian one only, as
    radial models written before it existed have none), or "REAR,FRONT" for a frame per
    stage (written per stage, as the trainer does for a lens whose attachment makes only one
    group anamorphic)."""
    rng = np.random.default_rng(seed)
    names = frame.split(",") if "," in frame else [frame, frame]
    fr1, fr2 = (FRAMES[n] for n in names)
    wl = WL_RANGE if dispersion else [587.5618, 587.5618]
    if "," in frame:
        extra = {"frame": "cartesian" if "cartesian" in names else "radial"}
        per_stage = [{"frame": n} for n in names]
    else:
        extra, per_stage = ({} if fr1 is RADIAL else {"frame": frame}), [{}, {}]
    return {"format": "neurolens-model", "version": 1,
            "lens": {"name": lens_name, "content_hash": lens_hash}, **extra,
            "planes": dict(PLANES),
            "domain": {"film_radius_mm": 18.0, "sensor_z_range": [-1.0, 0.0],
                       "wavelength_range_nm": list(wl), "dispersion": dispersion},
            "stages": [{**stage(rng, "rear", cells[0], fr1.d_in(dispersion), ensemble, hidden,
                                skip_degree, sparse, fr1), **per_stage[0]},
                       {**stage(rng, "front", cells[1], fr2.d_in(dispersion), ensemble, hidden,
                                skip_degree, sparse, fr2), **per_stage[1]}],
            "ensemble_size": ensemble, "theta": hidden, "skip_degree": skip_degree}


def write_model(model: dict, directory) -> Path:
    """Write NAME.neurolens-style directory: the ONNX files and model.json (with their hashes)."""
    directory = Path(directory)
    model = dict(model)
    model["files"] = write_onnx_files(model, directory)
    (directory / "model.json").write_text(json.dumps(model))
    return directory


def random_rays(n: int, seed: int = 1, n_axis: int = 200, r_max: float = 18.0,
                dir_max: float = 0.5) -> np.ndarray:
    """(n, 6) rays on Pi_1 inside the synthetic stage-1 box; the first n_axis have r = 0."""
    rng = np.random.default_rng(seed)
    r = r_max * np.sqrt(rng.random(n))
    r[:n_axis] = 0.0
    phi = rng.uniform(0, 2 * np.pi, n)
    rho = dir_max * np.sqrt(rng.random(n))
    psi = rng.uniform(0, 2 * np.pi, n)
    u, v = rho * np.cos(psi), rho * np.sin(psi)
    return np.stack([r * np.cos(phi), r * np.sin(phi), u, v, np.sqrt(1 - u * u - v * v),
                     rng.uniform(WL_RANGE[0] + 1, WL_RANGE[1] - 1, n)], axis=1)


def near_split(model, rays, margin):
    """Rays whose stage inputs (reference, float64) lie within `margin` of a kd-tree split:
    float32 and float64 may route those to different cells, so tests compare the rest."""
    disp = model["domain"]["dispersion"]
    o = np.concatenate([rays[:, :2], np.zeros((len(rays), 1))], axis=1)
    frames = model_frames(model)
    X1, _ = reference.stage_inputs(o, rays[:, 2:5], rays[:, 5], disp, frames[0])
    stop, _, _ = reference.evaluate(model, rays)
    o2 = np.concatenate([stop[:, :2], np.zeros((len(rays), 1))], axis=1)
    X2, _ = reference.stage_inputs(o2, stop[:, 2:5], rays[:, 5], disp, frames[1])
    near = np.zeros(len(rays), bool)
    for st, X in zip(model["stages"], (X1, X2)):
        for nd in st.get("tree", []):
            if "cell" not in nd:
                near |= np.abs(X[:, nd["axis"]] - nd["split"]) < margin
    return near


def reference_jacobian_fd(model: dict, rays: np.ndarray, h: float) -> np.ndarray:
    """(N, 4, 4) central differences of the float64 reference's Pi_2 (x, y, u, v) over the
    input (x, y, u, v), each perturbed ray's w recomputed so its direction stays unit."""
    J = np.zeros((len(rays), 4, 4))
    for j in range(4):
        plus, minus = rays.copy(), rays.copy()
        plus[:, j] += h
        minus[:, j] -= h
        for r in (plus, minus):
            r[:, 4] = np.sqrt(1 - r[:, 2] ** 2 - r[:, 3] ** 2)
        J[:, :, j] = (reference.evaluate(model, plus)[1][:, :4]
                      - reference.evaluate(model, minus)[1][:, :4]) / (2 * h)
    return J


def write_models(root: Path, specs: dict) -> dict:
    """{name: (model dict, directory)}: one synthetic model per make_model spec, written."""
    out = {}
    for name, kw in specs.items():
        m = make_model(**kw)
        out[name] = (m, write_model(m, Path(root) / f"{name}.neurolens"))
    return out
