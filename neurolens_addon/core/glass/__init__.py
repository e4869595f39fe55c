"""Glass dispersion: refractive index as a function of wavelength.

Two models, one interface (medium.Medium: `.index(wavelength_nm) -> float64 ndarray`, same
shape as the input; arrays.py: shapes and NaN for bad wavelengths):

1. **Catalog glass** (formulas.Glass), from the manufacturer's published coefficients (shipped
   in ``data/glass/*.toml`` (a file per maker), read by catalog_file, looked up by name in catalog; see
   ``docs/glass-catalog.md``), normally Sellmeier's law

       n(L)^2 = 1 + sum_{i=1..3} B_i L^2 / (L^2 - C_i),     L = wavelength in micrometres,

   or the Schott power series some makers publish instead.

2. **(n_d, V_d) model** (abbe.AbbeGlass), for prescriptions that give only the index and the
   Abbe number (patents usually do): n(L) = A + B / (L^2 - L0^2) through n_d, V_d and
   Schott's normal line of partial dispersion; with ``vd=None`` non-dispersive.

Air (medium.AIR) is the reference medium, index exactly 1.0. `resolve_medium` (media.py) turns
a prescription's Material into one of these.

Pure numpy; this package never imports bpy.
"""

from .abbe import NORMAL_LINE_PGF, AbbeGlass
from .catalog import GlassCatalog
from .catalog_file import (DEFAULT_CATALOG_PATH, ND_TOLERANCE, VD_TOLERANCE, default_catalog,
                           load_catalog)
from .formulas import Glass
from .media import medium_index, resolve_medium
from .medium import AIR, WAVELENGTH_C_NM, WAVELENGTH_F_NM, WAVELENGTH_G_NM, Medium

__all__ = [
    "AIR", "AbbeGlass", "DEFAULT_CATALOG_PATH", "Glass", "GlassCatalog", "ND_TOLERANCE",
    "VD_TOLERANCE", "WAVELENGTH_C_NM", "WAVELENGTH_F_NM", "WAVELENGTH_G_NM", "default_catalog",
    "load_catalog", "medium_index", "resolve_medium", "Medium", "NORMAL_LINE_PGF",
]
