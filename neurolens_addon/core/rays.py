"""Ray arrays in lens space, structure-of-arrays, and the codes that say why a ray died.

A ray set holds origins o (3, N), unit directions d (3, N) and wavelengths (N,) in nm.
Structure-of-arrays keeps each component contiguous, so every numpy pass streams memory.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np


class RayStatus(IntEnum):
    """Why a ray is invalid (0 = it made it through)."""

    OK = 0
    BAD_INPUT = 1          # NaN/inf component, zero-length or wrongly oriented direction
    MISSED_SURFACE = 2     # no intersection with the surface's cap (or behind the ray)
    CLIPPED_APERTURE = 3   # outside a surface's semi-diameter
    CLIPPED_STOP = 4       # outside the aperture stop shape
    TOTAL_INTERNAL_REFLECTION = 5
    NO_CONVERGENCE = 6     # aspheric intersection did not converge
    BAD_WAVELENGTH = 7     # outside the glass data or non-finite
    OUT_OF_DOMAIN = 8      # outside the region of ray space a learned lens was trained on


@dataclass
class Rays:
    """A set of N rays in lens space (mm), directions unit length."""

    o: np.ndarray           # (3, N) float64 origins
    d: np.ndarray           # (3, N) float64 unit directions
    wavelength: np.ndarray  # (N,) float64 nm

    @property
    def n(self) -> int:
        return self.o.shape[1]

    @staticmethod
    def from_rows(rows: np.ndarray) -> "Rays":
        """Build from an (N, 7) array of x, y, z, dx, dy, dz, wavelength_nm rows."""
        rows = np.asarray(rows, dtype=np.float64)
        if rows.ndim != 2 or rows.shape[1] != 7:
            raise ValueError(f"expected an N x 7 ray array (x y z dx dy dz wavelength_nm), got shape {rows.shape}")
        return Rays(np.ascontiguousarray(rows[:, 0:3].T), np.ascontiguousarray(rows[:, 3:6].T),
                    np.ascontiguousarray(rows[:, 6]))

    def to_rows(self, valid: np.ndarray | None = None) -> np.ndarray:
        """(N, 7) rows, plus an eighth column 1.0/0.0 for validity when `valid` is given."""
        cols = [self.o.T, self.d.T, self.wavelength[:, None]]
        if valid is not None:
            cols.append(valid.astype(np.float64)[:, None])
        return np.concatenate(cols, axis=1)


@dataclass
class TraceResult:
    """Rays after the lens plus, per ray, whether it is valid, why not, and where it died.

    Invalid rays carry zeros (never NaN) in `rays`.
    """

    rays: Rays
    valid: np.ndarray    # (N,) bool
    status: np.ndarray   # (N,) uint8 RayStatus
    surface: np.ndarray  # (N,) int16 index of the surface where the ray died, -1 if none
    weight: np.ndarray | None = None  # (N,) the path's coating weight (0 where invalid); None
                                      # when traced without a coating

    @property
    def valid_fraction(self) -> float:
        return float(self.valid.mean()) if self.valid.size else 0.0
