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


#: the ray-table domain's grid (trainer.pipeline.fit_table): cells of (r, u_r, u_t), finer in the
#: directions (a cell a 36th of the Tessar's pupil) than the film radius (slices are aligned)
TABLE_SHAPE = (32, 96, 96)
#: the rays a slice's hull is taken over at least (table_occupancy)
MIN_HULL_RAYS = 1000
#: the area a hull of n uniform points in a disc misses, times n^(2/3) (Renyi and Sulanke
#: 1963; 3.39 measured by Monte Carlo for n from 300 to 3000)
HULL_SHORTFALL = 3.39


def table_occupancy(base: np.ndarray, lo, hi, shape=TABLE_SHAPE) -> np.ndarray:
    """The domain of a lens known only from a ray table, from its passing rays' base columns
    `base` (N, 3) = (r, u_r, u_t) in [lo, hi]: per slice of film radius, the cells whose
    middle lies in the convex hull of its rays' directions (u_r, u_t). The directions that
    pass from one film point are an intersection of round apertures' images, convex to the
    pupil's aberration, and a hull closes the holes of a table thin near the axis
    (area-uniform film points are few there). A slice of fewer than MIN_HULL_RAYS rays pools its nearest slices' rays, each
    moved by the difference of the slices' mean directions (a straight-line fit over the film
    radius: the bundle's centre moves smoothly, its shape slowly); within a slice each ray is
    moved to the slice's middle radius along the same line. A hull of n points misses part of
    the set they fill (HULL_SHORTFALL): it is grown by what a disc's would miss."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    shape = tuple(int(s) for s in shape)
    span = np.where(hi > lo, hi - lo, 1.0)
    q = (base - lo) / span * shape                   # continuous cell coordinates
    k_of = np.clip(q[:, 0].astype(int), 0, shape[0] - 1)
    per_slice = np.bincount(k_of, minlength=shape[0])
    order = np.argsort(k_of, kind="stable")
    starts = np.concatenate([[0], np.cumsum(per_slice)])
    uv = q[order, 1:]
    # the bundles' centre per slice: a straight line over the slices' mean directions
    ks = np.flatnonzero(per_slice)
    means = np.array([uv[starts[k]:starts[k + 1]].mean(axis=0) for k in ks])
    A = np.stack([np.ones(ks.size), ks + 0.5], axis=1) * np.sqrt(per_slice[ks])[:, None]
    coef = np.linalg.lstsq(A, means * np.sqrt(per_slice[ks])[:, None], rcond=None)[0]
    centre = np.stack([np.ones(shape[0]), np.arange(shape[0]) + 0.5], axis=1) @ coef
    mi, mj = np.meshgrid(np.arange(shape[1]) + 0.5, np.arange(shape[2]) + 0.5, indexing="ij")
    middles = np.stack([mi.ravel(), mj.ravel()], axis=1)
    # every ray moved to its slice's middle radius along that line: a slice's hull is then
    # the passing set of one film radius, not its union over the slice
    uv = uv - coef[1] * (q[order, 0] - (k_of[order] + 0.5))[:, None]
    grid = np.zeros(shape, dtype=bool)
    for k in ks:
        a, b = k, k + 1
        while per_slice[a:b].sum() < MIN_HULL_RAYS and (a > 0 or b < shape[0]):
            a, b = max(a - 1, 0), min(b + 1, shape[0])
        pts = np.concatenate([uv[starts[j]:starts[j + 1]] + (centre[k] - centre[j])
                              for j in range(a, b)])
        hull = _hull(pts)
        if len(hull) >= 3:
            # n points' hull misses HULL_SHORTFALL n^(-2/3) of a disc's area (Renyi-Sulanke):
            # grown about the points' mean to make it up
            grow = 1.0 / np.sqrt(1.0 - min(HULL_SHORTFALL * len(pts) ** (-2.0 / 3.0), 0.5))
            mid = pts.mean(axis=0)
            hull = mid + (hull - mid) * grow
            # the cells whose middle is inside: the midpoint rule, so the domain's area is the
            # hull's to a cell's rounding, neither grown nor shrunk on average
            grid[k] = _in_hull(hull, middles).reshape(shape[1], shape[2])
    return grid


def _hull(pts: np.ndarray) -> np.ndarray:
    """The convex hull of 2-D points, counter-clockwise (Andrew's monotone chain)."""
    pts = np.unique(pts, axis=0)
    if len(pts) < 3:
        return pts
    pts = pts[np.lexsort((pts[:, 1], pts[:, 0]))]

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower, upper = [], []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    for p in pts[::-1]:
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1])


def _in_hull(hull: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Which points q (M, 2) lie in the counter-clockwise convex polygon `hull` (edges
    included)."""
    if len(hull) < 3:
        return np.zeros(len(q), dtype=bool)
    a, b = hull, np.roll(hull, -1, axis=0)
    side = ((b[:, 0] - a[:, 0])[None] * (q[:, 1:2] - a[:, 1][None])
            - (b[:, 1] - a[:, 1])[None] * (q[:, 0:1] - a[:, 0][None]))
    return (side >= -1e-9).all(axis=1)
