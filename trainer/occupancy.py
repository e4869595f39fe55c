"""The learned domain of a stage: which (r, u_r, u_t) cells contain rays that pass the group.

Rotational symmetry makes a ray's fate through a lens group depend only on its radial-frame
coordinates (r, u_r, u_t) and wavelength. We grid that box and trace, exactly, a ray at every
grid corner and cell centre at three wavelengths (380, 587.6, 780 nm); a cell is in the domain if
any of them passes. The grid is conservative (a cell partly inside is kept), so the model is
never asked for rays it was not trained near, and rays in cells with no passing ray are flagged.
model.json stores the grid as neural.modelfile.encode_occupancy writes it.
"""

from __future__ import annotations

import numpy as np

from neurolens_addon.core.prescription import Lens
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.trace import trace

WAVELENGTHS = (380.0, 587.5618, 780.0)


def occupancy_grid(lens: Lens, surfaces: tuple[int, int], plane_z: float, lo, hi,
                   shape=(64, 64, 64), stop_radius: float | None = None) -> np.ndarray:
    """Boolean grid over (r, u_r, u_t) in [lo, hi]: True where a ray traced from the plane
    z = plane_z through `surfaces` (sensor side first) passes."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    shape = tuple(int(s) for s in shape)
    axes_c = [np.linspace(lo[i], hi[i], shape[i] + 1) for i in range(3)]          # corners
    axes_m = [0.5 * (a[:-1] + a[1:]) for a in axes_c]                               # centres
    ok_c = _passes(lens, surfaces, plane_z, *np.meshgrid(*axes_c, indexing="ij"), stop_radius)
    ok_m = _passes(lens, surfaces, plane_z, *np.meshgrid(*axes_m, indexing="ij"), stop_radius)
    occ = ok_m.copy()
    for di in (0, 1):
        for dj in (0, 1):
            for dk in (0, 1):
                occ |= ok_c[di:di + shape[0], dj:dj + shape[1], dk:dk + shape[2]]
    return occ


def _passes(lens, surfaces, plane_z, r, ur, ut, stop_radius):
    shp = r.shape
    r, ur, ut = r.ravel(), ur.ravel(), ut.ravel()
    w2 = 1.0 - ur * ur - ut * ut
    ok_dir = w2 > 1e-6
    w = np.sqrt(np.where(ok_dir, w2, 1.0))
    n = r.size
    d = np.stack([ur, ut, w])
    # Start each ray well behind its plane (the plane only parametrises the line; a surface
    # may bulge past it towards the sensor).
    back = 50.0 / w
    o = np.stack([r - back * ur, -back * ut, np.full(n, plane_z) - back * w])
    passed = np.zeros(n, dtype=bool)
    for wl in WAVELENGTHS:
        res = trace(lens, Rays(o, d, np.full(n, wl)), surfaces=surfaces, stop_radius=stop_radius)
        passed |= res.valid
    return (passed & ok_dir).reshape(shp)


def lookup(d: dict, grid: np.ndarray, X3: np.ndarray) -> np.ndarray:
    """True where rows (r, u_r, u_t) fall in an occupied cell (False outside the box)."""
    lo, hi = np.asarray(d["lo"]), np.asarray(d["hi"])
    shape = np.asarray(grid.shape)
    with np.errstate(invalid="ignore"):
        f = (X3 - lo) / (hi - lo)
        inside = np.all((f >= 0.0) & (f <= 1.0), axis=1)
    idx = np.clip(np.nan_to_num(f * shape).astype(np.int64), 0, shape - 1)
    return inside & grid[idx[:, 0], idx[:, 1], idx[:, 2]]
