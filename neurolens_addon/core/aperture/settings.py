"""An aperture shape from the add-on's UI settings (`aperture_from_settings`).

shape (case-insensitive): "circle" (also "circular", "round"), "polygon" ("blades", "iris") or
"image" ("mask", "custom"); blades / rotation_deg / curvature feed the polygon, mask_path (a
PNG) the image mask.
"""

from __future__ import annotations

from ..errors import ApertureError
from .base import Aperture
from .circle import CircularAperture
from .image_mask import ImageMaskAperture, load_mask_image
from .polygon import PolygonAperture

_SHAPES = {
    "circle": "circle", "circular": "circle", "round": "circle",
    "polygon": "polygon", "blades": "polygon", "iris": "polygon",
    "image": "image", "mask": "image", "custom": "image",
}



def aperture_from_settings(shape: str, blades: int = 0, rotation_deg: float = 0.0,
                           curvature: float = 0.0, mask_path=None) -> Aperture:
    """Build an aperture from UI settings.

    shape (case-insensitive): "circle" (also "circular", "round"), "polygon" ("blades",
    "iris") or "image" ("mask", "custom"); blades / rotation_deg / curvature are used by the
    polygon, mask_path (a PNG) by the image mask.
    """
    key = _SHAPES.get(str(shape).strip().lower())
    if key is None:
        raise ApertureError(f"aperture shape must be one of 'circle', 'polygon', 'image', "
                            f"got {shape!r}")
    if key == "circle":
        return CircularAperture()
    if key == "polygon":
        return PolygonAperture(blades, rotation_deg, curvature)
    if mask_path is None or str(mask_path).strip() == "":
        raise ApertureError("aperture shape 'image' needs a mask image file (mask_path)")
    return ImageMaskAperture(load_mask_image(mask_path), source=str(mask_path))
