"""The stop shape a Cycles camera shader embeds: OSL holds an image mask as constant arrays of
at most SHADER_MASK_SIDE pixels a side (area-averaged down: ImageMaskAperture.reduced);
circles and bladed irises are embedded as they are. The derived camera (camera.derived)
computes the Cycles camera's centre irradiance and pupil with this shape, so that its image
centre reads 1 with the shape it clips with."""

from __future__ import annotations

from ..errors import ApertureError
from .circle import CircularAperture
from .image_mask import ImageMaskAperture
from .polygon import PolygonAperture

SHADER_MASK_SIDE = 64


def shader_shape(aperture):
    """The shape a shader embeds for `aperture` (None: the circle)."""
    if aperture is None:
        return CircularAperture()
    if isinstance(aperture, ImageMaskAperture):
        return aperture.reduced(SHADER_MASK_SIDE)
    if isinstance(aperture, (CircularAperture, PolygonAperture)):
        return aperture
    raise ApertureError(f"the Cycles camera supports circle, polygon and image-mask apertures, "
                        f"not {type(aperture).__name__}")
