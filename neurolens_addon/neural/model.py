"""A trained learned lens loaded for use: a model directory (neural.modelfile) checked, its
graphs opened with onnxruntime (neural.session), and rays evaluated with the learned domain
guarded (neural.domain).

`LearnedLens.evaluate` runs forward.onnx (or forward_jacobian.onnx) on rays on Pi_1, streaming
bounded batches; each stage's domain is judged on the float32 rays the graph sees, and rays
outside it are replaced by the on-axis ray before they enter the graph and zeroed after.

`LearnedLens.trace_from_sensor` traces film rays like core.trace: film points (x, y) at
z = sensor_z with unit directions d (d_z > 0) move freely to Pi_1,
x_1 = x + (z_1 - sensor_z) u / w, the model maps them to the stop plane, the stop is tested
exactly there (x^2 + y^2 <= R^2, or a core.aperture shape's inside(x / R, y / R)), and survivors
go on to Pi_2. Status precedence: BAD_INPUT, then OUT_OF_DOMAIN (stage 1), CLIPPED_STOP,
OUT_OF_DOMAIN (stage 2). With forward_fast.onnx (the default) it runs on neural.fastpath; with
uncertainty=True, or a model without that graph, on forward.onnx, which also reports each
ray's ensemble spread.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import ModelError
from ..core.rays import Rays, RayStatus, TraceResult
from ..core.irf import model_frames
from .domain import frame_inputs, prepare_pi1
from .fastpath import FastTracer
from .modelfile import (FAST_FILE, FORWARD_FILE, GRAPH_IO, JACOBIAN_FILE, MODEL_FILE,
                        read_model_json)
from .session import choose_providers, open_session, verify_file

DEFAULT_BATCH = 16384
# forward_fast.onnx batch: small enough for a batch's buffers to stay in the cache two cores
# share (docs/learned-graphs.md has the measurements)
FAST_BATCH = 4096

# read_model_json and the file names are neural.modelfile's, importable here as before
__all__ = ["DEFAULT_BATCH", "FAST_BATCH", "FAST_FILE", "FORWARD_FILE", "JACOBIAN_FILE",
           "MODEL_FILE", "LearnedLens", "LearnedTraceResult", "read_model_json"]


@dataclass
class LearnedTraceResult(TraceResult):
    """TraceResult plus each ray's ensemble spread per stage (N, 2) in mm / direction units
    (0 for invalid rays): the model's own estimate of its uncertainty."""

    uncertainty: np.ndarray = None


class LearnedLens:
    """A loaded model: `evaluate` rays on Pi_1, or `trace_from_sensor` like core.trace."""

    def __init__(self, directory: Path, meta: dict, guards, files: dict, session, providers,
                 threads, lens=None, fast_session=None):
        self.directory = directory
        self.meta = meta
        self.frames = model_frames(meta)        # core.irf: each stage's input frame
        self._guards = guards
        self._files = files
        self._session = session
        self._jac_session = None
        self._fast = None if fast_session is None else FastTracer(
            fast_session, threads, meta["planes"], bool(meta["domain"]["dispersion"]))
        self._providers = providers
        self._threads = threads
        self._lens = lens

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
        graphs = {f: verify_file(directory / f, files[f])
                  for f in (FORWARD_FILE, JACOBIAN_FILE) + ((FAST_FILE,) if fast else ())}
        prov = choose_providers(providers)
        session = open_session(directory / FORWARD_FILE, prov, threads, graphs[FORWARD_FILE])
        fast_session = (open_session(directory / FAST_FILE, prov, 1, graphs[FAST_FILE])
                        if fast else None)
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
        return self._fast is not None

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
            data = verify_file(path, self._files[JACOBIAN_FILE])
            self._jac_session = open_session(path, self._providers, self._threads, data)
        return self._jac_session

    # -- evaluation

    def _sanitise(self, rays: np.ndarray):
        """Stage-1 domain of (n, 6) rays, judged on the float32 rays the graph will see, and
        that graph input (rays outside the domain replaced by the on-axis ray, so no NaN/inf
        enters the graph). The bounds are finite, so a NaN or inf in x, y, u, v or w always
        makes the frame's columns (r, u_r, u_t or x, y, u, v) or w fail the box: no separate
        finiteness pass is needed."""
        with np.errstate(over="ignore"):             # beyond float32: inf, out of domain
            inp = rays.astype(np.float32)
        cols = np.ascontiguousarray(inp.T)
        with np.errstate(invalid="ignore", over="ignore"):
            ok = self._guards[0].inside(frame_inputs(self.frames[0], *cols, self.dispersion))
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
            graph = JACOBIAN_FILE if jacobian else FORWARD_FILE
            for (name, _, _), o in zip(GRAPH_IO[graph][1], outs):
                view = o[lo:hi]
                io.bind_output(name, "cpu", 0, np.float32, list(view.shape), view.ctypes.data)
            sess.run_with_iobinding(io)
            c1 = np.ascontiguousarray(outs[0][lo:hi].T)
            with np.errstate(invalid="ignore", over="ignore"):
                # finite, in-box inputs give finite outputs (tanh, bounded polynomial, guarded
                # sqrt), so stage 2 needs only its own box and occupancy
                ok2 = ok1 & self._guards[1].inside(frame_inputs(self.frames[1], *c1, inp[:, 5],
                                                                disp))
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
        d(x', y', u', v' on Pi_2) / d(x, y, u, v on Pi_1) (onnx_export.forward defines it).
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
        if uncertainty or self._fast is None:
            return self._trace_forward(o, d, wl, zs, R, no_stop, aperture, batch or DEFAULT_BATCH)
        z_one = float(z.reshape(-1)[0]) if z.size == 1 else None
        return self._result(*self._fast.trace(o, d, wl, zs, z_one, R, no_stop, aperture,
                                              batch or FAST_BATCH))

    def _result(self, o, d, wl, status, valid, spread=None) -> LearnedTraceResult:
        """The trace result of rays on Pi_2; a ray clipped by the stop names its surface."""
        surface = np.full(status.shape[0], -1, np.int16)
        if self._lens is not None:
            surface[status == RayStatus.CLIPPED_STOP] = self._lens.stop_index
        return LearnedTraceResult(Rays(o, d, wl), valid, status, surface, uncertainty=spread)

    def _trace_forward(self, o, d, wl, zs, R, no_stop, aperture, batch) -> LearnedTraceResult:
        """trace_from_sensor on forward.onnx: the float64 flight to Pi_1, the graph, the stop
        tested in float64 on the float32 stop-plane point; with each stage's spread."""
        n = o.shape[1]
        bad, p1, d, _ = prepare_pi1(o, d, wl, zs, float(self.planes["input_z"]))
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
        clipped = ~bad & dom[:, 0] & ~passed
        status[~dom[:, 1]] = RayStatus.OUT_OF_DOMAIN
        status[clipped] = RayStatus.CLIPPED_STOP
        status[~bad & ~dom[:, 0]] = RayStatus.OUT_OF_DOMAIN
        status[bad] = RayStatus.BAD_INPUT
        valid = status == RayStatus.OK
        v = valid[:, None]
        out64 = np.where(v, out.astype(np.float64), 0.0)
        o_out = np.stack([out64[:, 0], out64[:, 1],
                          np.where(valid, float(self.planes["output_z"]), 0.0)])
        d_out = np.ascontiguousarray(out64[:, 2:5].T)
        return self._result(o_out, d_out, np.where(valid, wl, 0.0), status, valid,
                            np.where(v, spread.astype(np.float64), 0.0))
