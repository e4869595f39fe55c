"""The interface of every aperture shape (`Aperture`) and its coordinate helpers.

Coordinates: (x, y) in the stop plane divided by the current stop radius, so the full circular
opening is the unit disc. Every shape lies inside the disc of radius `bounding_radius()`.
All methods are vectorised over broadcastable arrays; NaN / inf points are never inside.
`sample(u1, u2)` maps the unit square onto the shape; its density per unit (normalised) area
is pdf() = 1 / area() for the uniform shapes.
"""

from __future__ import annotations

import numpy as np

#: Points this close outside the boundary (relative) still count as inside, so that samples
#: generated on the boundary itself never fail `inside` by rounding.
EDGE_TOL = 1e-12


def as_xy(x, y) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Broadcast to float64 arrays; also return the finite mask (NaN-safe copies at 0)."""
    x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    ok = np.isfinite(x) & np.isfinite(y)
    return np.where(ok, x, 0.0), np.where(ok, y, 0.0), ok


def as_uv(u1, u2) -> tuple[np.ndarray, np.ndarray]:
    u1, u2 = np.broadcast_arrays(np.asarray(u1, dtype=np.float64),
                                 np.asarray(u2, dtype=np.float64))
    top = np.nextafter(1.0, 0.0)
    return (np.clip(np.nan_to_num(u1, nan=0.0), 0.0, top),
            np.clip(np.nan_to_num(u2, nan=0.0), 0.0, top))


class Aperture:
    """Common interface. Subclasses implement inside, sample, area, bounding_radius."""

    kind = "aperture"

    def inside(self, x, y) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def transmittance(self, x, y) -> np.ndarray:
        """Fraction of light passed at (x, y): 1.0 inside, 0.0 outside for hard shapes."""
        return self.inside(x, y).astype(np.float64)

    def sample(self, u1, u2) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - abstract
        raise NotImplementedError

    def area(self) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def bounding_radius(self) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def key(self) -> tuple:
        """A value that identifies the shape (equal shapes, equal keys: caches by value)."""
        return (self.kind,)

    def pdf(self) -> float:
        """Density of `sample` per unit (normalised) area: 1 / area() (uniform shapes)."""
        return 1.0 / self.area()
