"""The chief ray of a lens that is not of revolution (an anamorphic lens), over a grid of film
points: its ST-maps in the desqueezed frame and where it images scene points.

Chief ray. From a lens-space film point (x, y) on the sensor plane z_s the ray aimed at (a, b)
on the paraxial exit pupil's plane z_a crosses the stop surface at (x_s, y_s)(a, b); the chief
ray's aim solves x_s = y_s = 0, by Newton's method with a forward-difference 2 x 2 Jacobian,
RINGS_AT_ONCE rings of the grid at once, outwards from the centre, each point started from
the aim of its neighbour on the last ring solved, moved on by that neighbour's own step per
ring (the aim moves smoothly over the film). Traced on through the lens it
leaves with direction d from the front surface at o; the grid keeps the slopes and the line:
    s = d_x / d_z,   t = d_y / d_z,   (u, v) = (o_x, o_y) + (z_r - o_z) (s, t)
(u, v) where the line crosses the plane z_r of the front vertex. Fields are interpolated
bilinearly between the GRID x GRID points, which span the film asked for (x and y each in
[-X, X] x [-Y, Y]).

Pinhole. The image is inverted (+x on the film sees -x) and both renderers desqueeze it: the
frame's point of film point (x, y) is (p, q) = (-S x, -y), S the lens's squeeze. The ideal
pinhole that agrees with the lens at the centre, in the desqueezed frame, images slopes (s, t)
at
    (P, Q) = (S f_x s, f_y t),   f_x = lim -x / s,   f_y = lim -y / t   (x, y -> 0)
(the paraxial focal lengths per axis at that focus, read one grid step from the centre by a
centred difference). Maps (Nuke's STMap, as core.stmap): distort samples the pinhole image at
the pinhole point of the lens image's pixel; undistort samples the lens image where the chief
ray of slopes (P / (S f_x), Q / f_y) starts, found by Newton's method on the interpolated
slopes (their bilinear Jacobian) from the pinhole's own film point.

Scene points. A lens-space point (X, Y, Z) lies on the chief ray of film point (x, y) when
    (u, v)(x, y) + (Z - z_r) (s, t)(x, y) = (X, Y),
solved by Newton's method on the interpolated fields from the pinhole's film point. A point is
placed where the solve settles within SETTLED_MM inside the grid; elsewhere it is not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import LensError
from .prescription import WAVELENGTH_D_NM, Lens
from .aimed_rays import aim_plane_z, trace_aimed

#: grid points each way
GRID = 129
#: rings of the grid solved together (each started from the last ring solved before them)
RINGS_AT_ONCE = 4
#: Newton steps of the chief-ray aim, and its difference step (mm)
AIM_STEPS = 12
AIM_STEP_MM = 1e-5
#: Newton steps of an inversion, and the film distance (mm) that counts as settled
SOLVE_STEPS = 20
SETTLED_MM = 1e-6


def _aims(lens: Lens, fx, fy, sensor_z: float, wavelength_nm: float, z_a: float):
    """(aims a, b, passes) of the chief rays from film points (fx, fy) (module docstring)."""
    stop, n = lens.stop_index, len(lens.surfaces)
    gi, gj = fx.shape
    # rings outwards from the centre: ring k holds the points k steps from it (either way)
    ci, cj = gi // 2, gj // 2
    ii, jj = np.meshgrid(np.arange(gi), np.arange(gj), indexing="ij")
    ring = np.maximum(np.abs(ii - ci), np.abs(jj - cj))
    a, b = np.zeros(fx.shape), np.zeros(fx.shape)
    step_a, step_b = np.zeros(fx.shape), np.zeros(fx.shape)

    def at_stop(x, y, ax, ay):
        res = trace_aimed(lens, x, y, ax, ay, sensor_z, z_a, wavelength_nm, (stop, n))
        p = res.rays.o
        return np.where(res.valid, p[0], np.nan), np.where(res.valid, p[1], np.nan)

    h = AIM_STEP_MM
    last = int(ring.max())
    solved = -1                                   # the outermost ring solved
    while solved < last:
        rings = min(RINGS_AT_ONCE, last - solved)
        sel = np.flatnonzero((ring.ravel() > solved) & (ring.ravel() <= solved + rings))
        i, j = ii.ravel()[sel], jj.ravel()[sel]
        # each point's neighbour on the last ring solved, m rings in, and its start: the
        # neighbour's aim moved on by m of its own steps
        m = ring.ravel()[sel] - max(solved, 0)
        pi = i - np.sign(i - ci) * np.minimum(m, np.abs(i - ci))
        pj = j - np.sign(j - cj) * np.minimum(m, np.abs(j - cj))
        x, y = fx[i, j], fy[i, j]
        ax = a[pi, pj] + m * step_a[pi, pj]
        ay = b[pi, pj] + m * step_b[pi, pj]
        with np.errstate(invalid="ignore", divide="ignore"):
            for _ in range(AIM_STEPS):
                gx, gy = at_stop(x, y, ax, ay)
                g1x, g1y = at_stop(x, y, ax + h, ay)
                g2x, g2y = at_stop(x, y, ax, ay + h)
                j11, j21 = (g1x - gx) / h, (g1y - gy) / h
                j12, j22 = (g2x - gx) / h, (g2y - gy) / h
                det = j11 * j22 - j12 * j21
                da = (j22 * gx - j12 * gy) / det
                db = (-j21 * gx + j11 * gy) / det
                good = np.isfinite(da) & np.isfinite(db)
                ax = np.where(good, ax - da, ax)
                ay = np.where(good, ay - db, ay)
                if np.nanmax(np.hypot(gx, gy), initial=0.0) < 1e-11:
                    break
        a[i, j], b[i, j] = ax, ay
        # a ring's step: from its neighbour one ring in (solved now, or before)
        qi = i - np.sign(i - ci)
        qj = j - np.sign(j - cj)
        step_a[i, j] = ax - a[qi, qj]
        step_b[i, j] = ay - b[qi, qj]
        solved += rings
    gx, gy = at_stop(fx.ravel(), fy.ravel(), a.ravel(), b.ravel())
    ok = np.isfinite(gx) & (np.hypot(np.nan_to_num(gx, nan=1.0), np.nan_to_num(gy, nan=1.0))
                            < 1e-6)
    return a, b, ok.reshape(fx.shape)


def _bilinear(field, xs, ys, x, y):
    """(values, d/dx, d/dy) of fields (I, J, k) on the grid xs (I,) x ys (J,) at points
    (x, y) (N,), clamped to the grid."""
    dx, dy = xs[1] - xs[0], ys[1] - ys[0]
    fi = np.clip(np.nan_to_num((x - xs[0]) / dx), 0.0, xs.size - 1 - 1e-9)
    fj = np.clip(np.nan_to_num((y - ys[0]) / dy), 0.0, ys.size - 1 - 1e-9)
    i, j = np.floor(fi).astype(np.int64), np.floor(fj).astype(np.int64)
    a, b = (fi - i)[:, None], (fj - j)[:, None]
    f00, f10 = field[i, j], field[i + 1, j]
    f01, f11 = field[i, j + 1], field[i + 1, j + 1]
    value = (1 - a) * (1 - b) * f00 + a * (1 - b) * f10 + (1 - a) * b * f01 + a * b * f11
    ddx = ((1 - b) * (f10 - f00) + b * (f11 - f01)) / dx
    ddy = ((1 - a) * (f01 - f00) + a * (f11 - f10)) / dy
    return value, ddx, ddy


@dataclass(frozen=True)
class ChiefRayGrid:
    """The chief rays of a lens over a grid of film points at one focus (module docstring)."""

    xs: np.ndarray              # (I,) film x, mm (lens space)
    ys: np.ndarray              # (J,) film y
    fields: np.ndarray          # (I, J, 4): s, t, u, v
    passes: np.ndarray          # (I, J) bool: the chief ray passes there
    f_x_mm: float
    f_y_mm: float
    squeeze: float
    z_ref: float                # the plane of (u, v): the front vertex
    sensor_z: float

    def _inside(self, x, y):
        """Film points inside the grid whose four surrounding chief rays pass."""
        xs, ys = self.xs, self.ys
        ins = (x >= xs[0]) & (x <= xs[-1]) & (y >= ys[0]) & (y <= ys[-1])
        x, y = np.where(ins, x, xs[0]), np.where(ins, y, ys[0])      # (nan: outside)
        i = np.clip(np.floor((x - xs[0]) / (xs[1] - xs[0])).astype(np.int64), 0, xs.size - 2)
        j = np.clip(np.floor((y - ys[0]) / (ys[1] - ys[0])).astype(np.int64), 0, ys.size - 2)
        p = self.passes
        return ins & p[i, j] & p[i + 1, j] & p[i, j + 1] & p[i + 1, j + 1]

    def slopes(self, x, y):
        """((N,) s, (N,) t, (N,) passes) of film points (x, y)."""
        v, _dx, _dy = _bilinear(self.fields[..., :2], self.xs, self.ys, x, y)
        return v[:, 0], v[:, 1], self._inside(x, y)

    def pinhole_of_lens(self, p, q):
        """The pinhole image's points (P, Q) of the desqueezed lens image's (p, q) (mm), and
        whether the lens images them."""
        s, t, ok = self.slopes(-p / self.squeeze, -q)
        return self.squeeze * self.f_x_mm * s, self.f_y_mm * t, ok

    def _solve(self, target, offset_z, x, y):
        """Film points (x, y) where fields s, t (offset_z None) or the line at offset_z
        (u + offset_z s, v + offset_z t) equal target (N, 2); (x, y, settled)."""
        settled = np.zeros(x.size, bool)
        for _ in range(SOLVE_STEPS):
            v, ddx, ddy = _bilinear(self.fields, self.xs, self.ys, x, y)
            if offset_z is None:
                g = v[:, :2] - target
                jx, jy = ddx[:, :2], ddy[:, :2]
            else:
                z = offset_z[:, None]
                g = v[:, 2:] + z * v[:, :2] - target
                jx, jy = ddx[:, 2:] + z * ddx[:, :2], ddy[:, 2:] + z * ddy[:, :2]
            det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
            det = np.where(np.abs(det) > 1e-300, det, 1e-300)
            dx = (jy[:, 1] * g[:, 0] - jy[:, 0] * g[:, 1]) / det
            dy = (-jx[:, 1] * g[:, 0] + jx[:, 0] * g[:, 1]) / det
            x, y = x - dx, y - dy
            settled = np.hypot(dx, dy) <= SETTLED_MM
            if settled.all():
                break
        return x, y, settled & self._inside(x, y)

    def lens_of_pinhole(self, big_p, big_q):
        """The desqueezed lens image's points (p, q) whose chief rays the pinhole images at
        (P, Q), and whether the lens images them."""
        s = big_p / (self.squeeze * self.f_x_mm)
        t = big_q / self.f_y_mm
        x, y, ok = self._solve(np.stack([s, t], axis=1), None, -s * self.f_x_mm,
                               -t * self.f_y_mm)
        return -self.squeeze * x, -y, ok

    def image_of_points(self, points):
        """The desqueezed image points (p, q) (mm) of lens-space scene points (N, 3), and
        whether they are placed (module docstring)."""
        points = np.asarray(points, dtype=np.float64)
        dz = points[:, 2] - self.z_ref
        far = np.where(np.abs(dz) > 1e-9, dz, 1e-9)
        x0, y0 = -self.f_x_mm * points[:, 0] / far, -self.f_y_mm * points[:, 1] / far
        x, y, ok = self._solve(points[:, :2], dz, x0, y0)
        ok &= dz > 0
        return np.where(ok, -self.squeeze * x, 0.0), np.where(ok, -y, 0.0), ok


def chief_ray_grid(lens: Lens, sensor_z: float, half_x_mm: float, half_y_mm: float, *,
                   squeeze: float, wavelength_nm: float = WAVELENGTH_D_NM) -> ChiefRayGrid:
    """The chief-ray grid of a lens over the lens film [-X, X] x [-Y, Y] mm (module
    docstring); LensError where no chief ray passes near the axis."""
    z_a = aim_plane_z(lens, sensor_z)
    xs = np.linspace(-half_x_mm, half_x_mm, GRID)
    ys = np.linspace(-half_y_mm, half_y_mm, GRID)
    fx, fy = np.meshgrid(xs, ys, indexing="ij")
    a, b, ok = _aims(lens, fx, fy, sensor_z, wavelength_nm, z_a)
    res = trace_aimed(lens, fx.ravel(), fy.ravel(), a.ravel(), b.ravel(), sensor_z, z_a,
                      wavelength_nm)
    out, at = res.rays.d, res.rays.o
    ok &= (res.valid & (out[2] > 1e-9)).reshape(fx.shape)
    z_ref = float(lens.front_vertex_z)
    with np.errstate(invalid="ignore", divide="ignore"):
        s, t = out[0] / out[2], out[1] / out[2]
        u = at[0] + (z_ref - at[2]) * s
        v = at[1] + (z_ref - at[2]) * t
    fields = np.stack([s, t, u, v], axis=1).reshape(GRID, GRID, 4)
    fields = np.where(ok[..., None], fields, 0.0)
    c, step = GRID // 2, (xs[1] - xs[0], ys[1] - ys[0])
    if not ok[c - 1:c + 2, c - 1:c + 2].all():
        raise LensError(f"lens '{lens.name}': no chief ray passes near the axis at sensor z "
                        f"{sensor_z:g} mm", path=lens.path)
    f_x = -2.0 * step[0] / (fields[c + 1, c, 0] - fields[c - 1, c, 0])
    f_y = -2.0 * step[1] / (fields[c, c + 1, 1] - fields[c, c - 1, 1])
    return ChiefRayGrid(xs, ys, fields, ok, float(f_x), float(f_y), float(squeeze), z_ref,
                        float(sensor_z))
