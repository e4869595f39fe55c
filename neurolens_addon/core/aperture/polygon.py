"""The bladed iris (`PolygonAperture`).

PolygonAperture(blades n, rotation_deg, curvature kappa): the iris inscribed in the unit circle,
vertex j at angle rot + 2 pi j / n (counter-clockwise from +x). With alpha = pi / n, the edge
midpoint lies at distance a = cos(alpha), half-chord h = sin(alpha). Each blade edge is a
circular arc through its two vertices with curvature kappa (1 / radius, in units of
1 / stop radius) bulging outward: kappa = 0 straight blades (regular polygon), kappa = 1 the
unit circle itself; in between the arc's sagitta is
    s = h^2 kappa / (1 + sqrt(1 - kappa^2 h^2)).
In the local frame of an edge (polar angle beta in [-alpha, alpha] from the edge normal) the
boundary is at radius
    r_max(beta) = (2 - kappa (a + s)) (a + s) / (sqrt(1 - q^2 sin^2 beta) - q cos beta),
    q = kappa (a + s) - 1,
(stable for kappa -> 0, where it becomes a / cos(beta)); inside iff rho <= r_max(beta).
The shape is convex for 0 <= kappa <= 1. Area (exact):
    A = n (a h + A_seg),  A_seg = (x - sin x) / (2 kappa^2),  x = 2 asin(kappa h)
(A_seg = 0 at kappa = 0; a series is used for small x).
`sample`: u1 picks the fan sector j = floor(n u1) (sector = triangle O-v_j-v_{j+1} plus its
circular segment, all of equal area) and its fractional part t sets the swept area
A(beta) = t A_sector, where
    A(beta) = 1/2 r_max(beta) sin(beta + alpha) + A_seg(chord from v_j to P(beta)),
inverted in closed form for kappa = 0 (beta = atan(2 A / a^2 - tan alpha)) and otherwise by
safeguarded Newton iterations (dA/dbeta = r_max^2 / 2, bisection when a step leaves the
bracket) from a tabulated first guess, to ~1e-15; then rho = r_max(beta) sqrt(u2).
This is an exact, deterministic warp of the unit square onto the shape: uniform density.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ApertureError
from .base import EDGE_TOL, Aperture, as_uv, as_xy


def _segment_area(chord, kappa: float) -> np.ndarray:
    """Area between a chord of length `chord` and its minor arc of curvature kappa (>= 0)."""
    chord = np.asarray(chord, dtype=np.float64)
    if kappa == 0.0:
        return np.zeros_like(chord)
    x = 2.0 * np.arcsin(np.clip(0.5 * kappa * chord, 0.0, 1.0))
    x2 = x * x
    series = x * x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0))
    diff = np.where(x < 1e-2, series, x - np.sin(x))
    return diff / (2.0 * kappa * kappa)


class PolygonAperture(Aperture):
    """A regular n-blade iris inscribed in the unit circle, blade edges optionally curved."""

    kind = "polygon"

    def __init__(self, blades: int, rotation_deg: float = 0.0, curvature: float = 0.0):
        try:
            n = int(blades)
        except (TypeError, ValueError):
            raise ApertureError(f"aperture blades must be an integer >= 3, got {blades!r}")
        if n != blades or n < 3:
            raise ApertureError(f"aperture blades must be an integer >= 3, got {blades!r}")
        rot = float(rotation_deg)
        kappa = float(curvature)
        if not math.isfinite(rot):
            raise ApertureError(f"aperture rotation must be finite (degrees), got {rotation_deg!r}")
        if not (0.0 <= kappa <= 1.0):
            raise ApertureError("aperture blade curvature must be in [0, 1] (0 straight blades, "
                                f"1 circular), got {curvature!r}")
        self.blades = n
        self.rotation_deg = rot
        self.curvature = kappa
        self._rot = math.radians(rot)
        self._alpha = math.pi / n
        self._a = math.cos(self._alpha)
        self._h = math.sin(self._alpha)
        kh = kappa * self._h
        self._s = self._h * kh / (1.0 + math.sqrt(max(0.0, 1.0 - kh * kh)))
        self._apex = self._a + self._s
        self._q = kappa * self._apex - 1.0
        self._num = (2.0 - kappa * self._apex) * self._apex
        self._tri = self._a * self._h
        self._seg = float(_segment_area(2.0 * self._h, kappa))
        self._sector = self._tri + self._seg
        if kappa > 0.0:   # table of the swept area: a close first guess for Newton's method
            self._beta_tab = np.linspace(-self._alpha, self._alpha, 1025)
            self._area_tab = self._swept_area(self._beta_tab)[0]

    # -- geometry in an edge's local frame --------------------------------------------------
    def _r_max(self, beta) -> np.ndarray:
        sb, cb = np.sin(beta), np.cos(beta)
        q = self._q
        return self._num / (np.sqrt(np.maximum(1.0 - q * q * sb * sb, 0.0)) - q * cb)

    def _swept_area(self, beta) -> tuple[np.ndarray, np.ndarray]:
        """Area of the sector part from beta = -alpha to beta, and r_max(beta)."""
        r = self._r_max(beta)
        tri = 0.5 * r * np.sin(beta + self._alpha)
        px, py = r * np.cos(beta), r * np.sin(beta)
        chord = np.hypot(px - self._a, py + self._h)
        return tri + _segment_area(chord, self.curvature), r

    def vertices(self) -> np.ndarray:
        """(n, 2) polygon vertices on the unit circle (the arcs' end points)."""
        ang = self._rot + 2.0 * self._alpha * np.arange(self.blades)
        return np.stack([np.cos(ang), np.sin(ang)], axis=1)

    def _local(self, x, y):
        rho = np.hypot(x, y)
        phi = np.arctan2(y, x) - self._rot
        width = 2.0 * self._alpha
        k = np.floor(phi / width)
        beta = phi - (k + 0.5) * width
        return rho, np.clip(beta, -self._alpha, self._alpha)

    def inside(self, x, y) -> np.ndarray:
        x, y, ok = as_xy(x, y)
        rho, beta = self._local(x, y)
        return ok & (rho <= self._r_max(beta) * (1.0 + EDGE_TOL))

    def sample(self, u1, u2) -> tuple[np.ndarray, np.ndarray]:
        u1, u2 = as_uv(u1, u2)
        n = self.blades
        scaled = u1 * n
        sector = np.minimum(np.floor(scaled), n - 1)
        frac = np.clip(scaled - sector, 0.0, 1.0)
        alpha = self._alpha
        if self.curvature == 0.0:   # closed-form inverse for the straight-edged triangle
            beta = np.arctan(2.0 * frac * self._tri / (self._a * self._a) - math.tan(alpha))
        else:
            target = frac * self._sector
            beta = np.interp(target, self._area_tab, self._beta_tab)
            lo = np.full_like(beta, -alpha)
            hi = np.full_like(beta, alpha)
            for _ in range(60):
                area, r = self._swept_area(beta)
                f = area - target
                lo = np.where(f < 0.0, beta, lo)
                hi = np.where(f > 0.0, beta, hi)
                step = f / (0.5 * r * r)
                new = beta - step
                bad = (new < lo) | (new > hi)       # Newton left the bracket: bisect
                new = np.where(bad, 0.5 * (lo + hi), new)
                change = np.max(np.abs(new - beta)) if new.size else 0.0
                beta = new
                if change < 1e-14:
                    break
            beta = np.clip(beta, -alpha, alpha)
        rho = self._r_max(beta) * np.sqrt(u2)
        phi = self._rot + (2.0 * sector + 1.0) * alpha + beta
        return rho * np.cos(phi), rho * np.sin(phi)

    def area(self) -> float:
        return self.blades * self._sector

    def bounding_radius(self) -> float:
        return 1.0

    @property
    def key(self) -> tuple:
        return ("polygon", self.blades, round(self.rotation_deg, 9), round(self.curvature, 9))

    def __repr__(self) -> str:
        return (f"PolygonAperture(blades={self.blades}, rotation_deg={self.rotation_deg:g}, "
                f"curvature={self.curvature:g})")
