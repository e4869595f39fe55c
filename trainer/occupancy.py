"""The learned domain of a stage: which cells of its frame's base columns hold rays that pass
the group.

A ray's fate through a lens group depends on its base coordinates and wavelength: in the radial
frame (rotational symmetry) on (r, u_r, u_t), in the cartesian frame (anamorphic lenses) on
(x, y, u, v) (core.irf). We grid that box and trace, exactly, a ray at every grid corner and
cell centre at three wavelengths (380, 587.6, 780 nm); a cell is in the domain if any of them
passes. The grid is conservative (a cell partly inside is kept), so the model is never asked for
rays it was not trained near, and rays in cells with no passing ray are flagged.
model.json stores the grid as neural.modelfile.encode_occupancy writes it.
"""

from __future__ import annotations

import itertools

import numpy as np

from neurolens_addon.core.irf import RADIAL, StageFrame
from neurolens_addon.core.prescription import Lens
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.trace import trace

WAVELENGTHS = (380.0, 587.5618, 780.0)
#: grid shapes per frame: 64^3 cells (32 KB) radial; 16^4 (8 KB) over the cartesian frame's
#: four base columns, where 64^4 would be 2 MB of bits and 17 M traced corners
DEFAULT_SHAPES = {"radial": (64, 64, 64), "cartesian": (16, 16, 16, 16)}


def occupancy_grid(lens: Lens, surfaces: tuple[int, int], plane_z: float, lo, hi,
                   shape=None, stop_radius: float | None = None,
                   frame: StageFrame = RADIAL) -> np.ndarray:
    """Boolean grid over the frame's base columns ((r, u_r, u_t) or (x, y, u, v)) in [lo, hi]:
    True where a ray traced from the plane z = plane_z through `surfaces` (sensor side first)
    passes."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    shape = tuple(int(s) for s in (shape or DEFAULT_SHAPES[frame.name]))
    k = len(shape)
    axes_c = [np.linspace(lo[i], hi[i], shape[i] + 1) for i in range(k)]          # corners
    axes_m = [0.5 * (a[:-1] + a[1:]) for a in axes_c]                               # centres
    ok_c = _passes(lens, surfaces, plane_z, np.meshgrid(*axes_c, indexing="ij"), stop_radius)
    ok_m = _passes(lens, surfaces, plane_z, np.meshgrid(*axes_m, indexing="ij"), stop_radius)
    occ = ok_m.copy()
    for corner in itertools.product((0, 1), repeat=k):
        occ |= ok_c[tuple(slice(c, c + s) for c, s in zip(corner, shape))]
    return occ


def _passes(lens, surfaces, plane_z, cols, stop_radius):
    """Whether rays with base columns `cols` (3 radial, as the ray on +x; 4 cartesian) pass."""
    shp = cols[0].shape
    cols = [c.ravel() for c in cols]
    if len(cols) == 3:
        x, y, u, v = cols[0], np.zeros_like(cols[0]), cols[1], cols[2]
    else:
        x, y, u, v = cols
    w2 = 1.0 - u * u - v * v
    ok_dir = w2 > 1e-6
    w = np.sqrt(np.where(ok_dir, w2, 1.0))
    n = x.size
    d = np.stack([u, v, w])
    # Start each ray well behind its plane (the plane only parametrises the line; a surface
    # may bulge past it towards the sensor).
    back = 50.0 / w
    o = np.stack([x - back * u, y - back * v, np.full(n, plane_z) - back * w])
    passed = np.zeros(n, dtype=bool)
    for wl in WAVELENGTHS:
        res = trace(lens, Rays(o, d, np.full(n, wl)), surfaces=surfaces, stop_radius=stop_radius)
        passed |= res.valid
    return (passed & ok_dir).reshape(shp)


def lookup(d: dict, grid: np.ndarray, Xb: np.ndarray) -> np.ndarray:
    """True where rows of base columns fall in an occupied cell (False outside the box)."""
    lo, hi = np.asarray(d["lo"]), np.asarray(d["hi"])
    shape = np.asarray(grid.shape)
    with np.errstate(invalid="ignore"):
        f = (Xb - lo) / (hi - lo)
        inside = np.all((f >= 0.0) & (f <= 1.0), axis=1)
    idx = np.clip(np.nan_to_num(f * shape).astype(np.int64), 0, shape - 1)
    return inside & grid[tuple(idx.T)]
