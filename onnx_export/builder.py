"""The ONNX node builder, and the pieces the forward and the rendering graph share.

`Graph` accumulates nodes and initializers (float32 unless said; equal constants are stored
once) and names every output `hint_k` in creation order, so the same model always gives the
same bytes. `finish` wraps a graph at our opset and IR version; `value_infos` declares a graph
file's inputs and outputs as neural.modelfile.GRAPH_IO lists them.
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from neurolens_addon.core.irf import FRAMES, StageFrame, model_frames
from neurolens_addon.neural.modelfile import GRAPH_IO, member_terms

OPSET = 17
IR_VERSION = 8              # onnxruntime >= 1.14 reads it; keeps files loadable by older runtimes
F32 = np.float32
_ELEMENT = {"float": TensorProto.FLOAT, "double": TensorProto.DOUBLE,
            "uint8": TensorProto.UINT8}


class Graph:
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


def f64(a) -> np.ndarray:
    return np.asarray(a, dtype=np.float64)


def finish(graph, model: dict, note: str) -> onnx.ModelProto:
    """Wrap a graph as a checked ONNX model at our opset and IR version."""
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                          producer_name="neurolens-trainer")
    m.ir_version = IR_VERSION
    m.doc_string = f"NeuroLens learned lens '{model.get('lens', {}).get('name', '?')}'{note}"
    onnx.checker.check_model(m)
    return m


def value_infos(fname: str) -> tuple[list, list]:
    """(inputs, outputs) of graph file `fname` as ONNX value infos, from GRAPH_IO."""
    return tuple([helper.make_tensor_value_info(name, _ELEMENT[typ], shape)
                  for name, typ, shape in part] for part in GRAPH_IO[fname])


def check_model(model: dict) -> tuple[bool, list[dict], list[StageFrame]]:
    """(dispersion, stages, each stage's frame) of a model dict whose cells can be exported:
    known frames, two stages, every cell's members alike (W1 shape and skip monomials) with
    its stage frame's d_in inputs. ValueError if not."""
    try:
        disp = bool(model["domain"]["dispersion"])
        stages = model["stages"]
    except (KeyError, TypeError) as e:
        raise ValueError(f"model dict lacks {e}") from None
    for name in [model.get("frame", "radial")] + [st.get("frame", "radial") for st in stages]:
        if name not in FRAMES:
            raise ValueError(f"unknown frame {name!r} (one of {', '.join(FRAMES)})")
    frames = model_frames(model)
    if len(stages) != 2:
        raise ValueError(f"a model has 2 stages, got {len(stages)}")
    for st, frame in zip(stages, frames):
        d_in = frame.d_in(disp)
        if st.get("propagate"):
            continue
        if not st["cells"]:
            raise ValueError(f"stage '{st.get('name')}' has no cells")
        for k, cell in enumerate(st["cells"]):
            kinds = {(f64(m["W1"]).shape, tuple(member_terms(m, f64(m["W1"]).shape[1])))
                     for m in cell["members"]}
            if len(kinds) != 1:
                raise ValueError(f"stage '{st.get('name')}' cell {k}: members differ in "
                                 f"W1 shape or skip monomials")
            if next(iter(kinds))[0][1] != d_in:
                raise ValueError(f"stage '{st.get('name')}' cell {k}: W1 has "
                                 f"{next(iter(kinds))[0][1]} inputs, expected {d_in}")
    return disp, stages, frames


def features(g: Graph, X: str, x_norm: dict, d_in: int, dX: str | None = None):
    """neural.reference.cell_features: the wavelength row (the last of d_in) as
    (l0 / lambda)^2 when x_norm names l0 (its tangent stays 0: lambda is held fixed), the w
    row c as its residual -q^3 (w + 3) / (8 (1 + w)^3), q = X[c-2]^2 + X[c-1]^2, when x_norm
    names c. With dX [d_in, 4, N] (the rows' tangents) returns (F, dF), else F; the
    residual's tangent is d/dq dq + d/dw dw with
        d/dq = -3 q^2 (w + 3) / (8 (1 + w)^3),  d/dw = q^3 (w + 4) / (4 (1 + w)^4)."""
    ref = x_norm.get("wavelength_ref_nm")
    wc = x_norm.get("w_residual_column")
    if ref is None and wc is None:
        return X if dX is None else (X, dX)
    rows = [g.op("Slice", X, g.ints([i]), g.ints([i + 1]), g.ints([0])) for i in range(d_in)]
    drows = None if dX is None else [g.op("Slice", dX, g.ints([i]), g.ints([i + 1]),
                                          g.ints([0])) for i in range(d_in)]
    if wc is not None:
        a, b, w = rows[wc - 2], rows[wc - 1], rows[wc]
        q = g.add(g.mul(a, a), g.mul(b, b))
        q2 = g.mul(q, q)
        w1 = g.add(w, g.const(1.0))
        w1_3 = g.mul(g.mul(w1, w1), w1)
        w3 = g.add(w, g.const(3.0))
        rows[wc] = g.op("Div", g.mul(g.mul(q2, q), g.mul(w3, g.const(-0.125))), w1_3)
        if dX is not None:
            da, db, dw = drows[wc - 2], drows[wc - 1], drows[wc]
            dq = g.mul(g.add(g.mul(da, g.unsqueeze(a, [1])), g.mul(db, g.unsqueeze(b, [1]))),
                       g.const(2.0))
            d_by_q = g.op("Div", g.mul(q2, g.mul(w3, g.const(-0.375))), w1_3)
            d_by_w = g.op("Div", g.mul(g.mul(q2, q), g.mul(g.add(w, g.const(4.0)),
                                                               g.const(0.25))),
                          g.mul(w1_3, w1))
            drows[wc] = g.add(g.mul(dq, g.unsqueeze(d_by_q, [1])),
                              g.mul(dw, g.unsqueeze(d_by_w, [1])))
    if ref is not None:
        q = g.op("Div", g.const(float(ref)), rows[-1])
        rows[-1] = g.mul(q, q)
    F = g.concat(rows, 0)
    return F if dX is None else (F, g.concat(drows, 0))


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


def leaf_masks(g: Graph, tree: list[dict], rows: list[str]) -> dict[int, str]:
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
