"""The learned domain inside forward_fast.onnx, exactly as neural.domain.StageGuard judges it.

Stage k accepts X (its float32 input rows) when LO <= X <= HI row by row, where LO / HI merge
the bounds box with the occupancy grid's range test 0 <= (X_i - lo_i) * scale_i <= shape_i
(i over the grid's axes: the frame's base columns, 3 radial, 4 cartesian).
That test is monotone in X_i, so the float32 limits that reproduce it are found exactly by
bisection over the float32 numbers (`occupancy_limits`). Then the occupancy cell
min(floor(f_i), shape_i - 1) is looked up by its flat C-order index j (exact in float32 below
2^24; 0 off the domain) in the grid, a uint8 initializer holding model.json's packed bits:
GatherElements of byte j // 8, and two BitShifts keep bit 7 - j % 8. NaN fails every test.
"""

from __future__ import annotations

import numpy as np
from onnx import TensorProto

from neurolens_addon.neural.modelfile import decode_occupancy, occupancy_bytes

from .builder import Graph, f64

_FLT_MAX = float(np.finfo(np.float32).max)


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
    scale32 = float32(shape[i] / (hi[i] - lo[i])): neural.domain.StageGuard's arithmetic)
    iff TL <= x <= TU. f is monotone in x, so bisection over float32 finds the limits."""
    out = []
    with np.errstate(over="ignore", invalid="ignore"):
        for i in range(len(shape)):
            o = np.float32(lo[i])
            sc = np.float32(shape[i] / (hi[i] - lo[i]))
            s = np.float32(shape[i])
            TL = _first_true(lambda x: (x - o) * sc >= np.float32(0.0))
            over = _first_true(lambda x: not ((x - o) * sc <= s))
            TU = np.float32(np.inf) if over is None else np.nextafter(over, np.float32(-np.inf))
            out.append((np.float32(np.inf) if TL is None else TL, TU))
    return out


def fast_limits(stage: dict, d: int):
    """float32 (LO [d], HI [d]) such that X passes the stage's bounds box AND the occupancy
    grid's range test iff LO <= X <= HI row by row (exact: both tests compare float32 values
    monotone in X), plus (lo, hi, shape, grid bits) of its occupancy lookup (None: none needed)."""
    if stage.get("propagate"):
        return np.full(d, -_FLT_MAX, np.float32), np.full(d, _FLT_MAX, np.float32), None
    LO = f64(stage["bounds"]["lo"]).astype(np.float32)
    HI = f64(stage["bounds"]["hi"]).astype(np.float32)
    occ = stage["occupancy"]
    olo, ohi = f64(occ["lo"]), f64(occ["hi"])
    shape = [int(s) for s in occ["shape"]]
    for i, (TL, TU) in enumerate(occupancy_limits(olo, ohi, shape)):
        LO[i], HI[i] = max(LO[i], TL), min(HI[i], TU)
    bits = occupancy_bytes(occ)
    full = bool(decode_occupancy(occ).all())
    return LO, HI, (None if full else (olo, ohi, shape, bits.copy()))


def fast_domain(g: Graph, X: str, d: int, LO, HI, occ) -> str:
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
    # cell = min(floor(f), shape - 1) per axis with f as StageGuard computes it; the flat C-order
    # index j (exact in float32 below 2^24) is zeroed outside the domain; the grid stays packed
    # as model.json has it (np.packbits: bit j is bit 7 - j % 8 of byte j // 8); the grid spans
    # the first k rows of X, the frame's base columns
    k = len(shape)
    Xb = g.op("Slice", X, g.ints([0]), g.ints([k]), g.ints([0])) if d > k else X
    scale = np.array([shape[i] / (ohi[i] - olo[i]) for i in range(k)], dtype=np.float32)
    F = g.mul(g.sub(Xb, g.const(olo[:, None])), g.const(scale[:, None]))
    K = g.op("Floor", g.op("Min", F, g.const((np.asarray(shape, float) - 1.0)[:, None])))
    strides = np.array([[float(np.prod(shape[i + 1:])) for i in range(k)]])
    flat = g.where(ok, g.mm(g.const(strides), K), g.const(0.0))
    byte = g.op("Floor", g.mul(flat, g.const(0.125)))
    shift = g.sub(g.add(g.mul(byte, g.const(8.0)), g.const(7.0)), flat)          # 7 - j % 8
    b = g.op("GatherElements", g.const(bits, "occupancy", np.uint8),
             g.reshape(g.op("Cast", byte, to=TensorProto.INT32), [-1]), axis=0)
    b = g.op("BitShift", b, g.reshape(g.op("Cast", shift, to=TensorProto.UINT8), [-1]),
             direction="RIGHT")
    b = g.op("BitShift", b, g.const(np.array([7], np.uint8), dtype=np.uint8), direction="LEFT")
    return g.op("And", ok, g.reshape(g.op("Cast", b, to=TensorProto.BOOL), [1, -1]))
