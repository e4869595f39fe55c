"""The media of a prescription resolved to dispersion laws: air, a catalog glass by name, or
(n_d, V_d).

A Material with nd None is a catalog glass; given numbers win over a name that is also in the
catalog. Resolved AbbeGlass objects are cached, so a lens's media resolve to the same objects
every time.
"""

from __future__ import annotations

import numpy as np

from ..prescription import Material
from .abbe import AbbeGlass
from .catalog import GlassCatalog
from .catalog_file import default_catalog
from .medium import AIR, Medium


def resolve_medium(material: Material, catalog: GlassCatalog | None = None) -> Medium:
    """The dispersion law of a prescription medium, resolved once: an object with .index(wl).

    air -> index exactly 1; a catalog name (material.nd is None) -> that catalog glass;
    (n_d, V_d) -> AbbeGlass (non-dispersive when V_d is None), even if the name is also a catalog
    name: given numbers win. An unknown name raises GlassError. The returned objects are shared
    (catalog glasses, AIR, cached AbbeGlass): call .index(), never mutate them.
    """
    if material.is_air:
        return AIR
    if material.nd is None:
        cat = catalog if catalog is not None else default_catalog()
        return cat.get(material.name)
    key = (material.nd, material.vd, material.name)
    medium = _ABBE_CACHE.get(key)
    if medium is None:
        medium = AbbeGlass(material.nd, material.vd, name=material.name)
        if len(_ABBE_CACHE) < 4096:
            _ABBE_CACHE[key] = medium
    return medium


_ABBE_CACHE: dict = {}


def medium_index(material: Material, wavelength_nm, catalog: GlassCatalog | None = None
                 ) -> np.ndarray:
    """Refractive index (relative to air) of a prescription medium at the given wavelengths."""
    return resolve_medium(material, catalog).index(wavelength_nm)
