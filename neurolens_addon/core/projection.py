"""Scene points to the film through the lens: the chief ray inverted (a lens of revolution).

A point of lens space (X, Y, Z) (mm, +z towards the scene, Z beyond the lens) is imaged where
the chief ray through it meets the film. The chief-ray table (core.stmap.ChiefRayTable) gives,
per film radius r, the ray's field angle theta(r) and where its scene-side line meets the axis,
z_c(r) (the entrance pupil as seen from that field: it moves with the field, pupil aberration).
The point lies on the chief ray of r when
    rho = (Z - z_c(r)) tan theta(r),     rho = sqrt(X^2 + Y^2),
solved by the fixed point
    theta_{n+1} = atan2(rho, Z - z_c(r_n)),   r_{n+1} = r(theta_{n+1})   (the table inverted),
started at the paraxial entrance pupil z_c(0): z_c changes little over the field, so each
step shrinks the error by about (dz_c / dr)(dr / dtheta) sin(theta) / distance, far below 1
for points beyond the lens's own length. A point is placed where the iteration settles (its
last step under SETTLED_MM (1 + r) of film radius); one behind the entrance pupil, beyond the
table's field, or not settled is not placed (valid False, position 0).
The image is inverted and the read-out turns it back, so the image point shares the scene
point's azimuth: (p, q) = r (X, Y) / rho (mm from the axis, right and up; the axis itself at
rho = 0); its position in pixels: core.film.Film.pixel_coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .stmap import ChiefRayTable

#: fixed-point steps at most, and the film radius change (mm) that counts as settled
STEPS = 12
SETTLED_MM = 1e-7


def film_radius(table: ChiefRayTable, rho: np.ndarray, z: np.ndarray):
    """(film radius r (N,) mm, placed (N,) bool) of lens-space points at distance rho from
    the axis and z along it (module docstring)."""
    rho = np.asarray(rho, dtype=np.float64)
    z = np.asarray(z, dtype=np.float64)
    if table.axis_z is None:
        raise ValueError("the chief-ray table holds no entrance pupil (axis_z)")
    zc = np.full(rho.shape, float(table.axis_z[0]))
    r = np.zeros(rho.shape)
    settled = np.zeros(rho.shape, bool)
    for _ in range(STEPS):
        theta = np.arctan2(rho, z - zc)
        r_new = np.interp(theta, table.theta, table.r_mm)
        settled = np.abs(r_new - r) <= SETTLED_MM * (1.0 + np.abs(r_new))
        r = r_new
        zc = np.interp(r, table.r_mm, table.axis_z)
        if settled.all():
            break
    theta = np.arctan2(rho, z - zc)
    placed = settled & (z > zc) & (theta <= table.theta[-1]) & np.isfinite(r)
    return np.where(placed, r, 0.0), placed


@dataclass(frozen=True)
class _Placement:
    """A lens's chief rays (`table`: a ChiefRayTable, or a core.chief_grid.ChiefRayGrid) and
    the film they are placed on (core.film.Film: the frame as rendered, desqueezed)."""

    table: object
    film: object

    def image_points(self, lens_points: np.ndarray):
        raise NotImplementedError

    def pixels(self, lens_points: np.ndarray):
        """((N, 2) pixel positions x from the left, y from the bottom, (N,) placed) of
        lens-space points (N, 3) mm; 0 where not placed."""
        lens_points = np.asarray(lens_points, dtype=np.float64)
        p, q, placed = self.image_points(lens_points)
        out = np.stack(self.film.pixel_coordinates(p, q), axis=1)
        out[~placed] = 0.0
        return out, placed


class FilmPlacement(_Placement):
    """Where a lens of revolution images scene points on a film, in pixels (module
    docstring). `table` the lens's ChiefRayTable at its focus, out to at least the film's
    corner."""

    def image_points(self, lens_points: np.ndarray):
        x, y, z = lens_points[:, 0], lens_points[:, 1], lens_points[:, 2]
        rho = np.hypot(x, y)
        r, placed = film_radius(self.table, rho, z)
        scale = np.where(rho > 0.0, r / np.where(rho > 0.0, rho, 1.0), 0.0)
        return x * scale, y * scale, placed


class GridPlacement(_Placement):
    """Where a lens that is not of revolution (anamorphic) images scene points, in the
    desqueezed frame's pixels: `table` its core.chief_grid.ChiefRayGrid (whose
    image_of_points solves the chief ray through each point)."""

    def image_points(self, lens_points: np.ndarray):
        return self.table.image_of_points(lens_points)
