"""Fitting a stage: error-driven kd-tree of cells, each an ensemble of networks.

For a cell (paper, section 4.4-4.5):
  * its samples come from the cell's box enlarged by 10 % on every side (continuity across
    cell borders); 80 % train, 20 % test;
  * the hidden width grows 4, 8, ... up to Theta until the ensemble's test error is below the
    threshold. The error that decides is the one an image sees: the RMS displacement, 1 m
    away, of the ray the cell predicts, sqrt(dx^2 + dy^2 + (1000 du)^2 + (1000 dv)^2) mm
    (Eq. 4's relative error is dominated by positions in mm and would let direction errors,
    which the image magnifies, through; both are recorded);
  * each of the E members trains on its own random subset of the training samples; the
    ensemble's output is their mean.
If the error at width Theta stays above the threshold (and depth and sample count allow), the
cell is split at the midpoint of one axis. Every axis is tried; the one whose two halves are
fitted best by the cells' polynomial skip alone (a least-squares fit: fast, and it ranks the
axes as the full fit does) is kept, and both halves are fitted recursively.
A stage is fitted in its lens's frame (core.irf): the radial frame's mirror symmetry in u_t
(the sparse skip's parity split, no split on u_t) holds only there; the cartesian frame of an
anamorphic lens uses every monomial the basis lists and may split on any axis.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from neurolens_addon.core.irf import RADIAL, StageFrame
from neurolens_addon.neural.modelfile import monomial_terms
from neurolens_addon.neural.reference import cell_features

from .mlp import (MIRROR_INPUT, MIRROR_OUTPUTS, Normaliser, fit_member, monomials, skip_lstsq,
                  sparse_skip_terms)
from .progress import ProgressBar


@dataclass
class FitConfig:
    theta: int = 8                  # largest hidden width
    ensemble: int = 3
    skip_degree: int = 5
    # "sparse": the skip keeps the monomials sparse_skip_terms lists, sees the wavelength as
    # (wavelength_ref_nm / lambda)^2 and w as its residual beyond the directions' expansion
    # (neural.reference.w_residual) and, in the radial frame, is fitted mirror-symmetric in
    # u_t (no split on u_t);
    # "full": every monomial of degree 1..skip_degree in the raw inputs (the earlier models).
    skip_basis: str = "full"
    networks: bool = True           # False: the skip polynomial alone (the polynomial baseline)
    wavelength_ref_nm: float = 550.0
    error_threshold: float = 0.01   # RMS displacement at 1 m (mm) a cell must reach
    max_depth: int = 3
    min_cell_samples: int = 4000
    member_samples: int = 8000      # training samples per member (each its own subset)
    method: str = "lm"              # "lm" or "adam"
    lm_iterations: int = 40
    adam_epochs: int = 150
    cell_time_budget_s: float = 120.0
    seed: int = 0
    progress: bool = False          # draw progress bars (the command line turns them on)


@dataclass
class CellFit:
    cell: dict
    test_error: float          # displacement at 1 m, mm (the criterion)
    hidden: int
    n_train: int
    seconds: float
    relative_error: float = 0.0    # Eq. 4


def relative_error(pred: np.ndarray, target: np.ndarray) -> float:
    """Eq. 4: sqrt(sum |pred - target|^2 / sum |target|^2)."""
    return float(np.sqrt(((pred - target) ** 2).sum() / max((target ** 2).sum(), 1e-300)))


#: weights turning (dx_r, dx_t, du_r, du_t) into a displacement 1 m (1000 mm) away
DISPLACEMENT_WEIGHTS = np.array([1.0, 1.0, 1000.0, 1000.0])


def displacement_error_mm(pred: np.ndarray, target: np.ndarray) -> float:
    """RMS displacement at 1 m of predicted rays against true ones (mm)."""
    e = (pred - target) * DISPLACEMENT_WEIGHTS
    return float(np.sqrt((e * e).sum(axis=1).mean())) if len(e) else 0.0


@dataclass
class CellInputs:
    """How a cell turns stage inputs X into network inputs and back: features, normalisers,
    skip monomials and whether the skip is mirror-symmetric."""

    x_norm: dict                  # model.json's x_norm (mean, scale[, wavelength_ref_nm])
    nx: Normaliser
    ny: Normaliser
    terms: list | None            # None: every monomial of degree 1..skip_degree
    mirror: bool

    @staticmethod
    def fit(X: np.ndarray, Y: np.ndarray, cfg: "FitConfig",
            frame: StageFrame = RADIAL) -> "CellInputs":
        sparse = cfg.skip_basis == "sparse"
        mirror = sparse and frame.mirror
        has_wl = X.shape[1] == frame.d_in(True)
        ref = {"wavelength_ref_nm": float(cfg.wavelength_ref_nm)} if sparse and has_wl else {}
        if sparse:      # w beside the directions, well conditioned (neural.reference)
            ref["w_residual_column"] = frame.w_column
        F = cell_features(X, ref)
        nx = Normaliser.fit(F, zero_mean=(MIRROR_INPUT,) if mirror else ())
        ny = Normaliser.fit(Y, zero_mean=MIRROR_OUTPUTS if mirror else ())
        terms = (sparse_skip_terms(X.shape[1], cfg.skip_degree, frame.w_column)
                 if sparse else None)
        return CellInputs({**nx.as_dict(), **ref}, nx, ny, terms, mirror)

    def xn(self, X: np.ndarray) -> np.ndarray:
        return self.nx.apply(cell_features(X, self.x_norm))

    def skip_terms(self, d_in: int, degree: int):
        return monomial_terms(d_in, degree) if self.terms is None else self.terms


def _box_select(X, lo, hi, grow=0.10):
    pad = (hi - lo) * grow
    return np.all((X >= lo - pad) & (X <= hi + pad), axis=1)


def _ensemble_predict(members, ci: CellInputs, X):
    xn = ci.xn(X)
    return np.mean([ci.ny.invert(m.forward(xn)) for m in members], axis=0)


def fit_cell(Xtr, Ytr, Xte, Yte, cfg: FitConfig, rng: np.random.Generator, log=print,
             frame: StageFrame = RADIAL) -> CellFit:
    t0 = time.perf_counter()
    ci = CellInputs.fit(Xtr, Ytr, cfg, frame)
    Xn, Yn = ci.xn(Xtr), ci.ny.apply(Ytr)
    if not cfg.networks:
        return _polynomial_cell(ci, Xn, Yn, Xte, Yte, cfg, t0, log)
    best = None
    widths = list(range(4, cfg.theta + 1, 4)) or [cfg.theta]
    if widths[-1] != cfg.theta:
        widths.append(cfg.theta)
    bar = ProgressBar(len(widths) * cfg.ensemble, "      training") if cfg.progress else None
    for hidden in widths:
        members = []
        per_member_budget = cfg.cell_time_budget_s / (len(widths) * cfg.ensemble)
        for e in range(cfg.ensemble):
            sub = rng.choice(Xn.shape[0], size=min(cfg.member_samples, Xn.shape[0]), replace=False)
            members.append(fit_member(Xn[sub], Yn[sub], hidden, cfg.skip_degree, rng,
                                      method=cfg.method, lm_iterations=cfg.lm_iterations,
                                      adam_epochs=cfg.adam_epochs,
                                      time_budget_s=per_member_budget,
                                      skip_terms=ci.terms, mirror=ci.mirror))
            if bar:
                bar.update(note=f"width {hidden}, member {e + 1}/{cfg.ensemble}")
        pred = _ensemble_predict(members, ci, Xte)
        err, rel = displacement_error_mm(pred, Yte), relative_error(pred, Yte)
        log(f"      width {hidden:2d}: {err:.4f} mm at 1 m, relative {100 * rel:.4f} %")
        if best is None or err < best[0]:
            best = (err, hidden, members, rel)
        if err <= cfg.error_threshold:
            if bar:
                bar.update(bar.total - bar.done, note="threshold reached")
            break
    err, hidden, members, rel = best
    cell = {"x_norm": ci.x_norm, "y_norm": ci.ny.as_dict(),
            "members": [m.as_dict() for m in members], "hidden": hidden,
            "test_error_mm_at_1m": err, "relative_error": rel, "n_train": int(Xtr.shape[0])}
    return CellFit(cell, err, hidden, int(Xtr.shape[0]), time.perf_counter() - t0, rel)


def _polynomial_cell(ci: CellInputs, Xn, Yn, Xte, Yte, cfg: FitConfig, t0: float, log) -> CellFit:
    """A cell that is the least-squares skip polynomial alone: one member whose network has
    one hidden unit and a zero output layer (so the model format and graphs stay the same)."""
    from .mlp import MLP
    terms = ci.skip_terms(Xn.shape[1], cfg.skip_degree)
    L, c = skip_lstsq(Xn, Yn, terms, ci.mirror)
    d, o = Xn.shape[1], Yn.shape[1]
    net = MLP(np.zeros((1, d)), np.zeros(1), np.zeros((1, 1)), np.zeros(1), np.zeros((o, 1)), c,
              L, cfg.skip_degree, None if ci.terms is None else list(terms))
    pred = _ensemble_predict([net], ci, Xte)
    err, rel = displacement_error_mm(pred, Yte), relative_error(pred, Yte)
    log(f"      polynomial degree {cfg.skip_degree}: {err:.4f} mm at 1 m, relative {100 * rel:.4f} %")
    cell = {"x_norm": ci.x_norm, "y_norm": ci.ny.as_dict(), "members": [net.as_dict()],
            "hidden": 0, "test_error_mm_at_1m": err, "relative_error": rel,
            "n_train": int(Xn.shape[0])}
    return CellFit(cell, err, 0, int(Xn.shape[0]), time.perf_counter() - t0, rel)


def _poly_error(Xtr, Ytr, Xte, Yte, cfg: FitConfig, frame: StageFrame = RADIAL):
    """Displacement error (mm at 1 m) of the least-squares skip polynomial alone."""
    ci = CellInputs.fit(Xtr, Ytr, cfg, frame)
    terms = ci.skip_terms(Xtr.shape[1], cfg.skip_degree)
    L, c = skip_lstsq(ci.xn(Xtr), ci.ny.apply(Ytr), terms, ci.mirror)
    pred = monomials(ci.xn(Xte), terms) @ L.T + c
    return displacement_error_mm(ci.ny.invert(pred), Yte)


def best_split_axis(X, Y, lo, hi, test_mask, cfg: FitConfig, frame: StageFrame = RADIAL):
    """Try every axis at its midpoint; keep the one whose halves the polynomial fits best."""
    best = None
    for axis in range(X.shape[1]):
        if hi[axis] - lo[axis] <= 0:
            continue
        if axis == MIRROR_INPUT and cfg.skip_basis == "sparse" and frame.mirror:
            continue                  # the mirror-symmetric skip already fits both halves alike
        mid = 0.5 * (lo[axis] + hi[axis])
        score = 0.0
        ok = True
        for side in (0, 1):
            clo, chi = lo.copy(), hi.copy()
            if side == 0:
                chi[axis] = mid
            else:
                clo[axis] = mid
            sel = _box_select(X, clo, chi)
            tr, te = sel & ~test_mask, sel & test_mask & _box_select(X, clo, chi, 0.0)
            if tr.sum() < cfg.min_cell_samples // 2 or te.sum() < 50:
                ok = False
                break
            score = max(score, _poly_error(X[tr], Y[tr], X[te], Y[te], cfg, frame))
        if ok and (best is None or score < best[1]):
            best = (axis, score, mid)
    return best


@dataclass
class StageFit:
    tree: list = field(default_factory=list)
    cells: list = field(default_factory=list)
    fits: list = field(default_factory=list)


def cell_rng(seed: int, stage: int, path: str) -> np.random.Generator:
    """Each cell's own random stream, from the seed and its place in the tree, so a resumed
    run (cells loaded from checkpoints) draws exactly what an uninterrupted one would."""
    return np.random.default_rng([seed, stage, int.from_bytes(path.encode() or b"root", "little") % (1 << 62)])


def fit_stage(X, Y, cfg: FitConfig, stage: int = 0, log=print, cache=None,
              frame: StageFrame = RADIAL) -> StageFit:
    """kd-tree of cells over the stage's input box (X in `frame`); 20 % of the samples held
    out for testing. `cache` (get(key) -> CellFit | None, put(key, CellFit)) makes the work
    resumable."""
    test_mask = np.random.default_rng([cfg.seed, stage, 7]).random(X.shape[0]) < 0.2
    out = StageFit()
    lo, hi = X.min(axis=0), X.max(axis=0)

    def build(lo, hi, depth, path="") -> int:
        node_id = len(out.tree)
        out.tree.append({})
        inside = _box_select(X, lo, hi, 0.0)
        tr = _box_select(X, lo, hi) & ~test_mask
        te = inside & test_mask
        key = f"stage{stage}-{path or 'root'}"
        fit = cache.get(key) if cache is not None else None
        if fit is None:
            log(f"    cell {key}: {int(tr.sum())} training samples")
            fit = fit_cell(X[tr], Y[tr], X[te], Y[te], cfg, cell_rng(cfg.seed, stage, path), log,
                           frame)
            if cache is not None:
                cache.put(key, fit)
        else:
            log(f"    cell {key}: resumed from checkpoint ({fit.test_error:.4f} mm at 1 m)")
        can_split = depth < cfg.max_depth and tr.sum() >= 2 * cfg.min_cell_samples
        if fit.test_error > cfg.error_threshold and can_split:
            split = best_split_axis(X, Y, lo, hi, test_mask, cfg, frame)
            if split is not None:
                axis, score, mid = split
                log(f"    split axis {axis} at {mid:.5g} (halves' polynomial error "
                    f"{score:.4f} mm at 1 m)")
                llo, lhi = lo.copy(), hi.copy()
                lhi[axis] = mid
                rlo, rhi = lo.copy(), hi.copy()
                rlo[axis] = mid
                left = build(llo, lhi, depth + 1, path + "L")
                right = build(rlo, rhi, depth + 1, path + "R")
                out.tree[node_id] = {"axis": int(axis), "split": float(mid),
                                     "left": left, "right": right}
                return node_id
        out.tree[node_id] = {"cell": len(out.cells)}
        out.cells.append(fit.cell)
        out.fits.append(fit)
        return node_id

    build(lo, hi, 0)
    return out
