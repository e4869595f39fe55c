"""Surface kinds: one class per kind of optical surface, and the registry that names them.

Every kind is a `SurfaceShape` subclass (base.py: the interface, frames and conventions) that
holds everything about it: ray intersection and normal on whole ray arrays, sag, paraxial
curvature, its keys in lens files, and its OSL for the Cycles exact camera. The trace, the
paraxial trace, the lens-file reader, writer and checks, the drawings and the OSL generator ask
a surface's `shape` instead of branching on its kind.

Kinds today:
- "standard" (standard.py): sphere, plane, conic of revolution;
- "even_asphere" (asphere.py): a standard surface plus even polynomial terms;
- "biconic", "cylinder", "toroidal" (anamorphic.py): no rotational symmetry, turned about
  the axis.

A new kind is one new module here: a frozen dataclass subclassing SurfaceShape (or a kind it
extends), decorated with `@register`, imported below.
"""

from .base import BACKWARD_TOLERANCE_MM, CHECK_SAMPLES, SurfaceShape
from .registry import DEFAULT_KIND, kind_class, kind_classes, kinds, register
from .standard import StandardSurface
from .asphere import EvenAsphere, rotational  # noqa: E402,I001 - registers after standard
from .anamorphic import AnamorphicSurface, Biconic, Cylinder, Toroidal  # noqa: E402,I001

__all__ = [
    "AnamorphicSurface", "Biconic", "Cylinder", "Toroidal", "BACKWARD_TOLERANCE_MM", "CHECK_SAMPLES", "DEFAULT_KIND", "EvenAsphere", "StandardSurface",
    "SurfaceShape", "kind_class", "kind_classes", "kinds", "register", "rotational",
]
