"""Reference evaluation of a learned lens in float64 numpy: the semantics the ONNX graph
reproduces in float32 (and the trainer's own measure of error).

A model has two stages (rear group: Pi_1 -> stop plane; front group: stop plane -> Pi_2). Each
stage, for rays (x, y, u, v, w, lambda) on its input plane:
  1. goes to the model's frame (core.irf; model.json "frame", absent: radial):
     radial X = (r, u_r, u_t, w[, lambda]), cartesian X = (x, y, u, v, w[, lambda]);
  2. descends its kd-tree to a leaf cell: node = {"axis": a, "split": t, "left": i, "right": j}
     goes left when X[a] < t; a leaf is {"cell": k};
  3. in cell k, for each ensemble member m:  Y_m = denorm_y(net_m(norm_x(F(X)))), where
     norm_x(F) = (F - mean_x) / scale_x, denorm_y(y) = y * scale_y + mean_y and net_m is the
     network of trainer.mlp (2 tanh layers plus a polynomial skip):
         net(x) = W3 tanh(W2 tanh(W1 x + b1) + b2) + b3 + L phi(x);
     F(X) = X, except that a cell whose x_norm has "wavelength_ref_nm" = l0 sees the
     wavelength (X's last column) as mu = (l0 / lambda)^2 (glass indices go as 1/lambda^2
     to first order, the Cauchy term, so a polynomial of low degree in mu carries the
     dispersion), and a cell whose x_norm has "w_residual_column" = c sees w = X[c] as what
     its fourth-order expansion in q = X[c-2]^2 + X[c-1]^2 (the two direction columns before
     it; w = sqrt(1 - q)) leaves,
         w - (1 - q/2 - q^2/8) = -q^3 (w + 3) / (8 (1 + w)^3),
     written in the right-hand form, which has no cancellation in float32: raw w is nearly a
     polynomial in the directions, so a skip holding w beside them is ill-conditioned (its
     fitted coefficients grow to 1e4-1e5 and cancel, which float32 cannot);
     phi(x) lists the member's "skip_terms" (index tuples: (2, 2, 4) = x_2^2 x_4) or, without
     them, every monomial of degree 1..skip_degree (neural.modelfile.member_terms);
  4. averages the members, Y = mean_m Y_m = (x'_r, x'_t, u'_r, u'_t) (cartesian: (x', y', u',
     v')), and reports their spread sqrt(mean_m |Y_m - Y|^2) as the stage's uncertainty;
  5. rotates Y back to lens space (radial), sets w' = sqrt(1 - u'^2 - v'^2) and z' = the
     output plane.
A stage marked "propagate" (no surfaces in its group) is exact free-space propagation.
"""

from __future__ import annotations

import numpy as np

from ..core.irf import RADIAL, StageFrame, from_frame, model_frames, stage_columns, unit_w
from .modelfile import member_terms


def prefix_closure(terms) -> list[tuple[int, ...]]:
    """`terms` and every prefix of each (t[:-1], t[:-2], ...), ordered by degree then index:
    the monomials a degree-by-degree product P_k = P_{k-1}[t[:-1]] * x[t[-1]] must visit."""
    out = set()
    for t in terms:
        for k in range(1, len(t) + 1):
            out.add(tuple(t[:k]))
    return sorted(out, key=lambda t: (len(t), t))


def monomial_columns(x, terms) -> list:
    """phi(x) as one column per monomial of `terms`, each product formed once from its prefix
    (rows of x: samples; works on numpy arrays and torch tensors alike)."""
    cache = {}
    for t in prefix_closure(terms):
        cache[t] = x[:, t[0]] if len(t) == 1 else cache[t[:-1]] * x[:, t[-1]]
    return [cache[tuple(t)] for t in terms]


def monomials(x: np.ndarray, terms) -> np.ndarray:
    if not len(terms):
        return np.zeros((x.shape[0], 0))
    return np.stack(monomial_columns(x, terms), axis=1)


def w_residual(q, w):
    """w - (1 - q/2 - q^2/8) for w = sqrt(1 - q), without cancellation (module docstring)."""
    return -q ** 3 * (w + 3.0) / (8.0 * (1.0 + w) ** 3)


def cell_features(X: np.ndarray, x_norm: dict) -> np.ndarray:
    """F(X) of the module docstring (step 3): the wavelength column (the last: there is one
    only with dispersion, in either frame) as (l0 / lambda)^2 when the cell's x_norm names a
    reference wavelength l0, the w column as its residual (w_residual) when it names one,
    else X itself."""
    ref = x_norm.get("wavelength_ref_nm")
    wc = x_norm.get("w_residual_column")
    if ref is None and wc is None:
        return X
    F = np.array(X, dtype=np.float64, copy=True)
    if wc is not None:
        F[:, wc] = w_residual(F[:, wc - 2] ** 2 + F[:, wc - 1] ** 2, F[:, wc])
    if ref is not None:
        F[:, -1] = (float(ref) / F[:, -1]) ** 2
    return F


def net_forward(net: dict, x: np.ndarray) -> np.ndarray:
    W1, b1, W2, b2, W3, b3, L = (np.asarray(net[k], dtype=np.float64)
                                 for k in ("W1", "b1", "W2", "b2", "W3", "b3", "L"))
    h1 = np.tanh(x @ W1.T + b1)
    h2 = np.tanh(h1 @ W2.T + b2)
    return h2 @ W3.T + b3 + monomials(x, member_terms(net, x.shape[1])) @ L.T


def route(tree: list[dict], X: np.ndarray) -> np.ndarray:
    """Leaf cell index of each row of X."""
    node = np.zeros(X.shape[0], dtype=np.int64)
    cell = np.full(X.shape[0], -1, dtype=np.int64)
    active = np.ones(X.shape[0], dtype=bool)
    for _ in range(len(tree)):
        if not active.any():
            break
        for i in np.unique(node[active]):
            sel = active & (node == i)
            nd = tree[int(i)]
            if "cell" in nd:
                cell[sel] = nd["cell"]
                active &= ~sel
            else:
                go_left = X[sel, nd["axis"]] < nd["split"]
                idx = np.flatnonzero(sel)
                node[idx[go_left]] = nd["left"]
                node[idx[~go_left]] = nd["right"]
    return cell


def stage_inputs(o, d, wl, dispersion: bool, frame: StageFrame = RADIAL):
    """(X (N, d_in), rotation or None) of rays o, d (N, 3) in `frame` (core.irf)."""
    cols, rot = stage_columns(frame, o[:, 0], o[:, 1], d[:, 0], d[:, 1], d[:, 2], wl, dispersion)
    return np.stack(cols, axis=1), rot


def eval_stage(stage: dict, o, d, wl, dispersion: bool, out_z: float,
               frame: StageFrame = RADIAL):
    """One stage on rays (o (N,3), d (N,3), wl (N,)): returns (o', d', spread).
    A stage with "propagate": true (a lens group with no surfaces, e.g. in front of a stop that
    is the first surface) is exact free-space propagation to out_z."""
    if stage.get("propagate"):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (out_z - o[:, 2]) / d[:, 2]
        o2 = np.stack([o[:, 0] + t * d[:, 0], o[:, 1] + t * d[:, 1], np.full_like(t, out_z)], 1)
        return o2, d.copy(), np.zeros(o.shape[0])
    X, rot = stage_inputs(o, d, wl, dispersion, frame)
    leaf = route(stage["tree"], X)
    Y = np.zeros((X.shape[0], 4))
    spread = np.zeros(X.shape[0])
    for k, cell in enumerate(stage["cells"]):
        sel = leaf == k
        if not sel.any():
            continue
        mx, sx = np.asarray(cell["x_norm"]["mean"]), np.asarray(cell["x_norm"]["scale"])
        my, sy = np.asarray(cell["y_norm"]["mean"]), np.asarray(cell["y_norm"]["scale"])
        xn = (cell_features(X[sel], cell["x_norm"]) - mx) / sx
        Ym = np.stack([net_forward(m, xn) * sy + my for m in cell["members"]])
        mean = Ym.mean(axis=0)
        Y[sel] = mean
        spread[sel] = np.sqrt(((Ym - mean) ** 2).sum(axis=2).mean(axis=0))
    x, y, u, v = from_frame(Y, rot)
    w = unit_w(u, v)
    return (np.stack([x, y, np.full_like(x, out_z)], axis=1), np.stack([u, v, w], axis=1),
            spread)


def evaluate(model: dict, rays: np.ndarray):
    """rays (N, 6) = x, y, u, v, w, lambda on Pi_1 -> (stop_rays (N,5), out_rays (N,5),
    spread (N,2)); rays are (x, y, u, v, w) on the stop plane and on Pi_2."""
    rays = np.asarray(rays, dtype=np.float64)
    disp = bool(model["domain"]["dispersion"])
    frames = model_frames(model)
    planes = model["planes"]
    o = np.concatenate([rays[:, :2], np.full((rays.shape[0], 1), planes["input_z"])], axis=1)
    d, wl = rays[:, 2:5], rays[:, 5]
    o1, d1, s1 = eval_stage(model["stages"][0], o, d, wl, disp, planes["stop_z"], frames[0])
    o2, d2, s2 = eval_stage(model["stages"][1], o1, d1, wl, disp, planes["output_z"], frames[1])
    return (np.concatenate([o1[:, :2], d1], axis=1), np.concatenate([o2[:, :2], d2], axis=1),
            np.stack([s1, s2], axis=1))
