"""A lens prescription: surfaces front (scene side) to back (sensor side), as patents list them.

Lens space (DESIGN.md): millimetres, optical axis z, +z points to the scene, the design image
plane (the sensor at the lens's design focus) at z = 0.

Each surface row follows the patent convention:
- `shape`: the surface's kind and parameters (core.surfaces: the equations of each kind). The
  patent columns are properties of every row: `radius_mm`, the signed radius of curvature,
  positive when the centre of curvature lies on the sensor side of the vertex (light travels
  scene -> sensor, i.e. towards -z), `inf` flat; `conic` k and even `aspheric` coefficients,
  which give the sag along the propagation direction
      sag(r) = c r^2 / (1 + sqrt(1 - (1 + k) c^2 r^2)) + sum_j A_2j r^2j,   c = 1 / radius;
  in lens space the surface is the set of points z = vertex_z - sag.
- `thickness_mm`: axial distance from this vertex to the next one (for the last surface: to the
  design image plane).
- `material`: the medium *after* this surface, between it and the next one (air or a glass).
- `semi_diameter_mm`: clear half-aperture; rays farther from the axis are clipped.
- `stop`: the aperture stop (usually a flat air surface); its semi-diameter is the full-aperture
  stop radius of the design f-number. Any kind of surface may be the stop.

Vertex positions follow from the thicknesses: z_last = thickness_last, z_i = z_{i+1} + t_i.
"""

from __future__ import annotations

import dataclasses

import hashlib
import json
import math
from dataclasses import dataclass, field

import numpy as np

from .surfaces import SurfaceShape, rotational

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


def _from_shape(name: str, doc: str) -> property:
    """A read-only Surface attribute answered by its shape."""
    return property(lambda surface: getattr(surface.shape, name), doc=doc)


@dataclass(frozen=True, init=False, repr=False)
class Surface:
    """One row of the prescription: the surface's shape (a surfaces.SurfaceShape: its kind and
    parameters), the axial distance to the next vertex, the medium after it, its clear
    semi-diameter, and whether it is the aperture stop.

    `Surface(radius_mm, thickness_mm, material, semi_diameter_mm, conic=0.0, aspheric=(),
    stop=False)` builds the rotationally symmetric kinds from the patent columns;
    `Surface(shape=..., thickness_mm=..., material=..., semi_diameter_mm=..., stop=...)` takes
    any kind (and `dataclasses.replace` works on the fields below).
    """

    shape: SurfaceShape
    thickness_mm: float
    material: Material
    semi_diameter_mm: float
    stop: bool = False

    def __init__(self, radius_mm: float | None = None, thickness_mm: float | None = None,
                 material: Material | None = None, semi_diameter_mm: float | None = None,
                 conic: float = 0.0, aspheric: tuple[tuple[int, float], ...] = (),
                 stop: bool = False, *, shape: SurfaceShape | None = None):
        if (shape is None) == (radius_mm is None):
            raise TypeError("Surface needs either radius_mm (with conic, aspheric) or shape")
        if shape is not None and (conic != 0.0 or aspheric):
            raise TypeError("Surface: conic and aspheric belong to the shape when shape is given")
        if thickness_mm is None or material is None or semi_diameter_mm is None:
            raise TypeError("Surface needs thickness_mm, material and semi_diameter_mm")
        if shape is None:
            shape = rotational(radius_mm, conic, aspheric)
        for name, value in (("shape", shape), ("thickness_mm", thickness_mm),
                            ("material", material), ("semi_diameter_mm", semi_diameter_mm),
                            ("stop", stop)):
            object.__setattr__(self, name, value)

    def __repr__(self) -> str:
        common = (f"thickness_mm={self.thickness_mm!r}, material={self.material!r}, "
                  f"semi_diameter_mm={self.semi_diameter_mm!r}")
        if self.shape.implied:
            return (f"Surface(radius_mm={self.radius_mm!r}, {common}, conic={self.conic!r}, "
                    f"aspheric={self.aspheric!r}, stop={self.stop!r})")
        return f"Surface(shape={self.shape!r}, {common}, stop={self.stop!r})"

    # ---- the patent columns (every kind answers them; see surfaces.base) ----------------------
    radius_mm = _from_shape("radius_mm", "signed radius of curvature (mm), inf for flat")
    conic = _from_shape("conic", "conic constant k")
    aspheric = _from_shape("aspheric", "even aspheric terms as (power, coefficient) pairs, "
                                       "power in {2, 4, 6, ...}")
    curvature = _from_shape("curvature", "vertex curvature 1 / radius_mm (0 for flat)")
    is_flat = _from_shape("is_plane", "the surface is a plane")

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
    #: gaps that move to focus (internal focusing) or to zoom (core.variable_gaps); None: none
    focus_gaps: "VariableGaps | None" = None
    zoom_gaps: "VariableGaps | None" = None
    #: back focal distance as the source states it (last vertex to the image of infinity, mm)
    back_focus_mm: float | None = None

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
    def anamorphic(self) -> bool:
        """Some surface is not a surface of revolution (core.surfaces.anamorphic)."""
        return any(not s.shape.rotationally_symmetric for s in self.surfaces)

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
                 list(map(list, s.aspheric)), s.stop] + s.shape.hash_fields()
                for s in self.surfaces]
        for name, table in (("focus", self.focus_gaps), ("zoom", self.zoom_gaps)):
            if table is not None:
                rows.append([name, [p if math.isfinite(p) else "inf" for p in table.positions],
                             list(table.surfaces), [list(t) for t in table.thickness_mm]])
                # a zoom's stop column changes the rays (its stated f-numbers do not)
                if table.stop_semi_diameter_mm is not None:
                    rows.append([name + " stop", list(table.stop_semi_diameter_mm)])
        blob = json.dumps(rows, sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]

    def with_surfaces(self, surfaces) -> "Lens":
        return dataclasses.replace(self, surfaces=tuple(surfaces))
