"""A learned lens (model.json dict) as ONNX graphs, float32, opset 17, built node by node.

Graph `forward.onnx`
  input   rays      [N, 6] = (x, y, u, v, w, lambda) on Pi_1 (N dynamic)
  outputs stop_rays [N, 5] = (x, y, u, v, w) on the stop plane
          out_rays  [N, 5] = (x, y, u, v, w) on Pi_2
          spread    [N, 2] = each stage's ensemble spread sqrt(mean_m |Y_m - Y|^2)
Graph `forward_jacobian.onnx`: the same plus
          jacobian  [N, 4, 4],  J[n, i, j] = d(x', y', u', v')_i / d(x, y, u, v)_j
where (x', y', u', v') is the ray on Pi_2 and the input direction is the unit vector
(u, v, sqrt(1 - u^2 - v^2)): perturbing u or v also moves w (dw = -(u du + v dv) / w), lambda is
held fixed, and stage 2 sees the stop-plane ray's w1 = sqrt(1 - u1^2 - v1^2) the same way.

Semantics are those of neurolens_addon.neural.reference. Per stage:
  radial frame   r = sqrt(x^2 + y^2), f = [r == 0], c = (x + f) / (r + f), s = y / (r + f)
                 (so phi = 0 on the axis without a NaN), u_r = c u + s v, u_t = c v - s u,
                 X = (r, u_r, u_t, w[, lambda]);
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
  back to lens   x' = c x'_r - s x'_t, y' = s x'_r + c x'_t (same for u', v'),
                 w' = sqrt(max(0, 1 - u'^2 - v'^2)).

Layout and speed. Tensors are feature-major, [features, N] (a component is a contiguous row;
the [N, 1] input columns reshape to [1, N] rows for free). The members share GEMMs: layer 1 is
one Gemm with the stacked W1 [E H, d]; layer 2 is a batched MatMul [E, H, H] x [E, H, N]; the
heads and the skip are Gemms accumulating through C. Measured with onnxruntime 1.31 on this
2-core machine (1.17 M rays, 2 threads, 16 K batches; E = 3, H = 16, p = 3, dispersion,
1 cell/stage): batched layer 2 4.9 M rays/s; a block-diagonal [E H, E H] Gemm (3x the flops)
and one Gemm chain per member were 5-25 % slower; ray-major [N, features] tensors were slower
still (onnxruntime packs the big operand of every GEMM). Normalising x stays an explicit
Sub/Mul, since the skip needs Xn itself.

Forward-mode tangents (dual numbers, 4 seeds at once for d/dx, d/dy, d/du, d/dv) ride along
every op: a scalar row's tangent is [4, N]; a feature block's is [F, 4, N] (reshaped to
[F, 4 N] for the GEMMs). Rules used:
  d(a b) = da b + a db,  dr = c dx + s dy,  dc = (dx - c dr) / r,  ds = (dy - s dr) / r
  (0 at r = 0, where the frame is not differentiable), d tanh(z) = (1 - tanh(z)^2) dz,
  dY = A[:4] dh2 + sum_k B_k[:4] dP_k, dP_k = dP_{k-1}[prefix] Xn[last] + P_{k-1}[prefix]
  dXn[last]; routing is piecewise constant, so Where() selects the tangents with the values;
  dw' = -(u' du' + v' dv') / w' (0 at w' = 0).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from neurolens_addon.neural.reference import monomial_terms

OPSET = 17
IR_VERSION = 8              # onnxruntime >= 1.14 reads it; keeps files loadable by older runtimes
FORWARD_FILE = "forward.onnx"
JACOBIAN_FILE = "forward_jacobian.onnx"
F32 = np.float32


class _Graph:
    """Accumulates nodes and initializers; every op returns its output's name."""

    def __init__(self):
        self.nodes, self.inits, self._n, self._consts = [], [], 0, {}

    def name(self, hint: str) -> str:
        self._n += 1
        return f"{hint}_{self._n}"

    def const(self, arr, hint: str = "c", dtype=F32) -> str:
        arr = np.asarray(arr, dtype=dtype)
        key = (arr.dtype.str, arr.shape, arr.tobytes())
        if key not in self._consts:
            nm = self.name(hint)
            self.inits.append(numpy_helper.from_array(arr, nm))
            self._consts[key] = nm
        return self._consts[key]

    def ints(self, values) -> str:
        return self.const(np.asarray(values, dtype=np.int64), "i64", np.int64)

    def op(self, op_type: str, *inputs: str, n_out: int = 1, hint: str | None = None, **attrs):
        outs = [self.name(hint or op_type.lower()) for _ in range(n_out)]
        self.nodes.append(helper.make_node(op_type, list(inputs), outs, **attrs))
        return outs[0] if n_out == 1 else outs

    # small conveniences
    def add(self, a, b): return self.op("Add", a, b)
    def sub(self, a, b): return self.op("Sub", a, b)
    def mul(self, a, b): return self.op("Mul", a, b)
    def mm(self, a, b): return self.op("MatMul", a, b)
    def where(self, m, a, b): return self.op("Where", m, a, b)
    def reshape(self, a, shape): return self.op("Reshape", a, self.ints(shape))
    def unsqueeze(self, a, axes): return self.op("Unsqueeze", a, self.ints(axes))
    def concat(self, xs, axis): return self.op("Concat", *xs, axis=axis)
    def gather(self, a, idx, axis=0): return self.op("Gather", a, self.ints(idx), axis=axis)
    def split(self, a, n, axis=0): return self.op("Split", a, n_out=n, axis=axis)

    def lin(self, terms):
        """sum of products a b over terms [(a, b), ...]; a pair with a None factor is zero."""
        acc = None
        for a, b in terms:
            if a is None or b is None:
                continue
            t = self.mul(a, b)
            acc = t if acc is None else self.add(acc, t)
        return acc


class _Dual:
    """A scalar row: primal [1, N] and tangent [4, N] (None = identically zero)."""

    __slots__ = ("p", "t")

    def __init__(self, p, t=None):
        self.p, self.t = p, t


def _radial(g: _Graph, x: _Dual, y: _Dual, u: _Dual, v: _Dual):
    """(r, u_r, u_t, c, s) with tangents; phi = 0 at r = 0 via f = [r == 0]:
    c = (x + f) / (r + f), s = y / (r + f)."""
    r = g.op("Sqrt", g.add(g.mul(x.p, x.p), g.mul(y.p, y.p)))
    f = g.op("Cast", g.op("Equal", r, g.const(0.0)), to=TensorProto.FLOAT)
    inv = g.op("Reciprocal", g.add(r, f))
    c = g.mul(g.add(x.p, f), inv)
    s = g.mul(y.p, inv)
    ur = g.add(g.mul(c, u.p), g.mul(s, v.p))
    ut = g.sub(g.mul(c, v.p), g.mul(s, u.p))
    if x.t is None:
        return _Dual(r), _Dual(ur), _Dual(ut), _Dual(c), _Dual(s)
    dr = g.lin([(c, x.t), (s, y.t)])
    # dc = (dx - c dr) / r, ds = (dy - s dr) / r; zero where r = 0 (1/r -> (1 - f) / (r + f))
    inv_r = g.mul(inv, g.sub(g.const(1.0), f))
    dc = g.mul(g.sub(x.t, g.mul(c, dr)), inv_r)
    ds = g.mul(g.sub(y.t, g.mul(s, dr)), inv_r)
    # d(c u + s v) = dc u + c du + ds v + s dv ;  d(c v - s u) = dc v + c dv - ds u - s du
    dur = g.lin([(dc, u.p), (c, u.t), (ds, v.p), (s, v.t)])
    dut = g.sub(g.lin([(dc, v.p), (c, v.t)]), g.lin([(ds, u.p), (s, u.t)]))
    return _Dual(r, dr), _Dual(ur, dur), _Dual(ut, dut), _Dual(c, dc), _Dual(s, ds)


def _dw(g: _Graph, u, v, w, du, dv):
    """dw = -(u du + v dv) / w for w = sqrt(1 - u^2 - v^2); 0 where w = 0."""
    f = g.op("Cast", g.op("Equal", w, g.const(0.0)), to=TensorProto.FLOAT)
    neg_inv = g.mul(g.op("Reciprocal", g.add(w, f)), g.sub(f, g.const(1.0)))      # -(1-f)/w
    return g.mul(g.lin([(u, du), (v, dv)]), neg_inv)


def _unit_w(g: _Graph, u: _Dual, v: _Dual) -> _Dual:
    """w = sqrt(max(0, 1 - u^2 - v^2)) with its tangent."""
    q = g.sub(g.const(1.0), g.add(g.mul(u.p, u.p), g.mul(v.p, v.p)))
    w = g.op("Sqrt", g.op("Max", q, g.const(0.0)))
    if u.t is None:
        return _Dual(w)
    return _Dual(w, _dw(g, u.p, v.p, w, u.t, v.t))


def _f64(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float64)


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


def _cell(g: _Graph, cell: dict, X: str, dX: str | None, d_in: int):
    """One cell's ensemble on all rays: Y [4, N], spread [1, N], dY [4, 4, N] or None.

    X is [d_in, N]; dX is [d_in, 4, N] (None for the forward graph)."""
    members = cell["members"]
    E = len(members)
    H = _f64(members[0]["W1"]).shape[0]
    p = int(members[0].get("skip_degree", 1))
    mx, sx = _f64(cell["x_norm"]["mean"]), _f64(cell["x_norm"]["scale"])
    my, sy = _f64(cell["y_norm"]["mean"]), _f64(cell["y_norm"]["scale"])
    W1 = np.concatenate([_f64(m["W1"]) for m in members])                # [E H, d]
    b1 = np.concatenate([_f64(m["b1"]) for m in members])                # [E H]
    W2 = np.stack([_f64(m["W2"]) for m in members])                      # [E, H, H]
    b2 = np.concatenate([_f64(m["b2"]) for m in members])
    W3 = np.stack([_f64(m["W3"]) for m in members]) * sy[None, :, None]   # [E, 4, H]
    b3 = np.stack([_f64(m["b3"]) for m in members]) * sy[None, :] + my    # [E, 4]
    L = np.stack([_f64(m["L"]) for m in members]) * sy[None, :, None]     # [E, 4, T]
    A, c, B = _heads(W3, b3, L)
    EH = E * H

    inv_sx = 1.0 / sx
    Xn = g.mul(g.sub(X, g.const(mx[:, None])), g.const(inv_sx[:, None]))           # [d, N]
    dXn = None if dX is None else g.mul(dX, g.const(inv_sx[:, None, None]))         # [d, 4, N]

    # polynomial skip, degree by degree: P_k [T_k, N] (and dP_k [T_k, 4, N])
    terms = monomial_terms(d_in, p)
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


def _leaf_paths(tree: list[dict]):
    """[(cell, [(node, go_left), ...]), ...] for every leaf, depth first from node 0."""
    out, stack = [], [(0, [])]
    while stack:
        i, path = stack.pop()
        nd = tree[i]
        if "cell" in nd:
            out.append((int(nd["cell"]), path))
        else:
            stack.append((int(nd["right"]), path + [(i, False)]))
            stack.append((int(nd["left"]), path + [(i, True)]))
        if len(out) + len(stack) > 4 * len(tree) + 4:
            raise ValueError("kd-tree is not a tree (a node is reached twice)")
    return out


def _stage(g: _Graph, stage: dict, ray, lam: str, dispersion: bool):
    """One stage: ray = (x, y, u, v, w) duals on its input plane -> output duals and spread."""
    x, y, u, v, w = ray
    r, ur, ut, c, s = _radial(g, x, y, u, v)
    feats = [r, ur, ut, w] + ([_Dual(lam)] if dispersion else [])
    d_in = len(feats)
    X = g.concat([f.p for f in feats], 0)                                               # [d, N]
    dX = None
    if x.t is not None:
        zero_t = None
        rows = []
        for f in feats:
            t = f.t
            if t is None:
                zero_t = zero_t or g.mul(r.t, g.const(0.0))
                t = zero_t
            rows.append(g.unsqueeze(t, [0]))
        dX = g.concat(rows, 0)                                                          # [d,4,N]

    cells = [_cell(g, cell, X, dX, d_in) for cell in stage["cells"]]
    tree = stage["tree"]
    if len(cells) == 1:
        Y, spread, dY = cells[0]
    else:
        rows = [f.p for f in feats]
        less = {}
        masks = {}
        for cell_k, path in _leaf_paths(tree):
            m = None
            for i, left in path:
                if i not in less:
                    nd = tree[i]
                    less[i] = g.op("Less", rows[int(nd["axis"])], g.const(float(nd["split"])))
                cond = less[i] if left else g.op("Not", less[i])
                m = cond if m is None else g.op("And", m, cond)
            masks[cell_k] = m if cell_k not in masks else g.op("Or", masks[cell_k], m)
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
    cd, sd = c, s

    def rot(a, at, b, bt):
        """(c a - s b, s a + c b) with tangents."""
        p1 = g.sub(g.mul(cd.p, a), g.mul(sd.p, b))
        p2 = g.add(g.mul(sd.p, a), g.mul(cd.p, b))
        if at is None:
            return _Dual(p1), _Dual(p2)
        t1 = g.sub(g.lin([(cd.t, a), (cd.p, at)]), g.lin([(sd.t, b), (sd.p, bt)]))
        t2 = g.lin([(sd.t, a), (sd.p, at), (cd.t, b), (cd.p, bt)])
        return _Dual(p1, t1), _Dual(p2, t2)

    xo, yo = rot(xr, dxr, xt, dxt)
    uo, vo = rot(urp, durp, utp, dutp)
    wo = _unit_w(g, uo, vo)
    return (xo, yo, uo, vo, wo), spread


def _propagate(g: _Graph, ray, length: float):
    """Free space over `length` mm along z: x' = x + length u / w (directions unchanged)."""
    x, y, u, v, w = ray
    L = g.const(float(length))
    f = g.op("Cast", g.op("Equal", w.p, g.const(0.0)), to=TensorProto.FLOAT)
    q = g.op("Reciprocal", g.add(w.p, f))                       # 1 / w (0 -> 1: flagged anyway)
    lq = g.mul(L, q)
    xo, yo = g.add(x.p, g.mul(lq, u.p)), g.add(y.p, g.mul(lq, v.p))
    if x.t is None:
        return (_Dual(xo), _Dual(yo), u, v, w), g.mul(x.p, g.const(0.0))
    # d(L u / w) = L (du / w - u dw / w^2)
    dq = g.mul(g.mul(w.t, g.mul(q, q)), g.const(-1.0))
    dxo = g.add(x.t, g.mul(L, g.lin([(q, u.t), (u.p, dq)])))
    dyo = g.add(y.t, g.mul(L, g.lin([(q, v.t), (v.p, dq)])))
    return (_Dual(xo, dxo), _Dual(yo, dyo), u, v, w), g.mul(x.p, g.const(0.0))


def _check(model: dict) -> tuple[bool, list[dict]]:
    try:
        disp = bool(model["domain"]["dispersion"])
        stages = model["stages"]
    except (KeyError, TypeError) as e:
        raise ValueError(f"model dict lacks {e}") from None
    if len(stages) != 2:
        raise ValueError(f"a model has 2 stages, got {len(stages)}")
    d_in = 5 if disp else 4
    for st in stages:
        if st.get("propagate"):
            continue
        if not st["cells"]:
            raise ValueError(f"stage '{st.get('name')}' has no cells")
        for k, cell in enumerate(st["cells"]):
            kinds = {(_f64(m["W1"]).shape, int(m.get("skip_degree", 1))) for m in cell["members"]}
            if len(kinds) != 1:
                raise ValueError(f"stage '{st.get('name')}' cell {k}: members differ in "
                                 f"(W1 shape, skip_degree): {sorted(kinds)}")
            if next(iter(kinds))[0][1] != d_in:
                raise ValueError(f"stage '{st.get('name')}' cell {k}: W1 has "
                                 f"{next(iter(kinds))[0][1]} inputs, expected {d_in}")
    return disp, stages


def build_forward(model: dict, jacobian: bool = False) -> onnx.ModelProto:
    """The model's two-stage forward graph (plus the Jacobian output when `jacobian`)."""
    disp, stages = _check(model)
    g = _Graph()
    # [N, 1] columns and [1, N] rows share their memory layout: the reshapes are free
    x, y, u, v, w, lam = (g.reshape(col, [1, -1]) for col in g.split("rays", 6, 1))
    if jacobian:
        eye = np.eye(4)
        seed = [g.const(eye[:, j:j + 1]) for j in range(4)]                             # [4, 1]
        ray = [_Dual(x, seed[0]), _Dual(y, seed[1]), _Dual(u, seed[2]), _Dual(v, seed[3]),
               _Dual(w, _dw(g, u, v, w, seed[2], seed[3]))]
    else:
        ray = [_Dual(x), _Dual(y), _Dual(u), _Dual(v), _Dual(w)]
    planes = model["planes"]
    zs = [(float(planes["input_z"]), float(planes["stop_z"])),
          (float(planes["stop_z"]), float(planes["output_z"]))]
    outs = []
    for st, (z_in, z_out) in zip(stages, zs):
        if st.get("propagate"):
            outs.append(_propagate(g, ray, z_out - z_in))
        else:
            outs.append(_stage(g, st, ray, lam, disp))
        ray = outs[-1][0]
    (out1, s1), (out2, s2) = outs

    def columns(rows, name):
        g.nodes.append(helper.make_node("Concat", [g.reshape(r, [-1, 1]) for r in rows], [name],
                                        axis=1))

    columns([d.p for d in out1], "stop_rays")
    columns([d.p for d in out2], "out_rays")
    columns([s1, s2], "spread")
    outputs = [helper.make_tensor_value_info("stop_rays", TensorProto.FLOAT, ["N", 5]),
               helper.make_tensor_value_info("out_rays", TensorProto.FLOAT, ["N", 5]),
               helper.make_tensor_value_info("spread", TensorProto.FLOAT, ["N", 2])]
    if jacobian:      # [4 outputs, 4 seeds, N] -> [N, 4, 4]
        J = g.concat([g.unsqueeze(d.t, [0]) for d in out2[:4]], 0)
        g.nodes.append(helper.make_node("Transpose", [J], ["jacobian"], perm=[2, 0, 1]))
        outputs.append(helper.make_tensor_value_info("jacobian", TensorProto.FLOAT, ["N", 4, 4]))
    graph = helper.make_graph(
        g.nodes, "neurolens_" + ("forward_jacobian" if jacobian else "forward"),
        [helper.make_tensor_value_info("rays", TensorProto.FLOAT, ["N", 6])], outputs,
        initializer=g.inits)
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                          producer_name="neurolens-trainer")
    m.ir_version = IR_VERSION
    m.doc_string = f"NeuroLens learned lens '{model.get('lens', {}).get('name', '?')}'"
    onnx.checker.check_model(m)
    return m


def write_onnx_files(model: dict, directory) -> dict[str, str]:
    """Write forward.onnx and forward_jacobian.onnx into `directory`; {filename: sha256 hex}."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    hashes = {}
    for fname, jac in ((FORWARD_FILE, False), (JACOBIAN_FILE, True)):
        data = build_forward(model, jacobian=jac).SerializeToString()
        (directory / fname).write_bytes(data)
        hashes[fname] = hashlib.sha256(data).hexdigest()
    return hashes
