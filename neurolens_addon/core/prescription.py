"""A lens prescription: surfaces front (scene side) to back (sensor side), as patents list them.

Lens space (DESIGN.md): millimetres, optical axis z, +z points to the scene, the design image
plane (the sensor at the lens's design focus) at z = 0.

Each surface row follows the patent convention:
- `radius_mm`: signed radius of curvature, positive when the centre of curvature lies on the
  sensor side of the vertex (light travels scene -> sensor, i.e. towards -z); `inf` is flat.
- `thickness_mm`: axial distance from this vertex to the next one (for the last surface: to the
  design image plane).
- `material`: the medium *after* this surface, between it and the next one (air or a glass).
- `semi_diameter_mm`: clear half-aperture; rays farther from the axis are clipped.
- `conic` k and even `aspheric` coefficients give the sag along the propagation direction
      sag(r) = c r^2 / (1 + sqrt(1 - (1 + k) c^2 r^2)) + sum_j A_2j r^2j,   c = 1 / radius
  and in lens space the surface is the set of points z = vertex_z - sag(r).
- `stop`: the aperture stop (usually a flat air surface); its semi-diameter is the full-aperture
  stop radius of the design f-number.

Vertex positions follow from the thicknesses: z_last = thickness_last, z_i = z_{i+1} + t_i.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field

import numpy as np

#: Wavelength of the helium d line, where n_d is defined (nm).
WAVELENGTH_D_NM = 587.5618


@dataclass(frozen=True)
class Material:
    """The medium after a surface: air, a catalog glass by name, or a glass known by (n_d, V_d).

    `vd` may be None for an index-only (non-dispersive) material, e.g. from a pbrt .dat file.
    """

    name: str
    nd: float | None = None
    vd: float | None = None

    @property
    def is_air(self) -> bool:
        return self.name.lower() == "air"

    @staticmethod
    def air() -> "Material":
        return Material("air")

    @staticmethod
    def from_abbe(nd: float, vd: float | None) -> "Material":
        label = f"nd={nd:g}" + (f",vd={vd:g}" if vd is not None else "")
        return Material(label, nd=float(nd), vd=None if vd is None else float(vd))

    @property
    def is_catalog(self) -> bool:
        return not self.is_air and self.nd is None


@dataclass(frozen=True)
class Surface:
    radius_mm: float
    thickness_mm: float
    material: Material
    semi_diameter_mm: float
    conic: float = 0.0
    #: even aspheric terms as (power, coefficient) pairs, power in {2, 4, 6, ...}
    aspheric: tuple[tuple[int, float], ...] = ()
    stop: bool = False

    @property
    def curvature(self) -> float:
        return 0.0 if math.isinf(self.radius_mm) else 1.0 / self.radius_mm

    @property
    def is_flat(self) -> bool:
        return math.isinf(self.radius_mm) and not self.aspheric

    @property
    def is_aspheric(self) -> bool:
        return bool(self.aspheric) or self.conic != 0.0


@dataclass(frozen=True)
class Lens:
    """A whole prescription plus the designer's stated figures (checked, not trusted)."""

    name: str
    source: str
    focal_length_mm: float
    f_number: float
    surfaces: tuple[Surface, ...]
    #: full field of view the design covers (degrees, diagonal), if stated by the source
    field_of_view_deg: float | None = None
    notes: str = ""
    path: str | None = field(default=None, compare=False)
    #: closest focus (object distance from the sensor, mm) as the source states it; None: derived
    closest_focus_mm: float | None = None

    # ---- derived geometry -------------------------------------------------------------------
    @property
    def vertex_z(self) -> np.ndarray:
        """z of each surface vertex in lens space (design image plane at z = 0)."""
        t = np.array([s.thickness_mm for s in self.surfaces], dtype=np.float64)
        return np.cumsum(t[::-1])[::-1]

    @property
    def stop_index(self) -> int:
        for i, s in enumerate(self.surfaces):
            if s.stop:
                return i
        raise ValueError(f"lens '{self.name}' has no aperture stop")

    @property
    def stop_radius_mm(self) -> float:
        return self.surfaces[self.stop_index].semi_diameter_mm

    @property
    def rear_vertex_z(self) -> float:
        return float(self.surfaces[-1].thickness_mm)

    @property
    def front_vertex_z(self) -> float:
        return float(self.vertex_z[0])

    @property
    def total_track_mm(self) -> float:
        return self.front_vertex_z

    def media(self) -> list[Material]:
        """Medium before each surface (scene side), plus the one after the last: n+1 entries."""
        return [Material.air()] + [s.material for s in self.surfaces]

    def content_hash(self) -> str:
        """A stable hash of everything that changes the rays (not the name or the source)."""
        rows = [[s.radius_mm if math.isfinite(s.radius_mm) else "inf", s.thickness_mm,
                 s.material.name, s.material.nd, s.material.vd, s.semi_diameter_mm, s.conic,
                 list(map(list, s.aspheric)), s.stop] for s in self.surfaces]
        blob = json.dumps(rows, sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]

    def with_surfaces(self, surfaces) -> "Lens":
        return Lens(self.name, self.source, self.focal_length_mm, self.f_number, tuple(surfaces),
                    self.field_of_view_deg, self.notes, self.path, self.closest_focus_mm)
