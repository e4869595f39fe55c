"""Which rays a learned model accepts: valid input, and each stage's learned domain.

Domain of a ray (every condition must hold, else the ray is flagged and its outputs are 0):
  finite components (and finite lambda with dispersion); lambda in wavelength_range_nm (with
  dispersion); for each stage, its input X in the model's frame (core.irf: radial
  (r, u_r, u_t, w[, lambda]), cartesian (x, y, u, v, w[, lambda])) lies in the stage's bounds
  box  lo <= X <= hi  and its occupancy cell is True, where over the frame's base columns
  ((r, u_r, u_t) or (x, y, u, v): as many as the grid has axes)
      f = (X - lo_o) / (hi_o - lo_o),  inside iff 0 <= f <= 1,
      cell = min(floor(f * shape), shape - 1)  (per axis, C order of the packed bits).
Stage 2 is checked on stage 1's output (the ray on the stop plane).

The tests run in float32 on the float32 rays the graphs see, with every constant rounded to
float32 once, exactly as forward_fast.onnx does them (onnx_export.fast_domain): both paths
then accept the same rays, bit for bit.

Valid input of trace_from_sensor (`prepare_pi1`): film point and direction finite, |d| > 0 and
finite, d_z > 0 after normalising, finite wavelength and sensor plane, and a finite point on
Pi_1 after the free flight  x_1 = x + (z_1 - sensor_z) u / w.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.irf import RADIAL, StageFrame, propagate_to_z


def radial_inputs(x, y, u, v, w, lam, dispersion: bool) -> list[np.ndarray]:
    """Columns of the stage input X = (r, u_r, u_t, w[, lambda]); phi = 0 at r = 0 (in the
    float32 arithmetic forward_fast.onnx uses, not core.irf.to_radial's)."""
    r = np.sqrt(x * x + y * y)
    zero = r == 0
    rs = np.where(zero, 1.0, r)
    c = x / rs + zero
    s = y / rs
    return [r, c * u + s * v, c * v - s * u, w] + ([lam] if dispersion else [])


def frame_inputs(frame: StageFrame, x, y, u, v, w, lam, dispersion: bool) -> list[np.ndarray]:
    """Columns of the stage input X in `frame`: radial_inputs, or cartesian
    (x, y, u, v, w[, lambda]) as they are."""
    if frame is RADIAL:
        return radial_inputs(x, y, u, v, w, lam, dispersion)
    return [x, y, u, v, w] + ([lam] if dispersion else [])


@dataclass
class StageGuard:
    """A stage's learned domain: bounds box over X and occupancy grid over its frame's base
    columns (the grid's first axes of X)."""

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
        self._sc32 = np.array([shape[i] / (self.occ_hi[i] - self.occ_lo[i])
                               for i in range(len(shape))], dtype=np.float32)

    def inside(self, cols) -> np.ndarray:
        """cols: the d_in columns of X (float32 1-D arrays); NaN is never inside."""
        ok = np.ones(cols[0].shape, dtype=bool)
        for c, lo, hi in zip(cols, self._lo32, self._hi32):
            ok &= c >= lo
            ok &= c <= hi
        shape = self.grid.shape
        fs = []
        for i in range(len(shape)):
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


class FreeSpaceGuard:
    """A stage with no surfaces (exact propagation) accepts every finite ray."""

    def inside(self, cols) -> np.ndarray:
        ok = np.ones(cols[0].shape, dtype=bool)
        for c in cols:
            ok &= np.isfinite(c)
        return ok


def prepare_pi1(o, d, wl, zs, input_z: float):
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
