"""Aperture stop shapes in normalised stop coordinates, and f-number -> stop radius.

Coordinates: (x, y) in the stop plane divided by the current stop radius, so the full circular
opening is the unit disc (base.py: the interface every shape implements: inside,
transmittance, sample, area, bounding_radius, pdf). Shapes, each with its equations:
CircularAperture (circle.py), PolygonAperture, the bladed iris (polygon.py), ImageMaskAperture,
a transmittance image (image_mask.py). f_number.py gives the stop radius for an f-number and
every cache's key of a shape, settings.py a shape from the add-on's UI settings, shader.py the
shape a Cycles camera shader embeds.
"""

from ..errors import ApertureError
from .base import Aperture
from .circle import CircularAperture
from .f_number import aperture_key, clamp_f_number, stop_radius_for_f_number, stop_radius_of
from .image_mask import ImageMaskAperture, load_mask_image
from .polygon import PolygonAperture
from .settings import aperture_from_settings
from .shader import SHADER_MASK_SIDE, shader_shape

__all__ = [
    "Aperture", "ApertureError", "CircularAperture", "ImageMaskAperture", "PolygonAperture",
    "aperture_from_settings", "aperture_key", "clamp_f_number", "load_mask_image",
    "stop_radius_for_f_number", "stop_radius_of", "SHADER_MASK_SIDE", "shader_shape",
]
