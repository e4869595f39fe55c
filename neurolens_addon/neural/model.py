"""A trained learned lens: a model directory (model.json + ONNX graphs) loaded, checked and
evaluated with onnxruntime, with its learned domain guarded.

Directory `NAME.neurolens/`: model.json (schema below, every number float64) plus
forward.onnx, forward_jacobian.onnx and, in models written since it exists, forward_fast.onnx
(written by trainer.export_onnx; semantics in neural.reference). model.json keys read here:
  format "neurolens-model", version 1, lens {name, content_hash},
  planes {input_z, stop_z, output_z[, stop_radius_mm]},
  domain {film_radius_mm, sensor_z_range, wavelength_range_nm, dispersion},
  stages [rear, front] each {name, bounds {lo, hi} (d_in), occupancy {lo, hi, shape, bits},
          tree, cells [{x_norm [+ wavelength_ref_nm], y_norm,
                 members [{W1, b1, W2, b2, W3, b3, L, skip_degree or skip_terms}]}]},
  ensemble_size, theta, skip_degree, files {filename: sha256 hex} (forward_fast.onnx optional).
Unknown keys are ignored. d_in = 5 with dispersion (r, u_r, u_t, w, lambda), else 4.

Domain of a ray (every condition must hold, else the ray is flagged and its outputs are 0):
  finite components (and finite lambda with dispersion); lambda in wavelength_range_nm (with
  dispersion); for each stage, its radial-frame input X = (r, u_r, u_t, w[, lambda]) lies in
  the stage's bounds box  lo <= X <= hi  and its occupancy cell is True, where over (r, u_r, u_t)
      f = (X - lo_o) / (hi_o - lo_o),  inside iff 0 <= f <= 1,
      cell = min(floor(f * shape), shape - 1)  (per axis, C order of the packed bits).
Stage 2 is checked on stage 1's output (the ray on the stop plane).

Tracing from the sensor (`trace_from_sensor`): film points (x, y) at z = sensor_z with unit
directions d (d_z > 0) move freely to Pi_1:  x_1 = x + (z_1 - sensor_z) u / w, then the model
maps them to the stop plane, the stop is tested exactly there (x^2 + y^2 <= R^2, or a
core.aperture shape's inside(x / R, y / R)), and survivors go on to Pi_2.
Status precedence: BAD_INPUT, then OUT_OF_DOMAIN (stage 1), CLIPPED_STOP, OUT_OF_DOMAIN (stage 2).

With forward_fast.onnx (the default path) all of that but the aperture shapes happens in one
graph, batch by batch on worker threads: the flight to Pi_1 and the normalisation of d in
float32, both stages, both domain checks (box, occupancy cell, wavelength), the circular stop
test in float64 on the float32 stop-plane point, and the status. Rays the graph rejects at
stage 1 are re-judged in float64 as before: BAD_INPUT if the float64 test says so, and rays
whose float32 flight could be inexact (|d|^2 outside 1e-30..1e30, coordinates beyond 1e30)
go through the graph again from their float64 Pi_1 ray. Results equal the forward.onnx path
to float32 rounding (the flight is float32 here, float64 there); it reports no ensemble
spread (uncertainty=True takes the forward.onnx path, which does).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
import math
import os
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import ModelError
from ..core.irf import propagate_to_z
from ..core.rays import Rays, RayStatus, TraceResult
from .reference import monomial_terms

FORMAT = "neurolens-model"
VERSION = 1
MODEL_FILE = "model.json"
FORWARD_FILE = "forward.onnx"
JACOBIAN_FILE = "forward_jacobian.onnx"
FAST_FILE = "forward_fast.onnx"
DEFAULT_BATCH = 16384
FAST_BATCH = 4096           # forward_fast, 2 CPU threads: 2048-5120 within ~7 % of the best,
                            # 8192 ~20 % slower, 16384 ~30 % (two cores share one L3)
N2_RANGE = (1e-30, 1e30)    # |d|^2 forward_fast normalises in float32 (trainer.export_onnx)
_F, _D, _U8 = "tensor(float)", "tensor(double)", "tensor(uint8)"
# graph name -> (inputs, outputs), each [(name, type, shape)]; "N" / "M" are dynamic dims
_IO = {FORWARD_FILE: ([("rays", _F, ["N", 6])],
                      [("stop_rays", _F, ["N", 5]), ("out_rays", _F, ["N", 5]),
                       ("spread", _F, ["N", 2])]),
       JACOBIAN_FILE: ([("rays", _F, ["N", 6])],
                       [("stop_rays", _F, ["N", 5]), ("out_rays", _F, ["N", 5]),
                        ("spread", _F, ["N", 2]), ("jacobian", _F, ["N", 4, 4])]),
       FAST_FILE: ([("rays", _F, [6, "N"]), ("sensor_z", _F, ["M"]), ("stop_r2", _D, [1])],
                   [("stop_xy", _F, [2, "N"]), ("out_rays", _F, [5, "N"]),
                    ("in_domain", _U8, ["N"]), ("status", _U8, ["N"])])}


@dataclass
class LearnedTraceResult(TraceResult):
    """TraceResult plus each ray's ensemble spread per stage (N, 2) in mm / direction units
    (0 for invalid rays): the model's own estimate of its uncertainty."""

    uncertainty: np.ndarray = None


# ---------------------------------------------------------------- model.json checking

class _Checker:
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
        if kind is not None and not _is_kind(v, kind):
            self.fail(field, f"expected {_KIND_NAMES[kind]}, got {type(v).__name__} {v!r:.60}")
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


_KIND_NAMES = {"num": "a number", "int": "an integer", "str": "a string", "bool": "true/false",
               "list": "a list", "dict": "an object"}


def _is_kind(v, kind) -> bool:
    if kind == "num":
        return isinstance(v, (int, float)) and not isinstance(v, bool)
    if kind == "int":
        return isinstance(v, int) and not isinstance(v, bool)
    return isinstance(v, {"str": str, "bool": bool, "list": list, "dict": dict}[kind])


@dataclass
class _StageGuard:
    """A stage's learned domain: bounds box over X and occupancy grid over (r, u_r, u_t)."""

    lo: np.ndarray
    hi: np.ndarray
    occ_lo: np.ndarray
    occ_hi: np.ndarray
    grid: np.ndarray

    def __post_init__(self):
        self.all_occupied = bool(self.grid.all())
        # float32 arithmetic on float32 columns, constants rounded once (forward_fast.onnx does
        # exactly this; spelled out so numpy's casting rules cannot change it)
        shape = self.grid.shape
        self._lo32, self._hi32 = self.lo.astype(np.float32), self.hi.astype(np.float32)
        self._olo32 = self.occ_lo.astype(np.float32)
        self._sc32 = np.array([shape[i] / (self.occ_hi[i] - self.occ_lo[i]) for i in range(3)],
                              dtype=np.float32)

    def inside(self, cols) -> np.ndarray:
        """cols: the d_in columns of X (float32 1-D arrays); NaN is never inside."""
        ok = np.ones(cols[0].shape, dtype=bool)
        for c, lo, hi in zip(cols, self._lo32, self._hi32):
            ok &= c >= lo
            ok &= c <= hi
        shape = self.grid.shape
        fs = []
        for i in range(3):
            f = (cols[i] - self._olo32[i]) * self._sc32[i]
            ok &= f >= 0.0
            ok &= f <= shape[i]
            fs.append(f)
        if self.all_occupied:
            return ok
        flat = np.zeros(ok.shape, dtype=np.intp)
        for i, f in enumerate(fs):
            k = np.minimum(np.where(ok, f, 0.0), shape[i] - 1).astype(np.intp)
            flat = flat * shape[i] + k
        return ok & self.grid.ravel()[flat]


class _FreeSpaceGuard:
    """A stage with no surfaces (exact propagation) accepts every finite ray."""

    def inside(self, cols) -> np.ndarray:
        ok = np.ones(cols[0].shape, dtype=bool)
        for c in cols:
            ok &= np.isfinite(c)
        return ok


MAX_SKIP_DEGREE = 8
MAX_SKIP_TERMS = 2000


def _check_skip_terms(ck: _Checker, terms, d_in: int, field: str) -> int:
    """A skip's explicit monomials: distinct non-decreasing index tuples of length 1..8 over
    the d_in inputs. Returns their count."""
    if not isinstance(terms, list) or not 1 <= len(terms) <= MAX_SKIP_TERMS:
        ck.fail(field, f"expected a list of 1..{MAX_SKIP_TERMS} index lists")
    seen = set()
    for i, t in enumerate(terms):
        ok = (isinstance(t, list) and 1 <= len(t) <= MAX_SKIP_DEGREE
              and all(_is_kind(a, "int") and 0 <= a < d_in for a in t)
              and all(a <= b for a, b in zip(t, t[1:])))
        if not ok:
            ck.fail(f"{field}[{i}]", f"expected 1..{MAX_SKIP_DEGREE} non-decreasing input "
                                     f"indices in 0..{d_in - 1}, got {t!r:.60}")
        if tuple(t) in seen:
            ck.fail(f"{field}[{i}]", f"monomial {t} listed twice")
        seen.add(tuple(t))
    return len(terms)


def _check_stage(ck: _Checker, st, k: int, d_in: int):
    where = f"stages[{k}]"
    ck.get(st, "name", where, "str")
    if isinstance(st, dict) and st.get("propagate") is True:
        return _FreeSpaceGuard()
    b = ck.get(st, "bounds", where, "dict")
    lo = ck.array(ck.get(b, "lo", where + ".bounds"), where + ".bounds.lo", (d_in,))
    hi = ck.array(ck.get(b, "hi", where + ".bounds"), where + ".bounds.hi", (d_in,))
    if not np.all(lo <= hi):
        ck.fail(where + ".bounds", f"lo {lo.tolist()} exceeds hi {hi.tolist()}")
    occ = ck.get(st, "occupancy", where, "dict")
    ow = where + ".occupancy"
    olo = ck.array(ck.get(occ, "lo", ow), ow + ".lo", (3,))
    ohi = ck.array(ck.get(occ, "hi", ow), ow + ".hi", (3,))
    if not np.all(olo < ohi):
        ck.fail(ow, f"lo {olo.tolist()} must be below hi {ohi.tolist()}")
    shape = ck.get(occ, "shape", ow, "list")
    if len(shape) != 3 or not all(_is_kind(s, "int") and s > 0 for s in shape):
        ck.fail(ow + ".shape", f"expected 3 positive integers, got {shape!r:.60}")
    bits = ck.get(occ, "bits", ow, "str")
    try:
        raw = np.frombuffer(base64.b64decode(bits, validate=True), dtype=np.uint8)
    except (binascii.Error, ValueError):
        ck.fail(ow + ".bits", "not valid base64")
    n = int(np.prod(shape))
    if raw.size != (n + 7) // 8:
        ck.fail(ow + ".bits", f"{raw.size} bytes for a {shape} grid (expected {(n + 7) // 8})")
    grid = np.unpackbits(raw)[:n].astype(bool).reshape(shape)

    cells = ck.get(st, "cells", where, "list")
    if not cells:
        ck.fail(where + ".cells", "no cells")
    tree = ck.get(st, "tree", where, "list")
    if not tree:
        ck.fail(where + ".tree", "empty")
    for i, nd in enumerate(tree):
        tw = f"{where}.tree[{i}]"
        if not isinstance(nd, dict):
            ck.fail(tw, "expected an object")
        if "cell" in nd:
            c = ck.get(nd, "cell", tw, "int")
            if not 0 <= c < len(cells):
                ck.fail(tw + ".cell", f"{c} is not a cell index (0..{len(cells) - 1})")
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
    while todo:                                   # every node reached once from the root
        i = todo.pop()
        if i in seen:
            ck.fail(where + ".tree", f"node {i} is reached twice: not a tree")
        seen.add(i)
        if "cell" not in tree[i]:
            todo += [tree[i]["left"], tree[i]["right"]]
    for c, cell in enumerate(cells):
        cw = f"{where}.cells[{c}]"
        for key, width in (("x_norm", d_in), ("y_norm", 4)):
            nrm = ck.get(cell, key, cw, "dict")
            ck.array(ck.get(nrm, "mean", f"{cw}.{key}"), f"{cw}.{key}.mean", (width,))
            sc = ck.array(ck.get(nrm, "scale", f"{cw}.{key}"), f"{cw}.{key}.scale", (width,))
            if np.any(sc == 0):
                ck.fail(f"{cw}.{key}.scale", "contains 0")
        ref = cell["x_norm"].get("wavelength_ref_nm")
        if ref is not None:
            if d_in != 5:
                ck.fail(f"{cw}.x_norm.wavelength_ref_nm", "given, but the model has no wavelength input")
            if not _is_kind(ref, "num") or not (100.0 <= float(ref) <= 10000.0):
                ck.fail(f"{cw}.x_norm.wavelength_ref_nm",
                        f"expected a wavelength in nm (100..10000), got {ref!r:.40}")
        members = ck.get(cell, "members", cw, "list")
        if not members:
            ck.fail(cw + ".members", "no members")
        for m, mem in enumerate(members):
            mw = f"{cw}.members[{m}]"
            H = len(ck.get(mem, "b1", mw, "list"))
            if "skip_terms" in mem:
                T = _check_skip_terms(ck, mem["skip_terms"], d_in, mw + ".skip_terms")
            else:
                p = mem.get("skip_degree", 1)          # neural.reference's default
                if not _is_kind(p, "int"):
                    ck.fail(mw + ".skip_degree", f"expected an integer, got {p!r:.40}")
                if not 1 <= p <= MAX_SKIP_DEGREE:
                    ck.fail(mw + ".skip_degree", f"must be 1..{MAX_SKIP_DEGREE}, got {p}")
                T = len(monomial_terms(d_in, p))
            for key, shp in (("W1", (H, d_in)), ("b1", (H,)), ("W2", (H, H)), ("b2", (H,)),
                             ("W3", (4, H)), ("b3", (4,)), ("L", (4, T))):
                ck.array(ck.get(mem, key, mw), f"{mw}.{key}", shp)
    return _StageGuard(lo, hi, olo, ohi, grid)


def _check_meta(ck: _Checker, meta) -> tuple[list[_StageGuard], dict]:
    if not isinstance(meta, dict):
        ck.fail(None, "expected a JSON object")
    fmt = meta.get("format")
    if fmt != FORMAT:
        ck.fail("format", f"expected '{FORMAT}', got {fmt!r}: not a NeuroLens model")
    ver = meta.get("version")
    if ver != VERSION:
        ck.fail("version", f"version {ver!r} is not supported (this add-on reads {VERSION})")
    lens = ck.get(meta, "lens", "", "dict")
    ck.get(lens, "name", "lens", "str")
    ck.get(lens, "content_hash", "lens", "str")
    planes = ck.get(meta, "planes", "", "dict")
    for k in ("input_z", "stop_z", "output_z"):
        ck.get(planes, k, "planes", "num")
    if planes.get("stop_radius_mm") is not None:       # null: no stop (a ray-table model)
        r = ck.get(planes, "stop_radius_mm", "planes", "num")
        if not r > 0:
            ck.fail("planes.stop_radius_mm", f"must be > 0, got {r}")
    dom = ck.get(meta, "domain", "", "dict")
    ck.get(dom, "film_radius_mm", "domain", "num")
    ck.array(ck.get(dom, "sensor_z_range", "domain"), "domain.sensor_z_range", (2,))
    wl = ck.array(ck.get(dom, "wavelength_range_nm", "domain"), "domain.wavelength_range_nm",
                  (2,))
    if wl[0] > wl[1]:
        ck.fail("domain.wavelength_range_nm", f"{wl.tolist()} is not increasing")
    disp = ck.get(dom, "dispersion", "domain", "bool")
    for key in ("stop_radius_mm", "film_radius_min_mm"):
        if key in dom:
            v = ck.get(dom, key, "domain", "num")
            if not (math.isfinite(v) and v >= 0 and (v > 0 or key != "stop_radius_mm")):
                ck.fail("domain." + key, f"expected a finite positive number of mm, got {v!r}")
    for k in ("ensemble_size", "theta", "skip_degree"):
        ck.get(meta, k, "", "int")
    stages = ck.get(meta, "stages", "", "list")
    if len(stages) != 2:
        ck.fail("stages", f"expected 2 stages (rear, front), got {len(stages)}")
    d_in = 5 if disp else 4
    guards = [_check_stage(ck, st, k, d_in) for k, st in enumerate(stages)]
    files = ck.get(meta, "files", "", "dict")
    for f in (FORWARD_FILE, JACOBIAN_FILE) + ((FAST_FILE,) if FAST_FILE in files else ()):
        h = ck.get(files, f, "files", "str")
        if len(h) != 64 or any(ch not in "0123456789abcdef" for ch in h.lower()):
            ck.fail(f"files.{f}", f"expected a sha256 hex digest, got {h!r:.70}")
    return guards, files


# ---------------------------------------------------------------- runtime

def _providers(requested) -> list[str]:
    import onnxruntime as ort
    if requested is not None:
        return list(requested)
    avail = ort.get_available_providers()
    return (["CUDAExecutionProvider"] if "CUDAExecutionProvider" in avail else []) + \
        ["CPUExecutionProvider"]


def _radial_inputs(x, y, u, v, w, lam, dispersion: bool) -> list[np.ndarray]:
    """Columns of the stage input X = (r, u_r, u_t, w[, lambda]); phi = 0 at r = 0."""
    r = np.sqrt(x * x + y * y)
    zero = r == 0
    rs = np.where(zero, 1.0, r)
    c = x / rs + zero
    s = y / rs
    return [r, c * u + s * v, c * v - s * u, w] + ([lam] if dispersion else [])


class LearnedLens:
    """A loaded model: `evaluate` rays on Pi_1, or `trace_from_sensor` like core.trace."""

    def __init__(self, directory: Path, meta: dict, guards, files: dict, session, providers,
                 threads, lens=None, fast_session=None):
        self.directory = directory
        self.meta = meta
        self._guards = guards
        self._files = files
        self._session = session
        self._jac_session = None
        self._fast_session = fast_session
        self._providers = providers
        self._threads = threads
        self._lens = lens
        self._local = threading.local()         # per worker thread: _FastIO buffers
        self._pool = None
        self._pool_lock = threading.Lock()

    # -- loading

    @classmethod
    def load(cls, directory, lens=None, providers=None, threads: int | None = None
             ) -> "LearnedLens":
        """Read and check a model directory (or its model.json); ModelError when unusable.

        lens: a core.prescription.Lens the caller means to simulate; refused when the model was
        trained for another prescription. providers: onnxruntime providers (default CUDA when
        available, then CPU). threads: onnxruntime intra-op threads of forward.onnx (default:
        its own choice), and the number of worker threads trace_from_sensor runs
        forward_fast.onnx batches on, one onnxruntime thread each (default: os.cpu_count())."""
        directory, meta, guards, files = read_model_json(directory, lens)
        fast = FAST_FILE in files
        for f in (FORWARD_FILE, JACOBIAN_FILE) + ((FAST_FILE,) if fast else ()):
            _verify_file(directory / f, files[f])
        prov = _providers(providers)
        session = _open_session(directory / FORWARD_FILE, prov, threads)
        fast_session = _open_session(directory / FAST_FILE, prov, 1) if fast else None
        return cls(directory, meta, guards, files, session, prov, threads, lens, fast_session)

    # -- properties

    @property
    def name(self) -> str:
        return self.directory.name

    @property
    def lens_name(self) -> str:
        return self.meta["lens"]["name"]

    @property
    def planes(self) -> dict:
        return self.meta["planes"]

    @property
    def domain(self) -> dict:
        return self.meta["domain"]

    @property
    def dispersion(self) -> bool:
        return bool(self.meta["domain"]["dispersion"])

    @property
    def has_fast_graph(self) -> bool:
        """Whether the model ships forward_fast.onnx (trace_from_sensor's default path)."""
        return self._fast_session is not None

    @property
    def provider(self) -> str:
        """The execution provider onnxruntime actually uses (first of the session's list)."""
        return self._session.get_providers()[0]

    @property
    def stop_radius_mm(self) -> float | None:
        """The design's full-aperture stop radius (model.json, else the lens given to load)."""
        r = self.meta["planes"].get("stop_radius_mm")
        if r is None and self._lens is not None:
            r = self._lens.stop_radius_mm
        return None if r is None else float(r)

    def _jacobian_session(self):
        if self._jac_session is None:
            path = self.directory / JACOBIAN_FILE
            _verify_file(path, self._files[JACOBIAN_FILE])
            self._jac_session = _open_session(path, self._providers, self._threads)
        return self._jac_session

    # -- evaluation

    def _sanitise(self, rays: np.ndarray):
        """Stage-1 domain of (n, 6) rays, judged on the float32 rays the graph will see, and
        that graph input (rays outside the domain replaced by the on-axis ray, so no NaN/inf
        enters the graph). The bounds are finite, so a NaN or inf in x, y, u, v or w always
        makes r, u_r, u_t or w fail the box: no separate finiteness pass is needed."""
        with np.errstate(over="ignore"):             # beyond float32: inf, out of domain
            inp = rays.astype(np.float32)
        cols = np.ascontiguousarray(inp.T)
        with np.errstate(invalid="ignore", over="ignore"):
            ok = self._guards[0].inside(_radial_inputs(*cols, self.dispersion))
            if self.dispersion:
                lo, hi = self.domain["wavelength_range_nm"]
                ok &= (cols[5] >= lo) & (cols[5] <= hi)
        if not ok.all():
            inp[~ok] = [0, 0, 0, 0, 1, 0.5 * sum(self.domain["wavelength_range_nm"])]
        return ok, inp

    def _run(self, rays: np.ndarray, jacobian: bool, batch: int):
        """Stream batches through the session: outputs float32, zeroed outside the domain,
        and the per-stage domain masks (N, 2)."""
        rays = np.asarray(rays, dtype=np.float64)
        if rays.ndim != 2 or rays.shape[1] != 6:
            raise ValueError(f"expected an (N, 6) array of x, y, u, v, w, lambda rays, "
                             f"got shape {rays.shape}")
        if batch < 1:
            raise ValueError(f"batch must be >= 1, got {batch}")
        n = rays.shape[0]
        sess = self._jacobian_session() if jacobian else self._session
        if jacobian:              # 4 tangents ride along: a quarter of the rays per batch
            batch = max(1, batch // 4)
        outs = [np.empty((n, 5), np.float32), np.empty((n, 5), np.float32),
                np.empty((n, 2), np.float32)] + ([np.empty((n, 4, 4), np.float32)]
                                                  if jacobian else [])
        dom = np.empty((n, 2), bool)
        disp = self.dispersion
        for lo in range(0, n, batch):
            hi = min(lo + batch, n)
            ok1, inp = self._sanitise(rays[lo:hi])
            # onnxruntime writes straight into the (contiguous) output rows
            io = sess.io_binding()
            io.bind_cpu_input("rays", inp)
            for (name, _, _), o in zip(_IO[JACOBIAN_FILE if jacobian else FORWARD_FILE][1], outs):
                view = o[lo:hi]
                io.bind_output(name, "cpu", 0, np.float32, list(view.shape), view.ctypes.data)
            sess.run_with_iobinding(io)
            c1 = np.ascontiguousarray(outs[0][lo:hi].T)
            with np.errstate(invalid="ignore", over="ignore"):
                # finite, in-box inputs give finite outputs (tanh, bounded polynomial, guarded
                # sqrt), so stage 2 needs only its own box and occupancy
                ok2 = ok1 & self._guards[1].inside(_radial_inputs(*c1, inp[:, 5], disp))
            dom[lo:hi, 0], dom[lo:hi, 1] = ok1, ok2
        ok1, ok2 = dom[:, 0], dom[:, 1]
        if not ok2.all():
            outs[0][~ok1] = 0.0
            outs[2][~ok1, 0] = 0.0
            for o in outs[1:2] + outs[3:]:
                o[~ok2] = 0.0
            outs[2][~ok2, 1] = 0.0
        return outs[0], outs[1], outs[2], dom, (outs[3] if jacobian else None)

    def evaluate(self, rays_pi1: np.ndarray, jacobian: bool = False,
                 batch: int = DEFAULT_BATCH):
        """Rays (N, 6) = (x, y, u, v, w, lambda) on Pi_1 ->
        (stop_rays (N, 5), out_rays (N, 5), spread (N, 2), in_domain (N,) bool), all float32
        but the mask, out-of-domain rows zero; with jacobian=True also the (N, 4, 4) Jacobian
        d(x', y', u', v' on Pi_2) / d(x, y, u, v on Pi_1) (trainer.export_onnx defines it).
        Rays go through in batches of `batch` (batch / 4 for the Jacobian graph, whose
        tangents make each ray ~5x the work and memory), so memory stays bounded for any N."""
        stop, out, spread, dom, jac = self._run(rays_pi1, jacobian, batch)
        in_domain = dom[:, 1]
        # a ray whose stop-plane ray is fine but which leaves the domain in stage 2 keeps
        # nothing: in_domain means the whole model applies
        stop[~in_domain] = 0.0
        spread[~in_domain] = 0.0
        return (stop, out, spread, in_domain) + ((jac,) if jacobian else ())

    def trace_from_sensor(self, rays: Rays, sensor_z, stop_radius: float | None = None,
                          aperture=None, batch: int | None = None,
                          uncertainty: bool = False) -> LearnedTraceResult:
        """Rays from the film (origins' x, y on the sensor plane z = sensor_z, whatever o[2]
        says; directions toward +z, normalised here) through the learned lens to Pi_2.
        sensor_z: one plane for all rays, or an (N,) array, one per ray.

        stop_radius: the aperture-stop radius in mm (None: the design's full aperture);
        aperture: a core.aperture shape tested at (x / R, y / R) on the stop plane (None:
        circular). Result like core.trace.trace (origins on Pi_2, invalid rays all zero) plus
        `uncertainty` (N, 2), the ensemble spread of each stage, when uncertainty=True or the
        model has no forward_fast.onnx (forward.onnx path); otherwise None (forward_fast.onnx,
        several times faster, computes no spread). batch: rays per onnxruntime call (default
        FAST_BATCH, or DEFAULT_BATCH on the forward.onnx path)."""
        o = np.asarray(rays.o, dtype=np.float64)
        d = np.asarray(rays.d, dtype=np.float64)
        wl = np.asarray(rays.wavelength, dtype=np.float64).reshape(-1)
        if o.ndim != 2 or o.shape[0] != 3 or d.shape != o.shape or wl.shape[0] != o.shape[1]:
            raise ValueError(f"inconsistent ray arrays: o {o.shape}, d {d.shape}, "
                             f"wavelength {wl.shape}")
        n = o.shape[1]
        no_stop = ("stop_radius_mm" in self.meta["planes"]
                   and self.meta["planes"]["stop_radius_mm"] is None and stop_radius is None)
        trained = self.meta["domain"].get("stop_radius_mm")
        R = self.stop_radius_mm if stop_radius is None else float(stop_radius)
        if stop_radius is None and trained is not None and R is not None:
            R = min(R, float(trained))
        if trained is not None and R is not None and R > float(trained) * (1.0 + 1e-9):
            raise ModelError(f"this model was trained for stop radii up to {trained:.4g} mm "
                             f"(the scene's widest f-number); asked for {R:.4g} mm: choose "
                             "a model trained for this aperture or the exact lens",
                             path=str(self.directory / MODEL_FILE), field="domain.stop_radius_mm")
        if no_stop:
            R = math.inf
        elif R is None:
            raise ModelError("model.json gives no planes.stop_radius_mm: pass stop_radius or "
                             "load the model with its lens", path=str(self.directory / MODEL_FILE),
                             field="planes.stop_radius_mm")
        if not (R > 0) or (math.isinf(R) and not no_stop) or math.isnan(R):
            raise ValueError(f"stop_radius must be a positive number of mm, got {R}")
        z = np.asarray(sensor_z, dtype=np.float64)
        try:
            zs = np.broadcast_to(z, (n,))
        except ValueError:
            raise ValueError(f"sensor_z must be a number or one per ray ({n}), got shape "
                             f"{np.shape(sensor_z)}") from None
        if batch is not None and batch < 1:
            raise ValueError(f"batch must be >= 1, got {batch}")
        if uncertainty or self._fast_session is None:
            return self._trace_forward(o, d, wl, zs, R, no_stop, aperture, batch or DEFAULT_BATCH)
        z_one = float(z.reshape(-1)[0]) if z.size == 1 else None
        return self._trace_fast(o, d, wl, zs, z_one, R, no_stop, aperture, batch or FAST_BATCH)

    # -- forward_fast.onnx path

    def _workers(self) -> int:
        return max(1, int(self._threads) if self._threads else (os.cpu_count() or 1))

    def _map(self, fn, count: int):
        """fn(i) for i in range(count), on the worker threads when there is more than one: each
        worker takes the next i from a shared iterator (balanced, one task per worker)."""
        workers = min(self._workers(), count)
        if workers <= 1:
            for i in range(count):
                fn(i)
            return
        with self._pool_lock:
            if self._pool is None or self._pool._max_workers < workers:
                from concurrent.futures import ThreadPoolExecutor
                self._pool = ThreadPoolExecutor(workers, thread_name_prefix="neurolens")
        items = iter(range(count))              # next() on it is atomic under the GIL

        def loop():
            for i in items:
                fn(i)
        for f in [self._pool.submit(loop) for _ in range(workers)]:
            f.result()

    def _fast_io(self, m: int, keep: bool) -> "_FastIO":
        """This thread's forward_fast buffers for m rays (the full-batch set is kept)."""
        io = getattr(self._local, "fast", None)
        if io is not None and io.m == m and io.session is self._fast_session:
            return io
        io = _FastIO(self._fast_session, m)
        if keep:
            self._local.fast = io
        return io

    def _fast_pass(self, cols, zs, z_one, R, no_stop, aperture, batch):
        """forward_fast.onnx over the rays cols = (x, y, dx, dy, dz, wavelength) on planes zs
        (z_one: the single plane, or None): (origins (3, N) and directions (3, N) on Pi_2,
        wavelength (N,), status (N,) uint8, in_domain (N,) uint8, valid (N,)), invalid rays
        zero. (Two (3, N) arrays, not one (6, N): below glibc's 32 MB mmap limit up to ~1.4 M
        rays, a repeated call reuses heap pages instead of faulting in fresh zeroed ones.)"""
        n = cols[0].shape[0]
        o_out, d_out = np.empty((3, n)), np.empty((3, n))
        rows = (o_out[0], o_out[1], d_out[0], d_out[1], d_out[2])
        wl_out = np.empty(n)
        status = np.empty(n, np.uint8)
        dom = np.empty(n, np.uint8)
        valid_all = np.empty(n, bool)
        z_out = float(self.planes["output_z"])
        r2 = math.inf if (no_stop or aperture is not None) else R * R
        disp = self.dispersion

        def work(i):
            lo = i * batch
            hi = min(lo + batch, n)
            io = self._fast_io(hi - lo, keep=hi - lo == batch)
            with np.errstate(over="ignore", invalid="ignore"):    # beyond float32: inf, refused
                for k in range(6):
                    np.copyto(io.rays[k], cols[k][lo:hi], casting="same_kind")
                io.set_planes(z_one if z_one is not None else zs[lo:hi], r2)
            io.run()
            st = io.status
            if not disp:                   # lambda unused, but a NaN / inf one is BAD_INPUT:
                fin = np.isfinite(cols[5][lo:hi])      # leave it to the float64 judgement
                if not fin.all():
                    io.dom[~fin], st[~fin], io.out[:, ~fin] = 0, RayStatus.OUT_OF_DOMAIN, 0.0
            if aperture is not None:       # stop shapes: tested here, on stage-1-valid rays
                sx, sy = io.stop[0].astype(np.float64), io.stop[1].astype(np.float64)
                clip = (io.dom & 1).astype(bool) & ~np.asarray(aperture.inside(sx / R, sy / R),
                                                               dtype=bool)
                if clip.any():
                    st[clip] = RayStatus.CLIPPED_STOP
                    io.out[:, clip] = 0.0
            status[lo:hi] = st
            dom[lo:hi] = io.dom
            valid = np.equal(st, 0, out=valid_all[lo:hi])
            for k in range(5):
                np.copyto(rows[k][lo:hi], io.out[k], casting="same_kind")
            np.multiply(valid, z_out, out=o_out[2, lo:hi])
            with np.errstate(invalid="ignore"):     # inf * 0: refused rays, zeroed later
                np.multiply(cols[5][lo:hi], valid, out=wl_out[lo:hi])

        self._map(work, -(-n // batch))
        return o_out, d_out, wl_out, status, dom, valid_all

    def _trace_fast(self, o, d, wl, zs, z_one, R, no_stop, aperture, batch):
        n = o.shape[1]
        o_out, d_out, wl_out, status, dom, valid = self._fast_pass(
            (o[0], o[1], d[0], d[1], d[2], wl), zs, z_one, R, no_stop, aperture, batch)
        rej = np.flatnonzero((dom & 1) == 0)       # stage 1 refused: out of domain or bad
        if rej.size:
            wl_out[rej] = 0.0                       # (0 * NaN wavelength would be NaN)
            bad, p1, dn, n2 = _prepare_pi1(o[:, rej], d[:, rej], wl[rej], zs[rej],
                                           float(self.planes["input_z"]))
            status[rej[bad]] = RayStatus.BAD_INPUT
            with np.errstate(invalid="ignore"):
                big = np.maximum(np.abs(o[:2, rej]).max(axis=0),
                                 np.maximum(np.abs(zs[rej]), np.abs(p1[:2]).max(axis=0)))
                redo = ~bad & ((n2 < N2_RANGE[0]) | (n2 > N2_RANGE[1]) | (big > 1e30))
            if redo.any():                          # float32 flight may be inexact: again
                idx = rej[redo]                     # from the float64 Pi_1 ray
                cols = (p1[0][redo], p1[1][redo], dn[0][redo], dn[1][redo], dn[2][redo],
                        wl[idx])
                o2, d2, w2, s2, _, v2 = self._fast_pass(cols, None, float(self.planes["input_z"]),
                                                        R, no_stop, aperture, batch)
                o_out[:, idx], d_out[:, idx], wl_out[idx] = o2, d2, w2
                status[idx], valid[idx] = s2, v2
        surface = np.full(n, -1, np.int16)
        if self._lens is not None:
            surface[status == RayStatus.CLIPPED_STOP] = self._lens.stop_index
        return LearnedTraceResult(Rays(o_out, d_out, wl_out), valid, status, surface)

    # -- forward.onnx path

    def _trace_forward(self, o, d, wl, zs, R, no_stop, aperture, batch) -> LearnedTraceResult:
        n = o.shape[1]
        bad, p1, d, _ = _prepare_pi1(o, d, wl, zs, float(self.planes["input_z"]))
        rays_pi1 = np.stack([p1[0], p1[1], d[0], d[1], d[2], wl], axis=1)
        rays_pi1[bad] = 0.0
        stop, out, spread, dom, _ = self._run(rays_pi1, False, batch)
        sx, sy = stop[:, 0].astype(np.float64), stop[:, 1].astype(np.float64)
        if no_stop:
            passed = np.ones(n, dtype=bool)
        elif aperture is None:
            passed = sx * sx + sy * sy <= R * R
        else:
            passed = np.asarray(aperture.inside(sx / R, sy / R), dtype=bool)
        status = np.zeros(n, np.uint8)
        surface = np.full(n, -1, np.int16)
        clipped = ~bad & dom[:, 0] & ~passed
        status[~dom[:, 1]] = RayStatus.OUT_OF_DOMAIN
        status[clipped] = RayStatus.CLIPPED_STOP
        status[~bad & ~dom[:, 0]] = RayStatus.OUT_OF_DOMAIN
        status[bad] = RayStatus.BAD_INPUT
        if self._lens is not None:
            surface[clipped] = self._lens.stop_index
        valid = status == RayStatus.OK
        v = valid[:, None]
        out64 = np.where(v, out.astype(np.float64), 0.0)
        o_out = np.stack([out64[:, 0], out64[:, 1],
                          np.where(valid, float(self.planes["output_z"]), 0.0)])
        d_out = np.ascontiguousarray(out64[:, 2:5].T)
        return LearnedTraceResult(Rays(o_out, d_out, np.where(valid, wl, 0.0)), valid, status,
                                  surface, np.where(v, spread.astype(np.float64), 0.0))


def _prepare_pi1(o, d, wl, zs, input_z: float):
    """The float64 film -> Pi_1 flight of trace_from_sensor: (bad (N,), Pi_1 origins (3, N),
    unit directions (3, N), |d|^2 (N,)). bad: a NaN/inf component, a zero or infinite
    direction, d_z <= 0 after normalising, or no finite Pi_1 point. o, d are not modified."""
    o = np.array(o, dtype=np.float64)
    d = np.array(d, dtype=np.float64)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        n2 = (d * d).sum(axis=0)
        norm = np.sqrt(n2)
        bad = ~(np.isfinite(o[:2]).all(axis=0) & np.isfinite(d).all(axis=0) & (norm > 0)
                & np.isfinite(norm) & np.isfinite(wl) & np.isfinite(zs))
        d /= np.where(bad, 1.0, norm)
        bad |= ~(d[2] > 0.0)
        o[2] = zs
        p1 = propagate_to_z(o, d, input_z)
    bad |= ~np.isfinite(p1[:2]).all(axis=0)
    return bad, p1, d, n2


class _FastIO:
    """One worker thread's forward_fast.onnx buffers for batches of m rays, bound once."""

    def __init__(self, session, m: int):
        self.session, self.m = session, m
        self.rays = np.empty((6, m), np.float32)
        self.zs = np.empty(m, np.float32)
        self.r2 = np.empty(1, np.float64)
        self.stop = np.empty((2, m), np.float32)
        self.out = np.empty((5, m), np.float32)
        self.dom = np.empty(m, np.uint8)
        self.status = np.empty(m, np.uint8)
        self._zs_len = None
        io = self.io = session.io_binding()
        io.bind_input("rays", "cpu", 0, np.float32, [6, m], self.rays.ctypes.data)
        io.bind_input("stop_r2", "cpu", 0, np.float64, [1], self.r2.ctypes.data)
        for name, a in (("stop_xy", self.stop), ("out_rays", self.out), ("in_domain", self.dom),
                        ("status", self.status)):
            io.bind_output(name, "cpu", 0, a.dtype, list(a.shape), a.ctypes.data)

    def set_planes(self, zs, r2: float):
        """zs: one sensor plane (float) or this batch's (m,) planes."""
        k = 1 if isinstance(zs, float) else self.m
        if k == 1:
            self.zs[0] = zs
        else:
            np.copyto(self.zs, zs, casting="same_kind")
        if self._zs_len != k:
            self.io.bind_input("sensor_z", "cpu", 0, np.float32, [k], self.zs.ctypes.data)
            self._zs_len = k
        self.r2[0] = r2

    def run(self):
        self.session.run_with_iobinding(self.io)


def _verify_file(path: Path, sha256: str) -> None:
    try:
        data = path.read_bytes()
    except OSError as e:
        raise ModelError(f"cannot read the ONNX graph: {e.strerror or e}", path=str(path)) from None
    have = hashlib.sha256(data).hexdigest()
    if have != sha256.lower():
        raise ModelError(f"sha256 {have[:16]}... does not match model.json's {sha256[:16]}...: "
                         "the file is truncated, corrupted or belongs to another model",
                         path=str(path))


def read_model_json(directory, lens=None):
    """(directory, meta, stage guards, files) of a model directory (or its model.json),
    schema-checked, and refused when `lens` is given and the model was trained for another
    prescription. Reads only model.json: needs neither onnxruntime nor the graphs."""
    directory = Path(directory)
    if directory.is_file() and directory.name == MODEL_FILE:
        directory = directory.parent
    path = directory / MODEL_FILE
    if not path.is_file():
        raise ModelError(f"no {MODEL_FILE} in the model directory", path=str(directory))
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise ModelError(f"not valid JSON (line {e.lineno}, column {e.colno}: {e.msg})",
                         path=str(path)) from None
    except (OSError, UnicodeDecodeError) as e:
        raise ModelError(f"cannot read: {e}", path=str(path)) from None
    guards, files = _check_meta(_Checker(path), meta)
    if lens is not None:
        want, have = meta["lens"]["content_hash"], lens.content_hash()
        if want != have:
            raise ModelError(
                f"model '{directory.name}' was trained for lens '{meta['lens']['name']}' "
                f"(hash {want}), not '{lens.name}' (hash {have})", path=str(path),
                field="lens.content_hash")
    return directory, meta, guards, files


def _open_session(path: Path, providers, threads):
    import onnxruntime as ort
    so = ort.SessionOptions()
    if threads is not None:
        so.intra_op_num_threads = int(threads)
    so.inter_op_num_threads = 1
    # no busy-waiting between runs: a renderer interleaves lens batches with its own work
    # (scene ray casts), which spinning onnxruntime threads would slow down
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.log_severity_level = 3
    try:
        sess = ort.InferenceSession(str(path), so, providers=providers)
    except Exception as e:  # onnxruntime raises its own exception types
        raise ModelError(f"onnxruntime cannot load the graph: {str(e).strip()[:300]}",
                         path=str(path)) from None
    want_in, want_out = _IO[path.name]
    ins, outs = sess.get_inputs(), sess.get_outputs()
    got_in, got_out = [i.name for i in ins], [o.name for o in outs]
    if got_in != [w[0] for w in want_in] or got_out != [w[0] for w in want_out]:
        raise ModelError(f"graph inputs {got_in} / outputs {got_out}, expected "
                         f"{[w[0] for w in want_in]} / {[w[0] for w in want_out]}", path=str(path))
    problems = []
    for kind, have, want in (("input", ins, want_in), ("output", outs, want_out)):
        for a, (name, typ, shape) in zip(have, want):
            ok = a.type == typ and len(a.shape) == len(shape) and all(
                isinstance(s, str) or s == h for s, h in zip(shape, a.shape))
            if not ok:
                problems.append(f"{kind} {name} is {a.type} {a.shape}, expected "
                                f"{typ.replace('tensor(', '').rstrip(')')} "
                                f"[{', '.join(map(str, shape))}]")
    if problems:
        raise ModelError("; ".join(problems), path=str(path))
    return sess
