"""trace_from_sensor on forward_fast.onnx: the rendering path of a learned lens.

All of the trace but the aperture shapes happens in one graph, batch by batch on worker
threads: the flight from the film to Pi_1 and the normalisation of d in float32, both stages,
both domain checks (box, occupancy cell, wavelength), the circular stop test in float64 on the
float32 stop-plane point, and the status. Rays the graph rejects at stage 1 are re-judged in
float64 (neural.domain.prepare_pi1): BAD_INPUT if the float64 test says so, and rays whose
float32 flight could be inexact (|d|^2 outside modelfile.N2_RANGE, coordinates beyond 1e30)
go through the graph again from their float64 Pi_1 ray. Results equal the forward.onnx path to
float32 rounding (the flight is float32 here, float64 there); no ensemble spread is computed.

Each worker thread owns its input and output buffers, bound to the session once (`FastIO`), so
a batch costs one copy in, one graph run and one copy out.
"""

from __future__ import annotations

import math
import os
import threading

import numpy as np

from ..core.rays import RayStatus
from .domain import prepare_pi1
from .modelfile import N2_RANGE


class FastIO:
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


class FastTracer:
    """A model's forward_fast.onnx session and the worker threads that run it."""

    def __init__(self, session, threads: int | None, planes: dict, dispersion: bool):
        self.session = session
        self._threads = threads
        self._input_z = float(planes["input_z"])
        self._output_z = float(planes["output_z"])
        self._dispersion = dispersion
        self._local = threading.local()         # per worker thread: FastIO buffers
        self._pool = None
        self._pool_lock = threading.Lock()

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

    def _fast_io(self, m: int, keep: bool) -> FastIO:
        """This thread's buffers for m rays (the full-batch set is kept)."""
        io = getattr(self._local, "fast", None)
        if io is not None and io.m == m and io.session is self.session:
            return io
        io = FastIO(self.session, m)
        if keep:
            self._local.fast = io
        return io

    def _pass(self, cols, zs, z_one, R, no_stop, aperture, batch):
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
        z_out = self._output_z
        r2 = math.inf if (no_stop or aperture is not None) else R * R
        disp = self._dispersion

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

    def trace(self, o, d, wl, zs, z_one, R, no_stop, aperture, batch):
        """Film rays (o, d (3, N), wl (N,)) on planes zs (z_one: the single plane, or None) ->
        (origins (3, N), directions (3, N), wavelengths (N,) on Pi_2, status (N,), valid (N,)),
        invalid rays zero. R: the stop radius; no_stop: no stop test; aperture: a stop shape."""
        o_out, d_out, wl_out, status, dom, valid = self._pass(
            (o[0], o[1], d[0], d[1], d[2], wl), zs, z_one, R, no_stop, aperture, batch)
        rej = np.flatnonzero((dom & 1) == 0)       # stage 1 refused: out of domain or bad
        if rej.size:
            wl_out[rej] = 0.0                       # (0 * NaN wavelength would be NaN)
            bad, p1, dn, n2 = prepare_pi1(o[:, rej], d[:, rej], wl[rej], zs[rej], self._input_z)
            status[rej[bad]] = RayStatus.BAD_INPUT
            with np.errstate(invalid="ignore"):
                big = np.maximum(np.abs(o[:2, rej]).max(axis=0),
                                 np.maximum(np.abs(zs[rej]), np.abs(p1[:2]).max(axis=0)))
                redo = ~bad & ((n2 < N2_RANGE[0]) | (n2 > N2_RANGE[1]) | (big > 1e30))
            if redo.any():                          # float32 flight may be inexact: again
                idx = rej[redo]                     # from the float64 Pi_1 ray
                cols = (p1[0][redo], p1[1][redo], dn[0][redo], dn[1][redo], dn[2][redo],
                        wl[idx])
                o2, d2, w2, s2, _, v2 = self._pass(cols, None, self._input_z,
                                                   R, no_stop, aperture, batch)
                o_out[:, idx], d_out[:, idx], wl_out[idx] = o2, d2, w2
                status[idx], valid[idx] = s2, v2
        return o_out, d_out, wl_out, status, valid
