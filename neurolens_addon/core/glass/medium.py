"""The interface of every medium (`Medium`: name, n_d, V_d, index(wavelength)) and air.

Air is the reference medium: lens data (and catalog indices) are relative to air, so air has
index exactly 1.0 (NaN only where the wavelength is invalid). The Abbe number of any medium
follows from its own law at the d, F and C lines:
    V_d = (n_d - 1) / (n_F - n_C).
"""

from __future__ import annotations

import math

import numpy as np

from ..prescription import WAVELENGTH_D_NM
from .arrays import as_wavelengths, nan_bad, output, shaped

#: Fraunhofer / spectral lines used by the (n_d, V_d) model (nm).
WAVELENGTH_F_NM = 486.1327
WAVELENGTH_C_NM = 656.2725
WAVELENGTH_G_NM = 435.8343


class Medium:
    """Common interface: name, manufacturer, nd, vd, source, wavelength_range_nm, index()."""

    name: str
    manufacturer: str
    nd: float
    vd: float | None
    source: str
    wavelength_range_nm: tuple[float, float]

    def index(self, wavelength_nm, out: np.ndarray | None = None
              ) -> np.ndarray:  # pragma: no cover - abstract
        """Refractive index at `wavelength_nm` (any shape; float64 result of the same shape).

        `out`, if given, is a float64 array of that shape that receives the result.
        NaN where the wavelength is not finite or not positive.
        """
        raise NotImplementedError

    def __call__(self, wavelength_nm, out: np.ndarray | None = None) -> np.ndarray:
        return self.index(wavelength_nm, out)

    def abbe_from_index(self) -> tuple[float, float]:
        """(n_d, V_d) computed from this medium's own dispersion law."""
        n = self.index(np.array([WAVELENGTH_D_NM, WAVELENGTH_F_NM, WAVELENGTH_C_NM]))
        nd, nf, nc = (float(v) for v in n)
        vd = math.inf if nf == nc else (nd - 1.0) / (nf - nc)
        return nd, vd

    def __repr__(self) -> str:
        vd = "None" if self.vd is None else f"{self.vd:.2f}"
        return f"{type(self).__name__}({self.name!r}, nd={self.nd:.5f}, vd={vd})"


class _Air(Medium):
    """The reference medium: index exactly 1 (NaN only where the wavelength is invalid)."""

    def __init__(self):
        self.name = "air"
        self.manufacturer = ""
        self.nd = 1.0
        self.vd = None
        self.source = "reference medium (lens data are relative to air)"
        self.wavelength_range_nm = (0.0, math.inf)

    def index(self, wavelength_nm, out: np.ndarray | None = None) -> np.ndarray:
        w = as_wavelengths(wavelength_nm)
        n = output(out, w)
        n.fill(1.0)
        return shaped(nan_bad(n, w), wavelength_nm)


AIR = _Air()
