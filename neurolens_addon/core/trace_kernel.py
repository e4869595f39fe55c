"""One chunk of rays through a run of surfaces, in place: intersection, clipping, refraction.

At each surface, in travel order (the surface's shape gives the geometry, core.surfaces):
- t of the hit (shape.hit); a ray that misses the surface's cap, meets it more than
  BACKWARD_TOLERANCE_MM behind its start, or (aspheres) does not converge dies there;
- the ray moves to o + t d and is clipped where rho = x^2 + y^2 > semi-diameter^2, and at the
  aperture stop where it lies outside the stop shape: aperture.inside(x / R, y / R) for the
  stop radius R, or rho > R^2 for a circular stop;
- refraction unless both sides have the same index (the stop, a flat in air): with the normal
  N (shape.normal, normalised) oriented against the ray, cos_i = -N.d > 0 and eta = n1 / n2,
  Snell's law in vector form
      d' = eta d + (eta cos_i - sqrt(1 - eta^2 (1 - cos_i^2))) N,
  and a negative radicand is total internal reflection (the ray dies);
- or, at a step marked `reflect` (a ghost's path, core.ghosts), the mirror reflection
      d' = d + 2 cos_i N,
  the ray staying in its medium (the step's pair names the medium beyond the surface);
- with a coating (core.coatings) each ray's weight is multiplied by the surface's
  transmittance 1 - R(n1, n2, cos_i, lambda) where it refracts and by R where it reflects.
Each ray records the first reason it died (RayStatus) and the surface index.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .prescription import Lens
from .rays import RayStatus
from .surfaces import BACKWARD_TOLERANCE_MM, SurfaceShape


@dataclass(frozen=True)
class PlacedSurface:
    """A surface where the trace meets it: its shape, vertex z in lens space, semi-diameter
    squared, and whether it is the aperture stop."""

    shape: SurfaceShape
    z: float
    sd2: float
    stop: bool


@lru_cache(maxsize=64)
def placed_surfaces(lens: Lens) -> tuple[PlacedSurface, ...]:
    return tuple(PlacedSurface(s.shape, float(z), s.semi_diameter_mm ** 2, s.stop)
                 for s, z in zip(lens.surfaces, lens.vertex_z))


class Kernel:
    """Traces one chunk of rays through the surfaces in a given order (no allocation per surface
    beyond numpy temporaries); mutates the chunk's arrays in place."""

    def __init__(self, placed, order, media_index_pairs, stop_radius, aperture, *,
                 reflect=None, coating=None):
        self.placed = placed
        self.order = order                      # surface indices in travel order
        self.media_index_pairs = media_index_pairs  # per step: (medium before, medium after)
        self.stop_radius = stop_radius
        self.aperture = aperture
        self.reflect = tuple(reflect) if reflect is not None else (False,) * len(order)
        self.coating = coating                  # core.coatings.Coating: weights (run's weight)

    def run(self, ox, oy, oz, dx, dy, dz, wl, media, path=None, weight=None):
        """Trace the chunk in place; (status, died_at, alive). `weight` (with a coating):
        multiplied in place by each surface's transmittance or reflectance."""
        m = ox.shape[0]
        status = np.zeros(m, dtype=np.uint8)
        died_at = np.full(m, -1, dtype=np.int16)
        alive = np.ones(m, dtype=bool)

        # Indices per medium for this chunk: one scalar when all rays share a wavelength.
        if m and wl.min() == wl.max():
            idx = [float(np.asarray(med.index(np.array([wl[0]])))[0]) for med in media]
        else:
            idx = [med.index(wl) for med in media]
        bad_wl = ~np.isfinite(wl)
        for n in idx:
            if isinstance(n, float):
                if not math.isfinite(n):
                    bad_wl[:] = True
            else:
                bad_wl |= ~np.isfinite(n)
        if bad_wl.any():
            self._kill(alive, status, died_at, bad_wl, RayStatus.BAD_WAVELENGTH, -1)

        for step, si in enumerate(self.order):
            g = self.placed[si]
            n1 = idx[self.media_index_pairs[step][0]]
            n2 = idx[self.media_index_pairs[step][1]]
            self._surface(g, si, ox, oy, oz, dx, dy, dz, n1, n2, alive, status, died_at,
                          self.reflect[step], wl, weight)
            if path is not None:
                path.append((np.stack([ox, oy, oz]), alive.copy()))
        return status, died_at, alive

    @staticmethod
    def _kill(alive, status, died_at, mask, code, surface):
        newly = mask & alive
        np.copyto(status, np.uint8(code), where=newly)
        np.copyto(died_at, np.int16(surface), where=newly)
        alive &= ~newly

    def _surface(self, g, si, ox, oy, oz, dx, dy, dz, n1, n2, alive, status, died_at,
                 reflect=False, wl=None, weight=None):
        t, miss, unconverged = g.shape.hit(g.z, ox, oy, oz, dx, dy, dz)
        if unconverged is not None:
            self._kill(alive, status, died_at, unconverged & ~miss, RayStatus.NO_CONVERGENCE, si)
        miss |= t < -BACKWARD_TOLERANCE_MM
        self._kill(alive, status, died_at, miss, RayStatus.MISSED_SURFACE, si)
        np.copyto(t, 0.0, where=~alive)

        # Move to the hit point.
        ox += t * dx
        oy += t * dy
        oz += t * dz
        rho = ox * ox
        rho += oy * oy
        self._kill(alive, status, died_at, ~(rho <= g.sd2), RayStatus.CLIPPED_APERTURE, si)
        if g.stop and self.stop_radius is not None:
            r = self.stop_radius
            if self.aperture is None:
                outside = ~(rho <= r * r)
            else:
                outside = ~self.aperture.inside(ox / r, oy / r)
            self._kill(alive, status, died_at, outside, RayStatus.CLIPPED_STOP, si)

        # Refract, unless both sides have the same index (the stop, a flat in air).
        if isinstance(n1, float) and isinstance(n2, float) and n1 == n2 and not reflect:
            return
        nx, ny, nz = g.shape.normal(g.z, ox, oy, oz, rho)
        if not g.shape.normal_is_unit:
            inv = nx * nx
            inv += ny * ny
            inv += nz * nz
            np.sqrt(inv, out=inv)
            with np.errstate(divide="ignore", invalid="ignore"):
                np.divide(1.0, inv, out=inv)
            nx = nx * inv
            ny = ny * inv
            nz *= inv
        cosi = nx * dx
        cosi += ny * dy
        cosi += nz * dz
        np.negative(cosi, out=cosi)
        # Orient N against the incoming ray so that cos_i > 0.
        flip = np.where(cosi < 0.0, -1.0, 1.0)
        cosi *= flip
        if weight is not None and self.coating is not None:
            r = self.coating.reflectance(n1, n2, cosi, wl)
            weight *= r if reflect else 1.0 - r
        if reflect:
            # mirror: d' = d + 2 cos_i N_oriented, N_oriented = flip N
            fac = 2.0 * cosi * flip
            dx += fac * nx
            dy += fac * ny
            dz += fac * nz
            return
        eta = n1 / n2
        eta2 = eta * eta
        k = cosi * cosi
        k -= 1.0
        k *= eta2
        k += 1.0
        tir = k < 0.0
        self._kill(alive, status, died_at, tir, RayStatus.TOTAL_INTERNAL_REFLECTION, si)
        np.maximum(k, 0.0, out=k)
        np.sqrt(k, out=k)
        # factor = (eta cos_i - sqrt(k)) * flip, applied to the unflipped normal
        fac = eta * cosi
        fac -= k
        fac *= flip
        dx *= eta
        dx += fac * nx
        dy *= eta
        dy += fac * ny
        dz *= eta
        dz += fac * nz
