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

Graph `forward_fast.onnx` (rendering: neural.model's trace_from_sensor), feature-major I/O:
  inputs  rays      [6, N] float32 = rows x, y, dx, dy, dz, lambda: film points on the plane
                    z = sensor_z and directions of any positive length (normalised here)
          sensor_z  [M] float32, M = 1 (one plane) or N (one per ray)
          stop_r2   [1] float64, squared radius of the circular stop (inf: no stop test)
  outputs stop_xy   [2, N] float32, the ray's point on the stop plane (0 off the stage-1 domain)
          out_rays  [5, N] float32 = rows x', y', u', v', w' on Pi_2 (0 unless status is OK)
          in_domain [N] uint8: bit 0 = a valid input in stage 1's domain, bit 1 = that and
                    stage 2's domain (on stage 1's output); 3 = the whole model applies
          status    [N] uint8 core.rays.RayStatus: OK 0, CLIPPED_STOP 4 (stage-1 domain,
                    outside the stop), OUT_OF_DOMAIN 8 (incl. invalid input; the runtime
                    tells BAD_INPUT apart in float64)
  Per ray, all float32 unless said: |d|^2 = dx^2 + dy^2 + dz^2, (u, v, w) = d / |d|,
  t = (input_z - sensor_z) / w, (x1, y1) = (x + t u, y + t v) on Pi_1 (numpy's propagate_to_z);
  both stages as in forward.onnx, each cell's ensemble folded (_fold_ensemble: the members'
  tanh layers stay, heads and skips average into one head and ONE skip); stop test
  x_s^2 + y_s^2 <= stop_r2 in float64 on the float32 stop point (as the forward path does).
  Valid input: 1e-30 <= |d|^2 <= 1e30 (float32 exact to rounding), w > 0 (lambda, when the
  model has no dispersion, is not looked at: the runtime checks it is finite).
  Domain (stage k, on its float32 X; exactly neural.model._StageGuard + the wavelength range):
  LO <= X <= HI row by row, where LO/HI merge the bounds box, the occupancy grid's range test
  0 <= (X_i - lo_i) * scale_i <= shape_i (monotone in X_i, so a float32 limit found by
  bisection is exact: occupancy_limits), w > 0 and the wavelength range (stage 1); then the
  occupancy cell min(floor(f_i), shape_i - 1) is looked up by flat C-order index j (exact in
  float32 below 2^24; 0 off the domain) in the grid, a uint8 initializer holding model.json's
  packed bits (GatherElements of byte j // 8, two BitShifts keep bit 7 - j % 8).
  Out-of-domain rays still flow through (NaN included); Where() zeroes what they output.
  Multi-cell stages route each ray to its own cell only (NonZero, GatherElements of its X
  columns, the cell, one ScatterElements back), instead of every cell on every ray.
  The skip polynomial is factored for one big MatMul (see _skip_poly; explicit sparse
  monomials: _sparse_skip), and a cell whose x_norm names wavelength_ref_nm sees lambda as
  (l0 / lambda)^2 (_features).
  Measured (onnxruntime 1.31, this 2-core AMD EPYC, 1 thread, batches of 4096-8192, double
  Gauss E = 3, H = 4, p = 4, 1 cell/stage): ~205-215 ns per ray, over half of it the two
  skips. Tried and slower: [N, features] I/O (+30 % for the whole graph), forward.onnx's
  monomials with one M = 4 Gemm (+24 % for a skip), one dense factored MatMul (+8 %),
  ReduceSum for the multiplier sums (that op 10x the ones-MatMul), Gather for the occupancy
  (5x GatherElements), ReduceMin over uint8 for the domain tests (the slowest op of the
  graph); equal within noise: the grid unpacked (8x the bytes), And chains, static shapes.
  Layer 2 is block-diagonal (one fused Gemm + tanh) for E H <= 16, batched MatMul above
  (E = 3, H = 12: batched 14 % faster). Multi-cell routing vs every cell on every ray:
  -22 % (2 + 1 cells), -40 % (2 + 2 cells).
"""

from __future__ import annotations

import base64
import hashlib
import itertools
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from neurolens_addon.core.rays import RayStatus
from neurolens_addon.neural.modelfile import member_terms, monomial_terms
from neurolens_addon.neural.reference import WAVELENGTH_COLUMN, prefix_closure

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


def _skip_matrix(members, d_in: int):
    """(monomials, L [E, 4, T]): the members' skip coefficients over the prefix closure of
    their monomials (degree by degree; a prefix the members do not use gets 0)."""
    terms = member_terms(members[0], d_in)
    full = prefix_closure(terms)
    at = {t: i for i, t in enumerate(full)}
    L = np.zeros((len(members), 4, len(full)))
    for m, mem in enumerate(members):
        L[m][:, [at[t] for t in terms]] = _f64(mem["L"])
    return full, L


def _features(g: _Graph, X: str, x_norm: dict, d_in: int) -> str:
    """neural.reference.cell_features: the wavelength row as (l0 / lambda)^2 when x_norm names
    l0 (its tangent stays 0: lambda is held fixed)."""
    ref = x_norm.get("wavelength_ref_nm")
    if ref is None:
        return X
    assert WAVELENGTH_COLUMN == d_in - 1 == 4
    head = g.op("Slice", X, g.ints([0]), g.ints([4]), g.ints([0]))
    lam = g.op("Slice", X, g.ints([4]), g.ints([5]), g.ints([0]))
    q = g.op("Div", g.const(float(ref)), lam)
    return g.concat([head, g.mul(q, q)], 0)


def _cell(g: _Graph, cell: dict, X: str, dX: str | None, d_in: int):
    """One cell's ensemble on all rays: Y [4, N], spread [1, N], dY [4, 4, N] or None.

    X is [d_in, N]; dX is [d_in, 4, N] (None for the forward graph)."""
    members = cell["members"]
    E = len(members)
    H = _f64(members[0]["W1"]).shape[0]
    mx, sx = _f64(cell["x_norm"]["mean"]), _f64(cell["x_norm"]["scale"])
    my, sy = _f64(cell["y_norm"]["mean"]), _f64(cell["y_norm"]["scale"])
    W1 = np.concatenate([_f64(m["W1"]) for m in members])                # [E H, d]
    b1 = np.concatenate([_f64(m["b1"]) for m in members])                # [E H]
    W2 = np.stack([_f64(m["W2"]) for m in members])                      # [E, H, H]
    b2 = np.concatenate([_f64(m["b2"]) for m in members])
    W3 = np.stack([_f64(m["W3"]) for m in members]) * sy[None, :, None]   # [E, 4, H]
    b3 = np.stack([_f64(m["b3"]) for m in members]) * sy[None, :] + my    # [E, 4]
    terms, L = _skip_matrix(members, d_in)
    L = L * sy[None, :, None]                                             # [E, 4, T]
    A, c, B = _heads(W3, b3, L)
    EH = E * H

    inv_sx = 1.0 / sx
    X = _features(g, X, cell["x_norm"], d_in)
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


def _leaf_masks(g: _Graph, tree: list[dict], rows: list[str]) -> dict[int, str]:
    """Boolean [1, N] mask per cell: the conjunction of the split tests on its root path."""
    less, masks = {}, {}
    for cell_k, path in _leaf_paths(tree):
        m = None
        for i, left in path:
            if i not in less:
                nd = tree[i]
                less[i] = g.op("Less", rows[int(nd["axis"])], g.const(float(nd["split"])))
            cond = less[i] if left else g.op("Not", less[i])
            m = cond if m is None else g.op("And", m, cond)
        masks[cell_k] = m if cell_k not in masks else g.op("Or", masks[cell_k], m)
    return masks


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
        masks = _leaf_masks(g, tree, [f.p for f in feats])
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
            kinds = {(_f64(m["W1"]).shape, tuple(member_terms(m, _f64(m["W1"]).shape[1])))
                     for m in cell["members"]}
            if len(kinds) != 1:
                raise ValueError(f"stage '{st.get('name')}' cell {k}: members differ in "
                                 f"W1 shape or skip monomials")
            if next(iter(kinds))[0][1] != d_in:
                raise ValueError(f"stage '{st.get('name')}' cell {k}: W1 has "
                                 f"{next(iter(kinds))[0][1]} inputs, expected {d_in}")
    return disp, stages


def _finish(graph, model: dict, note: str) -> onnx.ModelProto:
    """Wrap a graph as a checked ONNX model at our opset and IR version."""
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                          producer_name="neurolens-trainer")
    m.ir_version = IR_VERSION
    m.doc_string = f"NeuroLens learned lens '{model.get('lens', {}).get('name', '?')}'{note}"
    onnx.checker.check_model(m)
    return m


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
    return _finish(graph, model, "")


# ====================================================================== forward_fast.onnx

FAST_FILE = "forward_fast.onnx"
N2_RANGE = (1e-30, 1e30)      # |d|^2 whose float32 normalisation is exact to rounding
_FLT_MAX = float(np.finfo(np.float32).max)
_TINY = float(np.nextafter(np.float32(0.0), np.float32(1.0)))   # smallest float32 > 0


def _fold_ensemble(cell: dict) -> dict:
    """One cell's float64 weights with the ensemble mean folded in (y_norm folded as in _cell):
    the members' tanh layers stay (W1 [E H, d], b1 [E H], W2 [E, H, H], b2 [E, H]); their
    heads average into A = [W3'_1 ... W3'_E] / E [4, E H] and c = mean_m b3'_m; their skips,
    being linear in the same monomials, average into ONE L = mean_m L'_m [4, T]."""
    members = cell["members"]
    E = len(members)
    my, sy = _f64(cell["y_norm"]["mean"]), _f64(cell["y_norm"]["scale"])
    W1 = np.concatenate([_f64(m["W1"]) for m in members])
    return {"E": E, "H": W1.shape[0] // E, "p": int(members[0].get("skip_degree", 1)),
            "terms": member_terms(members[0], W1.shape[1]),
            "mx": _f64(cell["x_norm"]["mean"]), "sx": _f64(cell["x_norm"]["scale"]),
            "W1": W1, "b1": np.concatenate([_f64(m["b1"]) for m in members]),
            "W2": np.stack([_f64(m["W2"]) for m in members]),
            "b2": np.stack([_f64(m["b2"]) for m in members]),
            "A": np.concatenate([_f64(m["W3"]) * sy[:, None] for m in members], axis=1) / E,
            "c": np.mean([_f64(m["b3"]) * sy + my for m in members], axis=0),
            "L": np.mean([_f64(m["L"]) * sy[:, None] for m in members], axis=0)}


def _skip_split(t: tuple, q: int):
    """Monomial t (sorted variable indices) = mu * rho: mu its first q indices (() = 1 when t
    has fewer), rho the rest (all indices >= mu's last)."""
    return (t[:q], t[q:]) if len(t) >= q else ((), t)


def _skip_cost(d: int, p: int, q: int, cuts: tuple) -> tuple[float, list, list]:
    """Groups, pieces and an estimated cost in ns per ray of the factored skip with multiplier
    groups cut at variable indices `cuts` (see _skip_poly). Rates fitted to onnxruntime 1.31 on
    a 2-core AMD EPYC (batches of 8192): MatMul ~45 GFMA/s, ~0.12 ns per row of N written,
    ~1.5 ns per group and ~1 ns per piece of fixed work; they rank the plans within ~5 %."""
    bounds = (0,) + cuts + (d,)
    band = lambda i: max(k for k in range(len(bounds) - 1) if bounds[k] <= i)
    terms = monomial_terms(d, p)
    mus = sorted({_skip_split(t, q)[0] for t in terms} | {()}, key=lambda m: (len(m), m))
    rhos = sorted({_skip_split(t, q)[1] for t in terms} | {()}, key=lambda r: (len(r), r))
    groups = [[m for m in mus if (band(m[-1]) if m else 0) == k] for k in range(len(bounds) - 1)]
    pieces = [[r for r in rhos if r and band(r[0]) == k] for k in range(len(bounds) - 1)]
    pieces[-1].append(())
    fma = writes = fixed = 0.0
    for k, grp in enumerate(groups):
        if not grp:
            continue
        rows = 4 * len(grp)
        used = [len(pc) for pc in pieces[k:] if pc]
        fma += rows * sum(used)
        writes += rows * (2 * len(used) - 1) + (2 * rows if len(grp) > 1 else 0)
        fixed += 1.5
    for pc in pieces:
        writes += 3 * len(pc)
        fixed += 1.0 if pc else 0.0
    return 0.022 * fma + 0.12 * writes + fixed, groups, pieces


def _skip_plan(d: int, p: int):
    """(q, groups, pieces) of the cheapest factorisation (see _skip_poly)."""
    q = 1 if p <= 3 else 2
    best = None
    for n in range(d):
        for cuts in itertools.combinations(range(1, d), n):
            cost, groups, pieces = _skip_cost(d, p, q, cuts)
            if best is None or cost < best[0] - 1e-9:
                best = (cost, groups, pieces)
    return q, best[1], best[2]


def _skip_poly(g: _Graph, f: dict, Xn: str, ones: str, d: int) -> str:
    """c + L phi(Xn) [4, N] for skip degree p >= 2, factored so that one MatMul does the bulk:
    every monomial t = mu * rho (_skip_split: mu of degree q = 1 (p <= 3) or 2, or mu = 1),
    so  sum_t L_t t = sum_mu mu * (C_mu rho-vector), with C_mu [4, #rho] gathered from L.
    Multipliers mu are grouped by their last variable index; group k needs only rho over
    variables >= its smallest such index, so the rho monomials are cut into pieces by their
    smallest index and group k multiplies pieces k, k+1, ... (a Gemm chain accumulating G_k
    [4 |group|, N], rows j |group| + m); then sum_m mu_m G_k[j, m] is one broadcast Mul and a
    [1, |group|] MatMul of ones. The cuts minimise _skip_cost (d = 5, p = 4: groups of 4 and 12
    multipliers, [16, 21] and [48, 10] MatMuls, 816 FMA a ray instead of 4 x 126 monomials
    through an M = 4 Gemm; p = 5: three groups). Monomials come from the rows of Xe = [Xn; 1]: P2 =
    all products of two Xe rows (1, x_i, x_i x_j), and a piece holding rho of degree k >= 3 as
    S[rho[:-1]] * Xe[rho[-1]] (Gather, Gather, Mul) with S = all monomials of degree < k."""
    p, L = f["p"], f["L"]
    q, groups, pieces = _skip_plan(d, p)
    pos = {t: i for i, t in enumerate(monomial_terms(d, p))}
    one = d
    Xe = g.concat([Xn, ones], 0)                                              # [d + 1, N]
    pad = lambda t, n: tuple(t) + (one,) * (n - len(t))
    maxdeg = max(len(r) for pc in pieces for r in pc)
    P2 = P2_rows = None
    if q == 2 or maxdeg >= 2:
        P2_terms = ([()] + [(i,) for i in range(d)]
                    + [t for t in monomial_terms(d, 2) if len(t) == 2])
        P2 = g.mul(g.gather(Xe, [pad(t, 2)[0] for t in P2_terms]),
                   g.gather(Xe, [pad(t, 2)[1] for t in P2_terms]))
        P2_rows = {t: i for i, t in enumerate(P2_terms)}
    below = {3: (P2, P2_rows)}           # k -> (tensor of every monomial of degree < k, rows)

    def source(k):
        if k not in below:
            prev, rows = source(k - 1)
            new = [t for t in monomial_terms(d, k - 1) if len(t) == k - 1]
            both = g.concat([prev, rows_of(new)], 0)
            below[k] = (both, {**rows, **{t: len(rows) + i for i, t in enumerate(new)}})
        return below[k]

    def rows_of(terms):
        """A tensor whose rows are the monomials `terms` (0 ops when it is Xe or P2 itself)."""
        if all(len(t) <= 1 for t in terms):
            idx = [t[0] if t else one for t in terms]
            return Xe if idx == list(range(d + 1)) else g.gather(Xe, idx)
        if all(len(t) <= 2 for t in terms):
            idx = [P2_rows[t] for t in terms]
            return P2 if idx == list(range(len(P2_rows))) else g.gather(P2, idx)
        S, S_rows = source(max(len(t) for t in terms))
        return g.mul(g.gather(S, [S_rows[t[:-1]] for t in terms]),
                     g.gather(Xe, [t[-1] if t else one for t in terms]))

    piece_t = [rows_of(pc) if pc else None for pc in pieces]
    poly = None
    for k, grp in enumerate(groups):
        if not grp:
            continue
        M = len(grp)
        mi = {m: i for i, m in enumerate(grp)}
        C = [np.zeros((4, M, len(pc))) for pc in pieces]
        ri = [{r: i for i, r in enumerate(pc)} for pc in pieces]
        where = {r: kk for kk, pc in enumerate(pieces) for r in pc}
        for t in monomial_terms(d, p):
            mu, rho = _skip_split(t, q)
            if mu in mi:
                C[where[rho]][:, mi[mu], ri[where[rho]][rho]] += L[:, pos[t]]
        if () in mi:                                          # mu = 1, rho = 1: the constant
            C[where[()]][:, mi[()], ri[where[()]][()]] += f["c"]
        G = None
        for kk in range(len(pieces) - 1, k - 1, -1):
            if piece_t[kk] is None:
                continue
            Ck = g.const(C[kk].reshape(4 * M, -1))
            G = g.mm(Ck, piece_t[kk]) if G is None else g.op("Gemm", Ck, piece_t[kk], G)
        if M == 1:
            term = G if grp[0] == () else g.mul(G, rows_of(grp))
        else:
            prod = g.mul(g.reshape(G, [4, -1]), g.reshape(rows_of(grp), [1, -1]))
            term = g.reshape(g.mm(g.const(np.ones((1, M))), g.reshape(prod, [4, M, -1])), [4, -1])
        poly = term if poly is None else g.add(poly, term)
    return poly


BASE_INPUTS = 3        # r, u_r, u_t: the skip's full polynomial part; w and mu multiply it


def _split_term(t: tuple) -> tuple[tuple, tuple]:
    """Monomial t = multiplier (its w and mu factors) * base (its r, u_r, u_t factors)."""
    return tuple(i for i in t if i >= BASE_INPUTS), tuple(i for i in t if i < BASE_INPUTS)


def _base_blocks(p: int) -> list[list[tuple]]:
    """Every monomial in (r, u_r, u_t) of degree k = 0..p, block k ordered so that the block
    k + 1 is  concat_i (the first n_i rows of block k) * x_i  with n_i = its monomials whose
    last index is <= i (a prefix, since block k is ordered by last index)."""
    blocks = [[()]]
    for _ in range(p):
        blocks.append([t + (i,) for i in range(BASE_INPUTS) for t in blocks[-1]
                       if not t or t[-1] <= i])
    return blocks


def _sparse_skip(g: _Graph, f: dict, Xn: str) -> str:
    """c + L phi(Xn) [4, N] for explicit skip monomials, factored as
        sum_t L_t t = sum_m m * (C_m b),
    m over the multipliers (products of w and mu: 1, w, mu, mu^2, w mu, ... as the terms
    need), b every monomial of (r, u_r, u_t) up to the top degree (_base_blocks: per degree
    three prefix Slices, three broadcast Muls and a Concat, no Gather), C_m gathered from L.
    One Gemm per degree accumulates G [4 K, N] (rows j K + m, M = 4 K = 24 for the sparse
    basis keeps the GEMM efficient), then Y = sum_m M_m G_m is a broadcast Mul and a [1, K]
    MatMul of ones. Measured on the double Gauss: see the module docstring."""
    terms, L = f["terms"], f["L"]
    mults = sorted({_split_term(t)[0] for t in terms} | {()}, key=lambda m: (len(m), m))
    K = len(mults)
    mi = {m: i for i, m in enumerate(mults)}
    p = max(len(_split_term(t)[1]) for t in terms)
    blocks = _base_blocks(p)
    where = {b: (k, i) for k, blk in enumerate(blocks) for i, b in enumerate(blk)}
    C = [np.zeros((4, K, len(blk))) for blk in blocks]
    for j, t in enumerate(terms):
        m, b = _split_term(t)
        k, i = where[b]
        C[k][:, mi[m], i] += L[:, j]
    C[0][:, mi[()], 0] += f["c"]
    rows = [g.op("Slice", Xn, g.ints([i]), g.ints([i + 1]), g.ints([0])) for i in range(BASE_INPUTS)]
    G = g.const(C[0].reshape(4 * K, 1))
    prev = None
    for k in range(1, p + 1):
        if k == 1:
            Bk = g.op("Slice", Xn, g.ints([0]), g.ints([BASE_INPUTS]), g.ints([0]))
        else:
            pieces = []
            for i in range(BASE_INPUTS):
                n_i = sum(1 for t in blocks[k - 1] if t[-1] <= i)
                src = prev if n_i == len(blocks[k - 1]) else g.op(
                    "Slice", prev, g.ints([0]), g.ints([n_i]), g.ints([0]))
                pieces.append(g.mul(src, rows[i]))
            Bk = g.concat(pieces, 0)
        G = g.op("Gemm", g.const(C[k].reshape(4 * K, -1)), Bk, G)
        prev = Bk
    if K == 1:
        return G
    mrow = {}

    def multiplier(m):
        if m not in mrow:
            x = g.op("Slice", Xn, g.ints([m[-1]]), g.ints([m[-1] + 1]), g.ints([0]))
            mrow[m] = x if len(m) == 1 else g.mul(multiplier(m[:-1]), x)
        return mrow[m]
    for m in mults[1:]:
        multiplier(m)
    Mk = g.concat([g.op("Expand", g.const(np.ones((1, 1))), g.op("Shape", rows[0]))
                   if m == () else mrow[m] for m in mults], 0)                 # [K, N]
    prod = g.mul(g.reshape(G, [4, K, -1]), g.reshape(Mk, [1, K, -1]))
    return g.reshape(g.mm(g.const(np.ones((1, K))), prod), [4, -1])


def _fast_cell(g: _Graph, cell: dict, X: str, ones: str, d: int, layer2: str | None) -> str:
    """One cell's ensemble mean Y [4, N] (rows x'_r, x'_t, u'_r, u'_t) on X [d, N]."""
    f = _fold_ensemble(cell)
    E, H = f["E"], f["H"]
    X = _features(g, X, cell["x_norm"], d)
    Xn = g.mul(g.sub(X, g.const(f["mx"][:, None])), g.const((1.0 / f["sx"])[:, None]))
    if "skip_terms" in cell["members"][0]:
        poly = _sparse_skip(g, f, Xn)
    elif f["p"] >= 2:
        poly = _skip_poly(g, f, Xn, ones, d)
    else:
        poly = g.op("Gemm", g.const(f["L"]), Xn, g.const(f["c"][:, None]))
    h1 = g.op("Tanh", g.op("Gemm", g.const(f["W1"]), Xn, g.const(f["b1"][:, None])))
    if (layer2 or ("blockdiag" if E * H <= 16 else "batched")) == "blockdiag":
        bd = np.zeros((E * H, E * H))
        for m in range(E):
            bd[m * H:(m + 1) * H, m * H:(m + 1) * H] = f["W2"][m]
        h2 = g.op("Tanh", g.op("Gemm", g.const(bd), h1, g.const(f["b2"].reshape(-1, 1))))
    else:
        h2 = g.op("Tanh", g.add(g.mm(g.const(f["W2"]), g.reshape(h1, [E, H, -1])),
                                g.const(f["b2"].reshape(E, H, 1))))
        h2 = g.reshape(h2, [E * H, -1])
    return g.op("Gemm", g.const(f["A"]), h2, poly)


def _f32_key(x) -> int:
    """Integer key monotone in the float32 value (for bisection over float32 numbers)."""
    b = int(np.array(x, np.float32).view(np.uint32))
    return b if b < 0x80000000 else -(b & 0x7FFFFFFF)


def _f32_of_key(k: int) -> np.float32:
    return np.array(k if k >= 0 else (-k) | 0x80000000, np.uint32).view(np.float32)[()]


def _first_true(pred) -> np.float32 | None:
    """Smallest finite float32 x with pred(x), for pred monotone (False ... True); -inf when
    pred(-FLT_MAX) holds, None when pred(FLT_MAX) does not."""
    a, b = _f32_key(-_FLT_MAX), _f32_key(_FLT_MAX)
    if not pred(_f32_of_key(b)):
        return None
    if pred(_f32_of_key(a)):
        return np.float32(-np.inf)
    while b - a > 1:
        m = (a + b) // 2
        a, b = (a, m) if pred(_f32_of_key(m)) else (m, b)
    return _f32_of_key(b)


def occupancy_limits(lo, hi, shape) -> list[tuple[np.float32, np.float32]]:
    """Per occupancy axis i, float32 (TL, TU) such that a float32 x has
    0 <= f <= shape[i] for f = (x - lo32) * scale32 in float32 (lo32 = float32(lo[i]),
    scale32 = float32(shape[i] / (hi[i] - lo[i])): neural.model._StageGuard's arithmetic)
    iff TL <= x <= TU. f is monotone in x, so bisection over float32 finds the limits."""
    out = []
    with np.errstate(over="ignore", invalid="ignore"):
        for i in range(3):
            o = np.float32(lo[i])
            sc = np.float32(shape[i] / (hi[i] - lo[i]))
            s = np.float32(shape[i])
            TL = _first_true(lambda x: (x - o) * sc >= np.float32(0.0))
            over = _first_true(lambda x: not ((x - o) * sc <= s))
            TU = np.float32(np.inf) if over is None else np.nextafter(over, np.float32(-np.inf))
            out.append((np.float32(np.inf) if TL is None else TL, TU))
    return out


def _fast_limits(stage: dict, d: int):
    """float32 (LO [d], HI [d]) such that X passes the stage's bounds box AND the occupancy
    grid's range test iff LO <= X <= HI row by row (exact: both tests compare float32 values
    monotone in X), plus (lo, hi, shape, grid bits) of its occupancy lookup (None: none needed)."""
    if stage.get("propagate"):
        return np.full(d, -_FLT_MAX, np.float32), np.full(d, _FLT_MAX, np.float32), None
    LO = _f64(stage["bounds"]["lo"]).astype(np.float32)
    HI = _f64(stage["bounds"]["hi"]).astype(np.float32)
    occ = stage["occupancy"]
    olo, ohi = _f64(occ["lo"]), _f64(occ["hi"])
    shape = [int(s) for s in occ["shape"]]
    for i, (TL, TU) in enumerate(occupancy_limits(olo, ohi, shape)):
        LO[i], HI[i] = max(LO[i], TL), min(HI[i], TU)
    n = int(np.prod(shape))
    bits = np.frombuffer(base64.b64decode(occ["bits"]), np.uint8)
    full = bool(np.unpackbits(bits)[:n].all())
    return LO, HI, (None if full else (olo, ohi, shape, bits.copy()))


def _fast_domain(g: _Graph, X: str, d: int, LO, HI, occ) -> str:
    """bool [1, N]: LO <= X <= HI in every row (NaN fails), and the occupancy cell is set."""
    inside = g.op("And", g.op("GreaterOrEqual", X, g.const(LO[:, None])),
                  g.op("LessOrEqual", X, g.const(HI[:, None])))
    count = g.mm(g.const(np.ones((1, d))), g.op("Cast", inside, to=TensorProto.FLOAT))
    ok = g.op("Equal", count, g.const(float(d)))
    if occ is None:
        return ok
    olo, ohi, shape, bits = occ
    if int(np.prod(shape)) >= 2 ** 24:
        raise ValueError(f"occupancy grid {shape} too large (flat index must be < 2^24)")
    # cell = min(floor(f), shape - 1) per axis with f as _StageGuard computes it; the flat C-order
    # index j (exact in float32 below 2^24) is zeroed outside the domain; the grid stays packed
    # as model.json has it (np.packbits: bit j is bit 7 - j % 8 of byte j // 8)
    X3 = g.op("Slice", X, g.ints([0]), g.ints([3]), g.ints([0])) if d > 3 else X
    scale = np.array([shape[i] / (ohi[i] - olo[i]) for i in range(3)], dtype=np.float32)
    F = g.mul(g.sub(X3, g.const(olo[:, None])), g.const(scale[:, None]))
    K = g.op("Floor", g.op("Min", F, g.const((np.asarray(shape, float) - 1.0)[:, None])))
    strides = np.array([[shape[1] * shape[2], shape[2], 1.0]])
    flat = g.where(ok, g.mm(g.const(strides), K), g.const(0.0))
    byte = g.op("Floor", g.mul(flat, g.const(0.125)))
    shift = g.sub(g.add(g.mul(byte, g.const(8.0)), g.const(7.0)), flat)          # 7 - j % 8
    b = g.op("GatherElements", g.const(bits, "occupancy", np.uint8),
             g.reshape(g.op("Cast", byte, to=TensorProto.INT32), [-1]), axis=0)
    b = g.op("BitShift", b, g.reshape(g.op("Cast", shift, to=TensorProto.UINT8), [-1]),
             direction="RIGHT")
    b = g.op("BitShift", b, g.const(np.array([7], np.uint8), dtype=np.uint8), direction="LEFT")
    return g.op("And", ok, g.reshape(g.op("Cast", b, to=TensorProto.BOOL), [1, -1]))


def _radial_rows(g: _Graph, x, y, u, v):
    """(r, u_r, u_t, c, s) exactly as neural.model._radial_inputs computes them in float32:
    r = sqrt(x^2 + y^2), f = [r == 0], c = (x + f) / (r + f), s = y / (r + f)."""
    r = g.op("Sqrt", g.add(g.mul(x, x), g.mul(y, y)))
    fz = g.op("Cast", g.op("Equal", r, g.const(0.0)), to=TensorProto.FLOAT)
    rs = g.add(r, fz)
    c, s = g.op("Div", g.add(x, fz), rs), g.op("Div", y, rs)
    return r, g.add(g.mul(c, u), g.mul(s, v)), g.sub(g.mul(c, v), g.mul(s, u)), c, s


def _fast_stage(g: _Graph, stage: dict, ray, lam, disp: bool, ones: str, length: float,
                extra_lo=None, extra_hi=None, layer2=None):
    """One stage on [1, N] rows: (output rows (x, y, u, v, w), in-domain bool [1, N])."""
    x, y, u, v, w = ray
    r, ur, ut, c, s = _radial_rows(g, x, y, u, v)
    feats = [r, ur, ut, w] + ([lam] if disp else [])
    d = len(feats)
    X = g.concat(feats, 0)                                                        # [d, N]
    LO, HI, occ = _fast_limits(stage, d)
    if extra_lo is not None:
        LO, HI = np.maximum(LO, extra_lo), np.minimum(HI, extra_hi)
    ok = _fast_domain(g, X, d, LO, HI, occ)
    if stage.get("propagate"):
        fz = g.op("Cast", g.op("Equal", w, g.const(0.0)), to=TensorProto.FLOAT)
        lq = g.op("Div", g.const(float(length)), g.add(w, fz))
        return (g.add(x, g.mul(lq, u)), g.add(y, g.mul(lq, v)), u, v, w), ok
    if len(stage["cells"]) == 1:
        Y = _fast_cell(g, stage["cells"][0], X, ones, d, layer2)
    else:
        tree = stage["tree"]
        masks = _leaf_masks(g, tree, feats)
        order = sorted(masks)
        # each cell on its own rays only: gather its columns, evaluate, and put every column
        # back with one scatter (the leaves partition the rays, NaN ones included)
        ys, cols = [], []
        for k in order:
            idx = g.op("NonZero", g.reshape(masks[k], [-1]))                      # [1, n_k]
            Xk = g.op("GatherElements", X, g.op("Expand", idx, g.ints([d, 1])), axis=1)
            ones_k = g.op("Expand", g.const(np.ones((1, 1))), g.op("Shape", idx))
            ys.append(_fast_cell(g, stage["cells"][k], Xk, ones_k, d, layer2))
            cols.append(idx)
        Yp, P = g.concat(ys, 1), g.concat(cols, 1)                                 # [4, N]
        Y = g.op("ScatterElements", Yp, g.op("Expand", P, g.ints([4, 1])), Yp, axis=1)
    xr, xt, urp, utp = g.split(Y, 4, 0)
    xo, yo = g.sub(g.mul(c, xr), g.mul(s, xt)), g.add(g.mul(s, xr), g.mul(c, xt))
    uo, vo = g.sub(g.mul(c, urp), g.mul(s, utp)), g.add(g.mul(s, urp), g.mul(c, utp))
    q = g.sub(g.const(1.0), g.add(g.mul(uo, uo), g.mul(vo, vo)))
    return (xo, yo, uo, vo, g.op("Sqrt", g.op("Max", q, g.const(0.0)))), ok


def build_fast(model: dict, layer2: str | None = None) -> onnx.ModelProto:
    """The rendering graph forward_fast.onnx (see the module docstring)."""
    disp, stages = _check(model)
    g = _Graph()
    x, y, dx, dy, dz, lam = g.split("rays", 6, 0)                                  # [1, N]
    zs = g.reshape("sensor_z", [1, -1])                                            # [1, M]
    ones = g.op("Expand", g.const(np.ones((1, 1))), g.op("Shape", x))
    n2 = g.add(g.add(g.mul(dx, dx), g.mul(dy, dy)), g.mul(dz, dz))
    nrm = g.op("Sqrt", n2)
    u, v, w = (g.op("Div", a, nrm) for a in (dx, dy, dz))
    planes = model["planes"]
    z_in, z_stop, z_out = (float(planes[k]) for k in ("input_z", "stop_z", "output_z"))
    t = g.op("Div", g.sub(g.const(z_in), zs), w)
    ray = (g.add(x, g.mul(t, u)), g.add(y, g.mul(t, v)), u, v, w)
    d = 5 if disp else 4
    elo, ehi = np.full(d, -np.inf, np.float32), np.full(d, np.inf, np.float32)
    elo[3] = _TINY                                                         # w > 0
    if disp:
        wl = model["domain"]["wavelength_range_nm"]
        elo[4], ehi[4] = np.float32(wl[0]), np.float32(wl[1])
    (out1, ok1), length = _fast_stage(g, stages[0], ray, lam, disp, ones, z_stop - z_in, elo, ehi,
                                      layer2), z_out - z_stop
    n_ok = g.op("And", g.op("GreaterOrEqual", n2, g.const(N2_RANGE[0])),
                g.op("LessOrEqual", n2, g.const(N2_RANGE[1])))
    ok1 = g.op("And", ok1, n_ok)
    out2, ok2 = _fast_stage(g, stages[1], out1, lam, disp, ones, length, layer2=layer2)
    ok2 = g.op("And", ok1, ok2)
    sxy = g.concat(list(out1[:2]), 0)                                              # [2, N]
    s64 = g.op("Cast", sxy, to=TensorProto.DOUBLE)
    sx64, sy64 = g.split(s64, 2, 0)
    passed = g.op("LessOrEqual", g.add(g.mul(sx64, sx64), g.mul(sy64, sy64)),
                  g.reshape("stop_r2", [1, 1]))
    ok_all = g.op("And", ok2, passed)
    u8 = lambda s: g.const(np.array(int(s), np.uint8), dtype=np.uint8)
    status = g.where(g.op("And", ok1, g.op("Not", passed)), u8(RayStatus.CLIPPED_STOP),
                     g.where(ok_all, u8(RayStatus.OK), u8(RayStatus.OUT_OF_DOMAIN)))
    code = g.add(g.op("Cast", ok1, to=TensorProto.UINT8),
                 g.mul(g.op("Cast", ok2, to=TensorProto.UINT8),
                       g.const(np.array(2, np.uint8), dtype=np.uint8)))
    zero = g.const(0.0)
    g.nodes += [helper.make_node("Where", [ok1, sxy, zero], ["stop_xy"]),
                helper.make_node("Where", [ok_all, g.concat(list(out2), 0), zero], ["out_rays"]),
                helper.make_node("Reshape", [code, g.ints([-1])], ["in_domain"]),
                helper.make_node("Reshape", [status, g.ints([-1])], ["status"])]
    F, U8 = TensorProto.FLOAT, TensorProto.UINT8
    graph = helper.make_graph(
        g.nodes, "neurolens_forward_fast",
        [helper.make_tensor_value_info("rays", F, [6, "N"]),
         helper.make_tensor_value_info("sensor_z", F, ["M"]),
         helper.make_tensor_value_info("stop_r2", TensorProto.DOUBLE, [1])],
        [helper.make_tensor_value_info("stop_xy", F, [2, "N"]),
         helper.make_tensor_value_info("out_rays", F, [5, "N"]),
         helper.make_tensor_value_info("in_domain", U8, ["N"]),
         helper.make_tensor_value_info("status", U8, ["N"])],
        initializer=g.inits)
    return _finish(graph, model, " (rendering)")


def write_onnx_files(model: dict, directory) -> dict[str, str]:
    """Write forward.onnx, forward_jacobian.onnx and forward_fast.onnx into `directory`;
    {filename: sha256 hex}."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    hashes = {}
    for fname, build in ((FORWARD_FILE, lambda: build_forward(model)),
                         (JACOBIAN_FILE, lambda: build_forward(model, jacobian=True)),
                         (FAST_FILE, lambda: build_fast(model))):
        data = build().SerializeToString()
        (directory / fname).write_bytes(data)
        hashes[fname] = hashlib.sha256(data).hexdigest()
    return hashes
