"""The circular stop (`CircularAperture`): the unit disc.

Inside iff x^2 + y^2 <= 1; area pi. `sample` uses Shirley & Chiu's concentric square -> disc map
(low distortion, keeps stratification):
    a = 2 u1 - 1, b = 2 u2 - 1;  |a| > |b|: r = a, phi = (pi/4) b/a;
                                 else:       r = b, phi = pi/2 - (pi/4) a/b.
"""

from __future__ import annotations

import math

import numpy as np

from .base import EDGE_TOL, Aperture, as_uv, as_xy


class CircularAperture(Aperture):
    """The unit disc."""

    kind = "circle"

    def inside(self, x, y) -> np.ndarray:
        x, y, ok = as_xy(x, y)
        return ok & (x * x + y * y <= 1.0 + EDGE_TOL)

    def sample(self, u1, u2) -> tuple[np.ndarray, np.ndarray]:
        u1, u2 = as_uv(u1, u2)
        a = 2.0 * u1 - 1.0
        b = 2.0 * u2 - 1.0
        first = np.abs(a) > np.abs(b)
        r = np.where(first, a, b)
        safe_a = np.where(a == 0.0, 1.0, a)
        safe_b = np.where(b == 0.0, 1.0, b)
        phi = np.where(first, (np.pi / 4.0) * (b / safe_a),
                       np.pi / 2.0 - (np.pi / 4.0) * (a / safe_b))
        phi = np.where((a == 0.0) & (b == 0.0), 0.0, phi)
        return r * np.cos(phi), r * np.sin(phi)

    def area(self) -> float:
        return math.pi

    def bounding_radius(self) -> float:
        return 1.0

    def __repr__(self) -> str:
        return "CircularAperture()"
