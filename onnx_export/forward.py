"""forward.onnx and forward_jacobian.onnx: a learned lens (model.json dict) as float32 ONNX.

Graph `forward.onnx`
  input   rays      [N, 6] = (x, y, u, v, w, lambda) on Pi_1 (N dynamic)
  outputs stop_rays [N, 5] = (x, y, u, v, w) on the stop plane
          out_rays  [N, 5] = (x, y, u, v, w) on Pi_2
          spread    [N, 2] = each stage's ensemble spread sqrt(mean_m |Y_m - Y|^2)
Graph `forward_jacobian.onnx`: the same plus
          jacobian  [N, 4, 4],  J[n, i, j] = d(x', y', u', v')_i / d(x, y, u, v)_j
where (x', y', u', v') is the ray on Pi_2 and the input direction is the unit vector
(u, v, sqrt(1 - u^2 - v^2)): perturbing u or v also moves w (dw = -(u du + v dv) / w), lambda is
held fixed, and stage 2 sees the stop-plane ray's w1 = sqrt(1 - u1^2 - v1^2) the same way
(tangent rules: onnx_export.dual).

Semantics are those of neurolens_addon.neural.reference. Per stage:
  radial frame   r = sqrt(x^2 + y^2), f = [r == 0], c = (x + f) / (r + f), s = y / (r + f)
                 (so phi = 0 on the axis without a NaN), u_r = c u + s v, u_t = c v - s u,
                 X = (r, u_r, u_t, w[, lambda]);
                 (the cartesian frame of an anamorphic lens: X = (x, y, u, v, w[, lambda]),
                 no rotation either way, core.irf);
  routing        leaf mask = AND over the kd-tree path of (X[a] < t) or its negation; every
                 cell is evaluated on every ray and Where() keeps each ray's own cell;
  one cell       Xn = (X - mean_x) / scale_x,
                 h1_m = tanh(W1_m Xn + b1_m),  h2_m = tanh(W2_m h1_m + b2_m),
                 Y_m  = W3'_m h2_m + b3'_m + L'_m phi(Xn),
                 with the output de-normalisation folded in (in float64, then cast):
                 W3' = diag(sy) W3, b3' = sy * b3 + my, L' = diag(sy) L;
                 phi(Xn) = monomials of degree 1..p, degree by degree as
                 P_k = P_{k-1}[prefix] * Xn[last] (two Gathers and a Mul);
                 Y = mean_m Y_m and spread^2 = sum_m |Y_m - Y|^2 / E come out of ONE set of
                 heads (see _heads): rows [Y; D] = A h2 + c + sum_k B_k P_k, |D|^2 = spread^2;
  back to lens   x' = c x'_r - s x'_t, y' = s x'_r + c x'_t (same for u', v'; cartesian: Y
                 is (x', y', u', v') already), w' = sqrt(max(0, 1 - u'^2 - v'^2)).
Tangents of a cell: d tanh(z) = (1 - tanh(z)^2) dz, dY = A[:4] dh2 + sum_k B_k[:4] dP_k,
dP_k = dP_{k-1}[prefix] Xn[last] + P_{k-1}[prefix] dXn[last].

Layout. Tensors are feature-major, [features, N]: a component is a contiguous row, and the
[N, 1] input columns reshape to [1, N] rows for free. The members share GEMMs: layer 1 is one
Gemm with the stacked W1 [E H, d]; layer 2 is a batched MatMul [E, H, H] x [E, H, N]; the heads
and the skip are Gemms accumulating through C. Normalising x stays an explicit Sub/Mul, since
the skip needs Xn itself. (The alternatives measured: docs/learned-graphs.md.)
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import helper

from neurolens_addon.core.irf import StageFrame
from neurolens_addon.neural.modelfile import FORWARD_FILE, JACOBIAN_FILE, member_terms
from neurolens_addon.neural.reference import prefix_closure

from .builder import Graph, check_model, f64, features, finish, leaf_masks, value_infos
from .dual import Dual, dw, propagate, radial, unit_w


def _heads(W3, b3, L):
    """Output heads of one cell with the ensemble mean and spread folded in.

    W3 [E, 4, H], b3 [E, 4], L [E, 4, T] (y_norm already folded) -> A [4 + 4(E-1), E H],
    c, B [4 + 4(E-1), T] such that rows 0..3 of (A h2 + c + B phi) are Y = mean_m Y_m and the
    remaining rows D satisfy |D|^2 = sum_m |Y_m - Y|^2 / E = spread^2: with Z the members'
    stacked outputs, Y_m - Y = (P Z)_m for the projector P = I - (1 1^T / E) (x) I_4 of rank
    4(E-1), and |P Z|^2 = |Q^T Z|^2 for Q an orthonormal basis of P's range (4 fewer rows)."""
    E, _, H = W3.shape
    W3bd = np.zeros((4 * E, E * H))
    for m in range(E):
        W3bd[4 * m:4 * m + 4, m * H:(m + 1) * H] = W3[m]
    mean = np.tile(np.eye(4), (1, E)) / E                                  # [4, 4E]
    evals, evecs = np.linalg.eigh(np.eye(4 * E) - np.tile(mean, (E, 1)))
    Q = evecs[:, evals > 0.5]                                              # [4E, 4(E-1)]
    M = np.concatenate([mean, Q.T / np.sqrt(E)])
    return M @ W3bd, M @ b3.reshape(-1), M @ L.reshape(4 * E, -1)


def _skip_matrix(members, d_in: int):
    """(monomials, L [E, 4, T]): the members' skip coefficients over the prefix closure of
    their monomials (degree by degree; a prefix the members do not use gets 0)."""
    terms = member_terms(members[0], d_in)
    full = prefix_closure(terms)
    at = {t: i for i, t in enumerate(full)}
    L = np.zeros((len(members), 4, len(full)))
    for m, mem in enumerate(members):
        L[m][:, [at[t] for t in terms]] = f64(mem["L"])
    return full, L


def _cell(g: Graph, cell: dict, X: str, dX: str | None, d_in: int):
    """One cell's ensemble on all rays: Y [4, N], spread [1, N], dY [4, 4, N] or None.

    X is [d_in, N]; dX is [d_in, 4, N] (None for the forward graph)."""
    members = cell["members"]
    E = len(members)
    H = f64(members[0]["W1"]).shape[0]
    mx, sx = f64(cell["x_norm"]["mean"]), f64(cell["x_norm"]["scale"])
    my, sy = f64(cell["y_norm"]["mean"]), f64(cell["y_norm"]["scale"])
    W1 = np.concatenate([f64(m["W1"]) for m in members])                # [E H, d]
    b1 = np.concatenate([f64(m["b1"]) for m in members])                # [E H]
    W2 = np.stack([f64(m["W2"]) for m in members])                      # [E, H, H]
    b2 = np.concatenate([f64(m["b2"]) for m in members])
    W3 = np.stack([f64(m["W3"]) for m in members]) * sy[None, :, None]   # [E, 4, H]
    b3 = np.stack([f64(m["b3"]) for m in members]) * sy[None, :] + my    # [E, 4]
    terms, L = _skip_matrix(members, d_in)
    L = L * sy[None, :, None]                                             # [E, 4, T]
    A, c, B = _heads(W3, b3, L)
    EH = E * H

    inv_sx = 1.0 / sx
    if dX is None:
        X = features(g, X, cell["x_norm"], d_in)
    else:
        X, dX = features(g, X, cell["x_norm"], d_in, dX)
    Xn = g.mul(g.sub(X, g.const(mx[:, None])), g.const(inv_sx[:, None]))           # [d, N]
    dXn = None if dX is None else g.mul(dX, g.const(inv_sx[:, None, None]))         # [d, 4, N]

    # polynomial skip, degree by degree: P_k [T_k, N] (and dP_k [T_k, 4, N])
    p = max(len(t) for t in terms)
    blocks, prev_terms, prev, dprev = [], None, None, None
    Xn3 = g.unsqueeze(Xn, [1]) if dX is not None else None                          # [d, 1, N]
    col = 0
    for k in range(1, p + 1):
        tk = [t for t in terms if len(t) == k]
        if k == 1:
            P, dP = Xn, dXn
        else:
            pos = {t: i for i, t in enumerate(prev_terms)}
            pre = [pos[t[:-1]] for t in tk]
            last = [t[-1] for t in tk]
            P = g.mul(g.gather(prev, pre), g.gather(Xn, last))
            dP = None
            if dX is not None:
                prev3 = g.unsqueeze(prev, [1])
                dP = g.add(g.mul(g.gather(dprev, pre), g.gather(Xn3, last)),
                           g.mul(g.gather(prev3, pre), g.gather(dXn, last)))
        blocks.append((P, dP, slice(col, col + len(tk))))
        col += len(tk)
        prev_terms, prev, dprev = tk, P, dP

    # hidden layers: layer 1 one Gemm for all members [E H, N]; layer 2 batched [E, H, N]
    h1 = g.op("Tanh", g.op("Gemm", g.const(W1), Xn, g.const(b1[:, None])))
    W2c = g.const(W2)
    h2 = g.op("Tanh", g.add(g.mm(W2c, g.reshape(h1, [E, H, -1])), g.const(b2.reshape(E, H, 1))))
    h2 = g.reshape(h2, [EH, -1])
    out = g.op("Gemm", g.const(A), h2, g.const(c[:, None]))                          # [4+4(E-1), N]
    for P, _, sl in blocks:
        out = g.op("Gemm", g.const(B[:, sl]), P, out)
    if E > 1:
        Y, dev = g.op("Split", out, g.ints([4, 4 * (E - 1)]), n_out=2, axis=0)
        spread = g.op("Sqrt", g.op("ReduceSumSquare", dev, axes=[0], keepdims=1))   # [1, N]
    else:                                                       # one member: no spread
        Y, spread = out, g.op("ReduceSumSquare", g.mul(out, g.const(0.0)), axes=[0], keepdims=1)
    if dX is None:
        return Y, spread, None

    # tangents [., 4 N]: dh = (1 - h^2) (W dh_prev); dY = A[:4] dh2 + sum_k B_k[:4] dP_k
    def dtanh(h, dpre, rows):
        gk = g.unsqueeze(g.sub(g.const(1.0), g.mul(h, h)), [1])                       # [R,1,N]
        return g.reshape(g.mul(g.reshape(dpre, [rows, 4, -1]), gk), [rows, -1])       # [R,4N]

    dh1 = dtanh(h1, g.mm(g.const(W1), g.reshape(dXn, [d_in, -1])), EH)
    dpre2 = g.reshape(g.mm(W2c, g.reshape(dh1, [E, H, -1])), [EH, -1])
    dY = g.mm(g.const(A[:4]), dtanh(h2, dpre2, EH))                                  # [4, 4N]
    for _, dP, sl in blocks:
        dY = g.op("Gemm", g.const(B[:4, sl]), g.reshape(dP, [sl.stop - sl.start, -1]), dY)
    return Y, spread, g.reshape(dY, [4, 4, -1])


def _stage(g: Graph, stage: dict, ray, lam: str, dispersion: bool, frame: StageFrame):
    """One stage: ray = (x, y, u, v, w) duals on its input plane -> output duals and spread.
    Routing is piecewise constant, so Where() selects each ray's cell with its tangents."""
    x, y, u, v, w = ray
    if frame.rotates:
        r, ur, ut, c, s = radial(g, x, y, u, v)
        feats, full = [r, ur, ut, w], r
    else:
        c = s = None
        feats, full = [x, y, u, v, w], w
    feats = feats + ([Dual(lam)] if dispersion else [])
    d_in = len(feats)
    X = g.concat([f.p for f in feats], 0)                                               # [d, N]
    dX = None
    if x.t is not None:
        # `full` has a [4, N] tangent; the cartesian inputs' own may be the [4, 1] seeds,
        # broadcast to [4, N] by adding its zero
        zero_t = None
        rows = []
        for f in feats:
            t = f.t
            if t is None or (not frame.rotates and f is not full):
                zero_t = zero_t or g.mul(full.t, g.const(0.0))
                t = zero_t if t is None else g.add(t, zero_t)
            rows.append(g.unsqueeze(t, [0]))
        dX = g.concat(rows, 0)                                                          # [d,4,N]

    cells = [_cell(g, cell, X, dX, d_in) for cell in stage["cells"]]
    tree = stage["tree"]
    if len(cells) == 1:
        Y, spread, dY = cells[0]
    else:
        masks = leaf_masks(g, tree, [f.p for f in feats])
        order = sorted(masks)
        Y, spread, dY = cells[order[-1]]
        for k in order[-2::-1]:
            Yk, sk, dYk = cells[k]
            Y = g.where(masks[k], Yk, Y)
            spread = g.where(masks[k], sk, spread)
            if dY is not None:
                dY = g.where(masks[k], dYk, dY)

    xr, xt, urp, utp = g.split(Y, 4, 0)
    dxr = dxt = durp = dutp = None
    if dY is not None:
        dxr, dxt, durp, dutp = (g.reshape(t, [4, -1]) for t in g.split(dY, 4, 0))
    if not frame.rotates:          # Y is (x', y', u', v') in lens space already
        xo, yo, uo, vo = Dual(xr, dxr), Dual(xt, dxt), Dual(urp, durp), Dual(utp, dutp)
        return (xo, yo, uo, vo, unit_w(g, uo, vo)), spread
    cd, sd = c, s

    def rot(a, at, b, bt):
        """(c a - s b, s a + c b) with tangents."""
        p1 = g.sub(g.mul(cd.p, a), g.mul(sd.p, b))
        p2 = g.add(g.mul(sd.p, a), g.mul(cd.p, b))
        if at is None:
            return Dual(p1), Dual(p2)
        t1 = g.sub(g.lin([(cd.t, a), (cd.p, at)]), g.lin([(sd.t, b), (sd.p, bt)]))
        t2 = g.lin([(sd.t, a), (sd.p, at), (cd.t, b), (cd.p, bt)])
        return Dual(p1, t1), Dual(p2, t2)

    xo, yo = rot(xr, dxr, xt, dxt)
    uo, vo = rot(urp, durp, utp, dutp)
    wo = unit_w(g, uo, vo)
    return (xo, yo, uo, vo, wo), spread


def build_forward(model: dict, jacobian: bool = False) -> onnx.ModelProto:
    """The model's two-stage forward graph (plus the Jacobian output when `jacobian`)."""
    disp, stages, frames = check_model(model)
    g = Graph()
    # [N, 1] columns and [1, N] rows share their memory layout: the reshapes are free
    x, y, u, v, w, lam = (g.reshape(col, [1, -1]) for col in g.split("rays", 6, 1))
    if jacobian:
        eye = np.eye(4)
        seed = [g.const(eye[:, j:j + 1]) for j in range(4)]                             # [4, 1]
        ray = [Dual(x, seed[0]), Dual(y, seed[1]), Dual(u, seed[2]), Dual(v, seed[3]),
               Dual(w, dw(g, u, v, w, seed[2], seed[3]))]
    else:
        ray = [Dual(x), Dual(y), Dual(u), Dual(v), Dual(w)]
    planes = model["planes"]
    zs = [(float(planes["input_z"]), float(planes["stop_z"])),
          (float(planes["stop_z"]), float(planes["output_z"]))]
    outs = []
    for st, frame, (z_in, z_out) in zip(stages, frames, zs):
        if st.get("propagate"):
            outs.append(propagate(g, ray, z_out - z_in))
        else:
            outs.append(_stage(g, st, ray, lam, disp, frame))
        ray = outs[-1][0]
    (out1, s1), (out2, s2) = outs

    def columns(rows, name):
        g.nodes.append(helper.make_node("Concat", [g.reshape(r, [-1, 1]) for r in rows], [name],
                                        axis=1))

    columns([d.p for d in out1], "stop_rays")
    columns([d.p for d in out2], "out_rays")
    columns([s1, s2], "spread")
    if jacobian:      # [4 outputs, 4 seeds, N] -> [N, 4, 4]
        J = g.concat([g.unsqueeze(d.t, [0]) for d in out2[:4]], 0)
        g.nodes.append(helper.make_node("Transpose", [J], ["jacobian"], perm=[2, 0, 1]))
    inputs, outputs = value_infos(JACOBIAN_FILE if jacobian else FORWARD_FILE)
    graph = helper.make_graph(
        g.nodes, "neurolens_" + ("forward_jacobian" if jacobian else "forward"), inputs, outputs,
        initializer=g.inits)
    return finish(graph, model, "")
