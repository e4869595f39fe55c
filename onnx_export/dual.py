"""Forward-mode tangents for the Jacobian graph: dual numbers in ONNX.

The 4 seeds d/dx, d/dy, d/du, d/dv ride along every op at once: a scalar row's primal is
[1, N] and its tangent [4, N] (None: identically zero); a feature block's tangent is [F, 4, N]
(reshaped to [F, 4 N] for the GEMMs). The input direction is the unit vector
(u, v, sqrt(1 - u^2 - v^2)), so perturbing u or v also moves w. Rules used here:
  d(a b) = da b + a db,  dr = c dx + s dy,  dc = (dx - c dr) / r,  ds = (dy - s dr) / r
  (0 at r = 0, where the radial frame is not differentiable),
  dw = -(u du + v dv) / w  (0 at w = 0),
  free flight x' = x + L u / w:  dx' = dx + L (du / w - u dw / w^2).
The network's own rules (tanh, the skip's products) are in onnx_export.forward.
"""

from __future__ import annotations

from onnx import TensorProto

from .builder import Graph


class Dual:
    """A scalar row: primal [1, N] and tangent [4, N] (None = identically zero)."""

    __slots__ = ("p", "t")

    def __init__(self, p, t=None):
        self.p, self.t = p, t


def radial(g: Graph, x: Dual, y: Dual, u: Dual, v: Dual):
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
        return Dual(r), Dual(ur), Dual(ut), Dual(c), Dual(s)
    dr = g.lin([(c, x.t), (s, y.t)])
    # dc = (dx - c dr) / r, ds = (dy - s dr) / r; zero where r = 0 (1/r -> (1 - f) / (r + f))
    inv_r = g.mul(inv, g.sub(g.const(1.0), f))
    dc = g.mul(g.sub(x.t, g.mul(c, dr)), inv_r)
    ds = g.mul(g.sub(y.t, g.mul(s, dr)), inv_r)
    # d(c u + s v) = dc u + c du + ds v + s dv ;  d(c v - s u) = dc v + c dv - ds u - s du
    dur = g.lin([(dc, u.p), (c, u.t), (ds, v.p), (s, v.t)])
    dut = g.sub(g.lin([(dc, v.p), (c, v.t)]), g.lin([(ds, u.p), (s, u.t)]))
    return Dual(r, dr), Dual(ur, dur), Dual(ut, dut), Dual(c, dc), Dual(s, ds)


def dw(g: Graph, u, v, w, du, dv):
    """dw = -(u du + v dv) / w for w = sqrt(1 - u^2 - v^2); 0 where w = 0."""
    f = g.op("Cast", g.op("Equal", w, g.const(0.0)), to=TensorProto.FLOAT)
    neg_inv = g.mul(g.op("Reciprocal", g.add(w, f)), g.sub(f, g.const(1.0)))      # -(1-f)/w
    return g.mul(g.lin([(u, du), (v, dv)]), neg_inv)


def unit_w(g: Graph, u: Dual, v: Dual) -> Dual:
    """w = sqrt(max(0, 1 - u^2 - v^2)) with its tangent."""
    q = g.sub(g.const(1.0), g.add(g.mul(u.p, u.p), g.mul(v.p, v.p)))
    w = g.op("Sqrt", g.op("Max", q, g.const(0.0)))
    if u.t is None:
        return Dual(w)
    return Dual(w, dw(g, u.p, v.p, w, u.t, v.t))


def propagate(g: Graph, ray, length: float):
    """Free space over `length` mm along z: x' = x + length u / w (directions unchanged);
    -> (output duals, a zero spread row)."""
    x, y, u, v, w = ray
    L = g.const(float(length))
    f = g.op("Cast", g.op("Equal", w.p, g.const(0.0)), to=TensorProto.FLOAT)
    q = g.op("Reciprocal", g.add(w.p, f))                       # 1 / w (0 -> 1: flagged anyway)
    lq = g.mul(L, q)
    xo, yo = g.add(x.p, g.mul(lq, u.p)), g.add(y.p, g.mul(lq, v.p))
    if x.t is None:
        return (Dual(xo), Dual(yo), u, v, w), g.mul(x.p, g.const(0.0))
    # d(L u / w) = L (du / w - u dw / w^2)
    dq = g.mul(g.mul(w.t, g.mul(q, q)), g.const(-1.0))
    dxo = g.add(x.t, g.mul(L, g.lin([(q, u.t), (u.p, dq)])))
    dyo = g.add(y.t, g.mul(L, g.lin([(q, v.t), (v.p, dq)])))
    return (Dual(xo, dxo), Dual(yo, dyo), u, v, w), g.mul(x.p, g.const(0.0))
