"""Checking model.json field by field: every failure is one ModelError naming the file and the
key path (e.g. stages[0].cells[2].members[1].W2), so a broken model says where it is broken.

`Checker` reads typed fields; `check_stage` checks one stage of the schema in neural.modelfile
(bounds, occupancy grid over the frame's base columns, kd-tree, cells and their members' weight
shapes) and returns its domain guard (neural.domain). A member's full skip of degree p over
d inputs has C(d + p, p) - 1 monomials (every degree 1..p), the column count of its L.
"""

from __future__ import annotations

import base64
import binascii
import math
from pathlib import Path

import numpy as np

from ..core.errors import ModelError
from ..core.irf import RADIAL, StageFrame
from .domain import FreeSpaceGuard, StageGuard

MAX_SKIP_DEGREE = 8
MAX_SKIP_TERMS = 2000

_KIND_NAMES = {"num": "a number", "int": "an integer", "str": "a string", "bool": "true/false",
               "list": "a list", "dict": "an object"}


def is_kind(v, kind: str) -> bool:
    """Whether a JSON value is of `kind` (see _KIND_NAMES); a bool is never a number."""
    if kind == "num":
        return isinstance(v, (int, float)) and not isinstance(v, bool)
    if kind == "int":
        return isinstance(v, int) and not isinstance(v, bool)
    return isinstance(v, {"str": str, "bool": bool, "list": list, "dict": dict}[kind])


class Checker:
    """Reads model.json fields, raising ModelError that names the file and the key path."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, field: str | None, message: str):
        raise ModelError(message, path=str(self.path), field=field)

    def get(self, d, key, where: str, kind=None):
        field = f"{where}.{key}" if where else str(key)
        if not isinstance(d, dict) or key not in d:
            self.fail(field, "missing")
        v = d[key]
        if kind is not None and not is_kind(v, kind):
            self.fail(field, f"expected {_KIND_NAMES[kind]}, got {type(v).__name__} {v!r:.60}")
        if kind == "num" and not math.isfinite(v):
            self.fail(field, f"expected a finite number, got {v!r}")
        return v

    def number(self, d, key, where: str, lo: float, hi: float, unit: str = ""):
        """A finite number in [lo, hi] (its physical range)."""
        v = self.get(d, key, where, "num")
        if not lo <= v <= hi:
            self.fail(f"{where}.{key}" if where else key,
                      f"{v!r} is outside its range [{lo:g}, {hi:g}]{unit}")
        return v

    def integer(self, d, key, where: str, lo: int, hi: int):
        v = self.get(d, key, where, "int")
        if not lo <= v <= hi:
            self.fail(f"{where}.{key}" if where else key,
                      f"{v!r} is outside its range [{lo}, {hi}]")
        return v

    def array(self, v, field: str, shape: tuple) -> np.ndarray:
        try:
            a = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            self.fail(field, "expected an array of numbers")
        if a.shape != tuple(shape):
            self.fail(field, f"expected shape {tuple(shape)}, got {a.shape}")
        if not np.isfinite(a).all():
            self.fail(field, "contains NaN or infinity")
        return a


def _check_skip_terms(ck: Checker, terms, d_in: int, field: str) -> int:
    """A skip's explicit monomials: distinct non-decreasing index tuples of length 1..8 over
    the d_in inputs. Returns their count."""
    if not isinstance(terms, list) or not 1 <= len(terms) <= MAX_SKIP_TERMS:
        ck.fail(field, f"expected a list of 1..{MAX_SKIP_TERMS} index lists")
    seen = set()
    for i, t in enumerate(terms):
        ok = (isinstance(t, list) and 1 <= len(t) <= MAX_SKIP_DEGREE
              and all(is_kind(a, "int") and 0 <= a < d_in for a in t)
              and all(a <= b for a, b in zip(t, t[1:])))
        if not ok:
            ck.fail(f"{field}[{i}]", f"expected 1..{MAX_SKIP_DEGREE} non-decreasing input "
                                     f"indices in 0..{d_in - 1}, got {t!r:.60}")
        if tuple(t) in seen:
            ck.fail(f"{field}[{i}]", f"monomial {t} listed twice")
        seen.add(tuple(t))
    return len(terms)


def _check_occupancy(ck: Checker, occ, ow: str, frame: StageFrame = RADIAL):
    """(lo, hi, grid) of a stage's occupancy entry (one axis per base column of the frame)."""
    k = frame.base
    olo = ck.array(ck.get(occ, "lo", ow), ow + ".lo", (k,))
    ohi = ck.array(ck.get(occ, "hi", ow), ow + ".hi", (k,))
    if not np.all(olo < ohi):
        ck.fail(ow, f"lo {olo.tolist()} must be below hi {ohi.tolist()}")
    shape = ck.get(occ, "shape", ow, "list")
    if len(shape) != k or not all(is_kind(s, "int") and s > 0 for s in shape):
        ck.fail(ow + ".shape", f"expected {k} positive integers ({frame.name} frame), "
                               f"got {shape!r:.60}")
    bits = ck.get(occ, "bits", ow, "str")
    try:
        raw = np.frombuffer(base64.b64decode(bits, validate=True), dtype=np.uint8)
    except (binascii.Error, ValueError):
        ck.fail(ow + ".bits", "not valid base64")
    n = int(np.prod(shape))
    if raw.size != (n + 7) // 8:
        ck.fail(ow + ".bits", f"{raw.size} bytes for a {shape} grid (expected {(n + 7) // 8})")
    return olo, ohi, np.unpackbits(raw)[:n].astype(bool).reshape(shape)


def _check_tree(ck: Checker, tree, n_cells: int, d_in: int, where: str) -> None:
    """Split nodes {axis, split, left, right} and leaves {cell}, every node reached once."""
    for i, nd in enumerate(tree):
        tw = f"{where}[{i}]"
        if not isinstance(nd, dict):
            ck.fail(tw, "expected an object")
        if "cell" in nd:
            c = ck.get(nd, "cell", tw, "int")
            if not 0 <= c < n_cells:
                ck.fail(tw + ".cell", f"{c} is not a cell index (0..{n_cells - 1})")
            continue
        a = ck.get(nd, "axis", tw, "int")
        if not 0 <= a < d_in:
            ck.fail(tw + ".axis", f"{a} is not an input axis (0..{d_in - 1})")
        ck.get(nd, "split", tw, "num")
        for side in ("left", "right"):
            j = ck.get(nd, side, tw, "int")
            if not 0 < j < len(tree):
                ck.fail(f"{tw}.{side}", f"{j} is not a node index (1..{len(tree) - 1})")
    seen, todo = set(), [0]
    while todo:
        i = todo.pop()
        if i in seen:
            ck.fail(where, f"node {i} is reached twice: not a tree")
        seen.add(i)
        if "cell" not in tree[i]:
            todo += [tree[i]["left"], tree[i]["right"]]


def _check_cell(ck: Checker, cell, d_in: int, cw: str, has_wavelength: bool) -> None:
    for key, width in (("x_norm", d_in), ("y_norm", 4)):
        nrm = ck.get(cell, key, cw, "dict")
        ck.array(ck.get(nrm, "mean", f"{cw}.{key}"), f"{cw}.{key}.mean", (width,))
        sc = ck.array(ck.get(nrm, "scale", f"{cw}.{key}"), f"{cw}.{key}.scale", (width,))
        if np.any(sc == 0):
            ck.fail(f"{cw}.{key}.scale", "contains 0")
    ref = cell["x_norm"].get("wavelength_ref_nm")
    if ref is not None:
        if not has_wavelength:
            ck.fail(f"{cw}.x_norm.wavelength_ref_nm", "given, but the model has no wavelength input")
        if not is_kind(ref, "num") or not (100.0 <= float(ref) <= 10000.0):
            ck.fail(f"{cw}.x_norm.wavelength_ref_nm",
                    f"expected a wavelength in nm (100..10000), got {ref!r:.40}")
    wc = cell["x_norm"].get("w_residual_column")
    if wc is not None and (not is_kind(wc, "int") or wc != d_in - 1 - int(has_wavelength)):
        ck.fail(f"{cw}.x_norm.w_residual_column",
                f"expected the stage's w column {d_in - 1 - int(has_wavelength)}, got {wc!r:.40}")
    members = ck.get(cell, "members", cw, "list")
    if not members:
        ck.fail(cw + ".members", "no members")
    for m, mem in enumerate(members):
        mw = f"{cw}.members[{m}]"
        H = len(ck.get(mem, "b1", mw, "list"))
        if "skip_terms" in mem:
            T = _check_skip_terms(ck, mem["skip_terms"], d_in, mw + ".skip_terms")
        else:
            p = mem.get("skip_degree", 1)          # modelfile.member_terms' default
            if not is_kind(p, "int"):
                ck.fail(mw + ".skip_degree", f"expected an integer, got {p!r:.40}")
            if not 1 <= p <= MAX_SKIP_DEGREE:
                ck.fail(mw + ".skip_degree", f"must be 1..{MAX_SKIP_DEGREE}, got {p}")
            T = math.comb(d_in + p, p) - 1    # monomials of degree 1..p
        for key, shp in (("W1", (H, d_in)), ("b1", (H,)), ("W2", (H, H)), ("b2", (H,)),
                         ("W3", (4, H)), ("b3", (4,)), ("L", (4, T))):
            ck.array(ck.get(mem, key, mw), f"{mw}.{key}", shp)


def check_stage(ck: Checker, st, k: int, d_in: int, frame: StageFrame = RADIAL):
    """stages[k] of a model with d_in inputs in `frame`, checked; its domain guard."""
    where = f"stages[{k}]"
    ck.get(st, "name", where, "str")
    if isinstance(st, dict) and st.get("propagate") is True:
        return FreeSpaceGuard()
    b = ck.get(st, "bounds", where, "dict")
    for key in ("lo", "hi"):
        v = b.get(key)
        if isinstance(v, list) and len(v) != d_in:
            ck.fail(f"{where}.bounds.{key}", f"{len(v)} values, but the {frame.name} frame has "
                                             f"{d_in} inputs (is model.json's 'frame' right?)")
    lo = ck.array(ck.get(b, "lo", where + ".bounds"), where + ".bounds.lo", (d_in,))
    hi = ck.array(ck.get(b, "hi", where + ".bounds"), where + ".bounds.hi", (d_in,))
    if not np.all(lo <= hi):
        ck.fail(where + ".bounds", f"lo {lo.tolist()} exceeds hi {hi.tolist()}")
    olo, ohi, grid = _check_occupancy(ck, ck.get(st, "occupancy", where, "dict"),
                                      where + ".occupancy", frame)
    cells = ck.get(st, "cells", where, "list")
    if not cells:
        ck.fail(where + ".cells", "no cells")
    tree = ck.get(st, "tree", where, "list")
    if not tree:
        ck.fail(where + ".tree", "empty")
    _check_tree(ck, tree, len(cells), d_in, where + ".tree")
    for c, cell in enumerate(cells):
        _check_cell(ck, cell, d_in, f"{where}.cells[{c}]", d_in == frame.d_in(True))
    return StageGuard(lo, hi, olo, ohi, grid)
