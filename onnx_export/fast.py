"""forward_fast.onnx, the rendering graph: film rays to Pi_2 in one graph (neural.fastpath).

Feature-major I/O:
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
both stages as in forward.onnx (in the model's frame: radial rows and the rotation back, or
the cartesian rows as they are), each cell's ensemble folded (_fold_ensemble: the members' tanh
layers stay, heads and skips average into one head and ONE skip, onnx_export.skip); stop
test x_s^2 + y_s^2 <= stop_r2 in float64 on the float32 stop point (as the forward path does).
Valid input: N2_RANGE[0] <= |d|^2 <= N2_RANGE[1] (float32 exact to rounding), w > 0 (lambda,
when the model has no dispersion, is not looked at: the runtime checks it is finite).
Domain: each stage's box and occupancy cell (onnx_export.fast_domain), and the wavelength
range with stage 1. Out-of-domain rays still flow through (NaN included); Where() zeroes what
they output. Multi-cell stages route each ray to its own cell only (NonZero, GatherElements of
its X columns, the cell, one ScatterElements back), instead of every cell on every ray; a cell
whose x_norm names wavelength_ref_nm sees lambda as (l0 / lambda)^2 (builder.features).
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, helper

from neurolens_addon.core.irf import StageFrame
from neurolens_addon.core.rays import RayStatus
from neurolens_addon.neural.modelfile import FAST_FILE, N2_RANGE, member_terms

from .builder import Graph, check_model, f64, features, finish, leaf_masks, value_infos
from .fast_domain import fast_domain, fast_limits
from .skip import skip_poly, sparse_skip

_TINY = float(np.nextafter(np.float32(0.0), np.float32(1.0)))   # smallest float32 > 0


def _fold_ensemble(cell: dict) -> dict:
    """One cell's float64 weights with the ensemble mean folded in (y_norm folded as
    forward.onnx folds it):
    the members' tanh layers stay (W1 [E H, d], b1 [E H], W2 [E, H, H], b2 [E, H]); their
    heads average into A = [W3'_1 ... W3'_E] / E [4, E H] and c = mean_m b3'_m; their skips,
    being linear in the same monomials, average into ONE L = mean_m L'_m [4, T]."""
    members = cell["members"]
    E = len(members)
    my, sy = f64(cell["y_norm"]["mean"]), f64(cell["y_norm"]["scale"])
    W1 = np.concatenate([f64(m["W1"]) for m in members])
    return {"E": E, "H": W1.shape[0] // E, "p": int(members[0].get("skip_degree", 1)),
            "terms": member_terms(members[0], W1.shape[1]),
            "mx": f64(cell["x_norm"]["mean"]), "sx": f64(cell["x_norm"]["scale"]),
            "W1": W1, "b1": np.concatenate([f64(m["b1"]) for m in members]),
            "W2": np.stack([f64(m["W2"]) for m in members]),
            "b2": np.stack([f64(m["b2"]) for m in members]),
            "A": np.concatenate([f64(m["W3"]) * sy[:, None] for m in members], axis=1) / E,
            "c": np.mean([f64(m["b3"]) * sy + my for m in members], axis=0),
            "L": np.mean([f64(m["L"]) * sy[:, None] for m in members], axis=0)}


def _fast_cell(g: Graph, cell: dict, X: str, ones: str, d: int, layer2: str | None,
               base: int) -> str:
    """One cell's ensemble mean Y [4, N] (rows x'_r, x'_t, u'_r, u'_t, or cartesian x', y',
    u', v') on X [d, N] whose first `base` rows are the frame's base columns."""
    f = _fold_ensemble(cell)
    E, H = f["E"], f["H"]
    X = features(g, X, cell["x_norm"], d)
    Xn = g.mul(g.sub(X, g.const(f["mx"][:, None])), g.const((1.0 / f["sx"])[:, None]))
    if "skip_terms" in cell["members"][0]:
        poly = sparse_skip(g, f, Xn, base)
    elif f["p"] >= 2:
        poly = skip_poly(g, f, Xn, ones, d)
    else:
        poly = g.op("Gemm", g.const(f["L"]), Xn, g.const(f["c"][:, None]))
    h1 = g.op("Tanh", g.op("Gemm", g.const(f["W1"]), Xn, g.const(f["b1"][:, None])))
    # layer 2 of all members: one block-diagonal Gemm while E H is small, a batched MatMul
    # above, where the block-diagonal flops grow as (E H)^2 (docs/learned-graphs.md)
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


def _radial_rows(g: Graph, x, y, u, v):
    """(r, u_r, u_t, c, s) exactly as neural.domain.radial_inputs computes them in float32:
    r = sqrt(x^2 + y^2), f = [r == 0], c = (x + f) / (r + f), s = y / (r + f)."""
    r = g.op("Sqrt", g.add(g.mul(x, x), g.mul(y, y)))
    fz = g.op("Cast", g.op("Equal", r, g.const(0.0)), to=TensorProto.FLOAT)
    rs = g.add(r, fz)
    c, s = g.op("Div", g.add(x, fz), rs), g.op("Div", y, rs)
    return r, g.add(g.mul(c, u), g.mul(s, v)), g.sub(g.mul(c, v), g.mul(s, u)), c, s


def _fast_stage(g: Graph, stage: dict, ray, lam, disp: bool, ones: str, length: float,
                frame: StageFrame, extra_lo=None, extra_hi=None, layer2=None):
    """One stage on [1, N] rows: (output rows (x, y, u, v, w), in-domain bool [1, N])."""
    x, y, u, v, w = ray
    if frame.rotates:
        r, ur, ut, c, s = _radial_rows(g, x, y, u, v)
        feats = [r, ur, ut, w]
    else:
        feats = [x, y, u, v, w]
    feats = feats + ([lam] if disp else [])
    d = len(feats)
    X = g.concat(feats, 0)                                                        # [d, N]
    LO, HI, occ = fast_limits(stage, d)
    if extra_lo is not None:
        LO, HI = np.maximum(LO, extra_lo), np.minimum(HI, extra_hi)
    ok = fast_domain(g, X, d, LO, HI, occ)
    if stage.get("propagate"):
        fz = g.op("Cast", g.op("Equal", w, g.const(0.0)), to=TensorProto.FLOAT)
        lq = g.op("Div", g.const(float(length)), g.add(w, fz))
        return (g.add(x, g.mul(lq, u)), g.add(y, g.mul(lq, v)), u, v, w), ok
    if len(stage["cells"]) == 1:
        Y = _fast_cell(g, stage["cells"][0], X, ones, d, layer2, frame.base)
    else:
        tree = stage["tree"]
        masks = leaf_masks(g, tree, feats)
        order = sorted(masks)
        # each cell on its own rays only: gather its columns, evaluate, and put every column
        # back with one scatter (the leaves partition the rays, NaN ones included)
        ys, cols = [], []
        for k in order:
            idx = g.op("NonZero", g.reshape(masks[k], [-1]))                      # [1, n_k]
            Xk = g.op("GatherElements", X, g.op("Expand", idx, g.ints([d, 1])), axis=1)
            ones_k = g.op("Expand", g.const(np.ones((1, 1))), g.op("Shape", idx))
            ys.append(_fast_cell(g, stage["cells"][k], Xk, ones_k, d, layer2, frame.base))
            cols.append(idx)
        Yp, P = g.concat(ys, 1), g.concat(cols, 1)                                 # [4, N]
        Y = g.op("ScatterElements", Yp, g.op("Expand", P, g.ints([4, 1])), Yp, axis=1)
    xr, xt, urp, utp = g.split(Y, 4, 0)
    if frame.rotates:
        xo, yo = g.sub(g.mul(c, xr), g.mul(s, xt)), g.add(g.mul(s, xr), g.mul(c, xt))
        uo, vo = g.sub(g.mul(c, urp), g.mul(s, utp)), g.add(g.mul(s, urp), g.mul(c, utp))
    else:                                      # (x', y', u', v') in lens space already
        xo, yo, uo, vo = xr, xt, urp, utp
    q = g.sub(g.const(1.0), g.add(g.mul(uo, uo), g.mul(vo, vo)))
    return (xo, yo, uo, vo, g.op("Sqrt", g.op("Max", q, g.const(0.0)))), ok


def build_fast(model: dict, layer2: str | None = None) -> onnx.ModelProto:
    """The rendering graph forward_fast.onnx (see the module docstring)."""
    disp, stages, frames = check_model(model)
    g = Graph()
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
    d = frames[0].d_in(disp)
    wc = frames[0].w_column
    elo, ehi = np.full(d, -np.inf, np.float32), np.full(d, np.inf, np.float32)
    elo[wc] = _TINY                                                        # w > 0
    if disp:
        wl = model["domain"]["wavelength_range_nm"]
        elo[wc + 1], ehi[wc + 1] = np.float32(wl[0]), np.float32(wl[1])
    (out1, ok1), length = _fast_stage(g, stages[0], ray, lam, disp, ones, z_stop - z_in, frames[0],
                                      elo, ehi, layer2), z_out - z_stop
    n_ok = g.op("And", g.op("GreaterOrEqual", n2, g.const(N2_RANGE[0])),
                g.op("LessOrEqual", n2, g.const(N2_RANGE[1])))
    ok1 = g.op("And", ok1, n_ok)
    out2, ok2 = _fast_stage(g, stages[1], out1, lam, disp, ones, length, frames[1],
                            layer2=layer2)
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
    inputs, outputs = value_infos(FAST_FILE)
    graph = helper.make_graph(g.nodes, "neurolens_forward_fast", inputs, outputs,
                              initializer=g.inits)
    return finish(graph, model, " (rendering)")
