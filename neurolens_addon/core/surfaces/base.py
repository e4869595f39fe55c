"""The interface every surface kind implements (`SurfaceShape`).

Frames. Lens space: millimetres, optical axis z, +z towards the scene. A surface sits with its
vertex at z = z_v on the axis; its local coordinate along the propagation direction
(scene -> sensor) is
    s = z_v - z,
and its shape is s = sag(x, y) (sag >= 0 bulges towards the sensor). A ray is o + t d
(d unit) in lens space.

Each kind gives, on whole float64 ray arrays:
- `hit`: the ray parameter t of the surface point the sequential trace uses (the cap through
  the vertex), with a miss mask; a ray may start up to BACKWARD_TOLERANCE_MM behind the
  surface (it starts on the previous one) and still hit it;
- `normal`: a normal (nx, ny, nz) in lens space at the hit point, any length, either
  orientation (the trace normalises it unless `normal_is_unit`, and orients it against the
  ray); grad of F = s - sag(x, y) = z_v - z - sag(x, y) gives (-sag_x, -sag_y, -1);
- `sag(x, y)` for drawings and the lens-file checks;
- `paraxial_curvature`: the curvature the paraxial (y-nu) trace uses, c_p = d^2 sag/dy^2 at
  the vertex, so that sag ~ c_p y^2 / 2 near the axis; the surface's paraxial power between
  indices n and n' is (n' - n) c_p (a surface without rotational symmetry adds
  `paraxial_curvature_x` = d^2 sag/dx^2 and `paraxial_curvature_xy` = d^2 sag/dx dy);
- its keys in a [[surface]] table of the lens file (read, checked, written),
- its OSL source for the Cycles exact camera (float32; constants written with core.oslfmt,
  imported when OSL is asked for: the core never needs the cycles package otherwise), and
- `kernel_params`: its row of the compiled trace's flat surface table (a KERNEL_* code and up
  to KERNEL_PARAMS numbers; surfaces/kernels.py holds the compiled hit and normal of each
  code, core.trace_compiled the trace); None for a kind without one (the trace then takes
  the numpy path for that lens).

The columns every prescription row has had since the first file format (radius_mm, conic,
aspheric) are properties of every kind: they feed Lens.content_hash, the CLI's surface table
and older callers; a kind without them keeps the defaults (flat, 0, none) and must describe
itself in `hash_fields`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np

#: a ray may start this far "behind" a surface (it starts on the previous one) and still hit it
BACKWARD_TOLERANCE_MM = 1e-9
#: the same in the float32 OSL trace (float32 positions ~1e-5 mm apart)
OSL_BACKWARD_TOLERANCE_MM = 1e-4
#: radii sampled in [0, semi-diameter] by the lens-file checks (sag finite, surfaces crossing)
CHECK_SAMPLES = 33

#: the compiled trace's surface codes (kernel_params; surfaces/kernels.py dispatches on them)
KERNEL_PLANE, KERNEL_CONIC, KERNEL_ASPHERE, KERNEL_BICONIC, KERNEL_TOROIDAL = range(5)
#: numbers per row of the compiled trace's surface table (an asphere's: c, c (1 + k), the
#: highest h and A_2 .. A_20)
KERNEL_PARAMS = 13


class SurfaceShape:
    """A surface kind. Subclasses are frozen dataclasses of their parameters (mm, 1/mm)
    registered with `surfaces.register`, so that equal parameters make equal, hashable
    shapes."""

    #: the kind's name in the registry and in a lens file's `kind = "..."`
    kind: ClassVar[str] = ""
    #: lens-file keys this kind needs / may have in a [[surface]] table (besides the keys every
    #: surface has: thickness, material, semi_diameter, stop, kind)
    required_keys: ClassVar[tuple[str, ...]] = ()
    optional_keys: ClassVar[tuple[str, ...]] = ()
    #: a [[surface]] table without `kind` may describe this kind (the writer leaves it out)
    implied: ClassVar[bool] = False
    #: what the exact OSL camera's header table calls it
    label: ClassVar[str] = ""
    #: the surface is a surface of revolution about the axis (the learned lens's radial frame,
    #: the rear-pupil sampler and the .zmx / .dat writers rely on it)
    rotationally_symmetric: ClassVar[bool] = True

    # ---- the columns of the first file format ------------------------------------------------
    radius_mm: float = math.inf
    conic: float = 0.0
    aspheric: tuple = ()

    @property
    def curvature(self) -> float:
        """Vertex curvature 1 / radius_mm (0 for flat)."""
        return 0.0 if math.isinf(self.radius_mm) else 1.0 / self.radius_mm

    @property
    def is_plane(self) -> bool:
        """The surface is the plane z = z_v."""
        return False

    def hash_fields(self) -> list:
        """What Lens.content_hash adds to a surface's row beyond radius, conic and aspheric:
        nothing for kinds those columns describe, else the kind and all its parameters."""
        if self.implied:
            return []
        return [self.kind] + [[f.name, getattr(self, f.name)] for f in dataclasses.fields(self)]

    # ---- geometry --------------------------------------------------------------------------
    def hit(self, zv: float, ox, oy, oz, dx, dy, dz):
        """(t, miss, unconverged or None) for rays o + t d against the surface with its vertex
        at z = zv. t may be anything where miss (or unconverged) is set; the arrays are fresh.
        Called inside np.errstate(invalid, divide, over = "ignore")."""
        raise NotImplementedError

    def intersect(self, zv: float, o, d) -> tuple[np.ndarray, np.ndarray]:
        """(t, valid) for rays o + t d ((3, N) arrays); t is 0 where not valid, never NaN."""
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            t, miss, unconverged = self.hit(zv, o[0], o[1], o[2], d[0], d[1], d[2])
        valid = ~miss if unconverged is None else ~miss & ~unconverged
        return np.where(valid, t, 0.0), valid

    def normal(self, zv: float, x, y, z, rho):
        """(nx, ny, nz): a normal in lens space at surface points (x, y, z), rho = x^2 + y^2;
        nz is a fresh array (the trace normalises in place)."""
        raise NotImplementedError

    #: the normal from `normal` already has unit length (no normalisation needed)
    normal_is_unit: bool = False

    def kernel_params(self) -> tuple[int, tuple[float, ...]] | None:
        """(KERNEL_* code, numbers) of the compiled trace's row for this surface (each kind
        says which numbers), or None where the kind has no compiled twin."""
        return None

    def sag(self, x, y, *, clamp: bool = False) -> np.ndarray:
        """s at (x, y) (mm along the propagation direction; the surface is z = z_v - sag).
        NaN where the surface has no point; with `clamp`, the surface is continued from its
        rim instead (for the lens-file checks)."""
        raise NotImplementedError

    @property
    def paraxial_curvature(self) -> float:
        """c_p = d^2 sag / dy^2 at the vertex (1/mm): the curvature of the y-nu trace."""
        raise NotImplementedError

    @property
    def paraxial_curvature_x(self) -> float:
        """d^2 sag / dx^2 at the vertex: the x meridian's (the y meridian's for a surface of
        revolution)."""
        return self.paraxial_curvature

    @property
    def paraxial_curvature_xy(self) -> float:
        """d^2 sag / dx dy at the vertex: 0 but on a turned anamorphic surface, whose x and y
        meridians couple (core.paraxial)."""
        return 0.0

    # ---- lens file -------------------------------------------------------------------------
    @classmethod
    def from_table(cls, table: dict, fields) -> "SurfaceShape":
        """The shape a [[surface]] table describes (its keys already checked against
        required_keys / optional_keys); lengths multiplied by fields.scale. `fields` is a
        lensfields.SurfaceFields: raise fields.error(message, field) for bad values."""
        raise NotImplementedError

    def check(self, semi_diameter_mm: float, fields) -> None:
        """Raise fields.error(...) if the values cannot make a surface over the semi-diameter
        (for lenses built in code as much as for files)."""

    def toml_items(self) -> list[tuple[str, str]]:
        """(key, TOML value text) of this shape's keys, as `from_table` reads them back."""
        raise NotImplementedError

    # ---- OSL (Cycles exact camera) ----------------------------------------------------------
    def shader_constants(self, semi_diameter_mm: float) -> list[tuple[str, float]]:
        """(lens-file key, value) of the numbers the float32 OSL camera forms from the shape
        (cycles.shader_range checks that each fits float32): the curvature c, c (1 + k) and
        c^2 (1 + k) (the conic's root argument), and an asphere's A_2h, h A_2h and the term's
        sag A_2h rho^h at the rim."""
        c = self.curvature
        out = [("radius", c), ("conic", c * (1.0 + self.conic)),
               ("conic", c * c * (1.0 + self.conic))]
        rim = float(semi_diameter_mm) ** 2
        for power, a in self.aspheric:
            h = int(power) // 2
            out += [("aspheric", a), ("aspheric", h * a), ("aspheric", abs(a) * rim ** h)]
        return out

    @classmethod
    def osl_library(cls) -> list[str]:
        """OSL functions the kind's surfaces call, emitted once per shader (lines)."""
        return []

    def osl_hit(self, index: int, zv: float, sd2: str) -> tuple[list[str], list[str], str]:
        """(functions, body, normal): OSL that moves `point p` along `vector d` to the surface
        (0-based surface `index`, vertex zv) and `return`s where it misses or lies beyond
        rho = sd2 (an OSL literal); then `normal`, an OSL vector expression at p."""
        raise NotImplementedError

    def osl_fused(self, zv: float, sd2: str, eta: str) -> list[str] | None:
        """Body lines that intersect, clip and refract (eta = n_before / n_after) in one call,
        or None where the kind has no such form (then osl_hit and the generic refraction)."""
        return None
