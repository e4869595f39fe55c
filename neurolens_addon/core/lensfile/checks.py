"""The value checks every lens passes, loaded from a file or built in code.

In order: the lens's own numbers (focal length, f-number, field of view, back focus, closest
focus: LENS_VALUES, typed by `lens_values` for the TOML reader and the .zmx NOTE reader alike,
ranged here); at least one and at most MAX_SURFACES surfaces; per surface the material (a
catalog glass, renamed to the catalog's spelling, or (n_d, V_d) within the model's physical
bounds, core.glass.abbe: 1 <= n_d <= 3, 5 <= V_d <= 150); exactly one stop; a [zoom] table's
stop and f-number columns (gap_tables.check_zoom_columns); air after the last surface; then
the lens's geometry (`check_position`): per surface thickness > 0 and semi-diameter > 0
(finite) and its kind's own checks (core.surfaces: radius, conic, terms, semi-diameter within
the surface), no crossing: in the y-z section, at CHECK_SAMPLES radii r in
[0, min(sd_i, sd_i+1)],
    (z_i - sag_i(r)) - (z_i+1 - sag_i+1(r)) = t_i - sag_i(r) + sag_i+1(r) > -OVERLAP_TOLERANCE_MM
(surfaces may touch, not cross), and a paraxial image. The geometry is checked by the same
function at every tabulated position of a [focus] or [zoom] table (core.variable_gaps.lens_at;
each table's positions with the other table at its first): a table whose later position
crosses two surfaces is refused, its message saying which position. The first problem raises
LensError.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..errors import GlassError
from ..glass.abbe import ND_LIMITS, VD_LIMITS
from ..lensfields import SurfaceFields, Where, number, string
from ..prescription import Lens, Material, Surface
from ..surfaces import CHECK_SAMPLES
from .gap_tables import check_zoom_columns
from .source import MAX_SURFACES

#: Consecutive surfaces may touch but not cross by more than this (mm).
OVERLAP_TOLERANCE_MM = 1e-9


def _glass_catalog():
    """The default glass catalog, or None while core/glass is not available."""
    try:
        from ..glass import default_catalog
    except ImportError:
        return None
    return default_catalog()


def _canonical(catalog, glass) -> str | None:
    """The catalogue's spelling of a glass's name: its own, or with its maker where the bare
    name finds another maker's glass ('CDGM F2', not Schott's F2); None if neither finds it."""
    name = catalog.canonical_name(glass) if hasattr(catalog, "canonical_name") else \
        getattr(glass, "name", None)
    try:
        return name if isinstance(name, str) and catalog.get(name) is glass else None
    except GlassError:
        return None


def is_named_model(m: Material) -> bool:
    """A glass given by name together with its (n_d, V_d) (not Material.from_abbe's label)."""
    return m.nd is not None and not m.is_air and not m.name.startswith("nd=")


def unknown_glass_notes(surfaces) -> list[str]:
    """A note for each named glass the catalogue does not know, modelled by its numbers."""
    return [f"glass {s.material.name} (surface {i + 1}) is not in the catalogue: modelled by "
            f"its n_d {s.material.nd:g}" + (f" and V_d {s.material.vd:g}"
                                             if s.material.vd is not None else "")
            for i, s in enumerate(surfaces) if is_named_model(s.material)]


def renamed_glass_notes(given, canonical) -> list[str]:
    """A note for each glass name the catalogue reads as another glass (a legacy name for its
    successor: SK16 -> N-SK16), beyond spelling."""
    import re

    def bare(name):
        return re.sub(r"[\s\-_./]+", "", name).upper()
    return [f"glass {a.material.name} (surface {i + 1}) is read as {b.material.name}"
            for i, (a, b) in enumerate(zip(given, canonical))
            if a.material.name != b.material.name
            and bare(a.material.name) != bare(b.material.name)]


def validate_lens(lens: Lens, path=None) -> None:
    """Check the values of a `Lens` (the same rules `loads_lens` applies); raise LensError."""
    check_lens(lens, Where(path if path is not None else lens.path))


#: the lens's own values, read alike from a TOML file's top level and a .zmx file's NOTE lines:
#: key -> "text" (a non-empty string), "note" (a string) or "number" (its range: _RANGES)
LENS_VALUES = {"name": "text", "source": "text", "notes": "note", "focal_length_mm": "number",
               "f_number": "number", "field_of_view_deg": "number", "back_focus_mm": "number",
               "closest_focus_mm": "number"}
#: the ranges of the lens's numbers: key -> (the test, what the message says is expected)
_RANGES = {
    "focal_length_mm": (lambda v: 0.0 < v < math.inf, "must be a finite number > 0"),
    "f_number": (lambda v: 0.0 < v < math.inf, "must be a finite number > 0"),
    "field_of_view_deg": (lambda v: 0.0 < v <= 360.0, "must be in (0, 360] degrees"),
    "back_focus_mm": (lambda v: 0.0 < v < math.inf, "must be a finite number > 0 mm"),
    "closest_focus_mm": (lambda v: 0.0 < v < math.inf, "must be a finite number > 0 mm"),
}


def lens_values(doc, where) -> dict:
    """The lens's own values (LENS_VALUES) that `doc` gives, typed as the TOML reader types
    them (lensfields.number and string: booleans are not numbers, NaN and infinities are
    refused, an integer too large for a float too); None (a .zmx NOTE's null) is "not stated".
    Their ranges are check_lens's, for every reader."""
    out = {}
    for key, kind in LENS_VALUES.items():
        value = doc.get(key)
        if value is None:
            continue
        out[key] = (number(value, where, field=key) if kind == "number" else
                    string(value, where, field=key, nonempty=(kind == "text")))
    return out


def _check_values(lens: Lens, where) -> None:
    """The lens's numbers, typed and in range (a lens built in code, a .zmx NOTE line)."""
    for key, (ok, expected) in _RANGES.items():
        value = getattr(lens, key)
        if value is None:
            continue
        v = number(value, where, field=key)
        if not ok(v):
            raise where.error(f"{expected}, got {v:g}", field=key)


def _check_material(m: Material, where, i: int) -> None:
    """A material given by its numbers: n_d and V_d within the (n_d, V_d) model's physical
    bounds (core.glass.abbe: ND_LIMITS, VD_LIMITS)."""
    lo, hi = ND_LIMITS
    if not (math.isfinite(m.nd) and lo <= m.nd <= hi):
        raise where.error(f"refractive index nd must be in [{lo:g}, {hi:g}] (no material is "
                          f"transparent across the visible outside it), got {m.nd:g}",
                          surface=i, field="material")
    lo, hi = VD_LIMITS
    if m.vd is not None and not (math.isfinite(m.vd) and lo <= m.vd <= hi):
        raise where.error(f"Abbe number vd must be in [{lo:g}, {hi:g}] (the dispersion of real "
                          f"glasses and crystals; leave it out for a non-dispersive material), "
                          f"got {m.vd:g}", surface=i, field="material")


def check_lens(lens: Lens, where: Where) -> list[Surface]:
    """Raise LensError for the first problem; return the surfaces with catalog names canonical.

    Order: the lens's values, the surface count, each surface's material, the stop, the
    [zoom] columns, the last medium; then the geometry of the lens as it stands (check_position)
    and again at every other tabulated zoom and focus position.
    """
    _check_values(lens, where)
    surfaces = list(lens.surfaces)
    if not surfaces:
        raise where.error("the lens has no surfaces: add [[surface]] tables, front to back",
                          field="surface")
    if len(surfaces) > MAX_SURFACES:
        raise where.error(f"{len(surfaces)} surfaces; at most {MAX_SURFACES} are allowed",
                          field="surface")

    catalog = None
    catalog_loaded = False
    for i, s in enumerate(surfaces):
        m = s.material
        if m.is_air:
            pass
        elif m.nd is not None:
            _check_material(m, where, i)
            if is_named_model(m):
                # a glass named with its (n_d, V_d): the catalogue's glass when it knows it
                if not catalog_loaded:
                    catalog, catalog_loaded = _glass_catalog(), True
                if catalog is not None and m.name in catalog:
                    surfaces[i] = replace(s, material=Material(
                        _canonical(catalog, catalog.get(m.name)) or m.name))
        else:
            if not catalog_loaded:
                catalog, catalog_loaded = _glass_catalog(), True
            if catalog is not None:
                try:
                    glass = catalog.get(m.name)
                except GlassError as exc:
                    text = str(exc)
                    if m.name not in text:
                        text = f"unknown glass '{m.name}': {text}"
                    raise where.error(text, surface=i, field="material") from None
                canonical = _canonical(catalog, glass)
                if isinstance(canonical, str) and canonical != m.name:
                    surfaces[i] = replace(s, material=Material(canonical))

    stops = [i for i, s in enumerate(surfaces) if s.stop]
    if not stops:
        raise where.error("no aperture stop: mark exactly one surface with stop = true",
                          field="stop")
    if len(stops) > 1:
        raise where.error(f"more than one aperture stop (surfaces "
                          f"{', '.join(str(j + 1) for j in stops)}): exactly one surface may "
                          "have stop = true", surface=stops[1], field="stop")
    check_zoom_columns(lens.zoom_gaps, surfaces, None, where, first=False)
    if not surfaces[-1].material.is_air:
        raise where.error(f"the last surface must be followed by air (the medium up to the "
                          f"image plane), got '{surfaces[-1].material.name}'",
                          surface=len(surfaces) - 1, field="material")

    checked = lens.with_surfaces(surfaces)
    check_position(checked, where, catalog)
    for kind, k, moved in _other_positions(checked):
        table = getattr(checked, f"{kind}_gaps")
        check_position(moved, where.within(
            f"at the [{kind}] table's position {k + 1} ({table.positions[k]:g} mm)"), catalog)
    return surfaces


def _other_positions(lens: Lens):
    """(kind, k, the lens at position k) for every tabulated position but the first, each
    table's with the other table at its first position (a gap moves with one table only).
    Only the geometry is asked of these lenses: their f-number is not worked out."""
    from ..variable_gaps import lens_at
    for kind in ("zoom", "focus"):
        table = getattr(lens, f"{kind}_gaps")
        if table is not None:
            for k in range(1, table.count):
                yield kind, k, lens_at(lens, **{kind: float(k)}, design_f_number=False)


def check_position(lens: Lens, where: Where, catalog=None) -> None:
    """The geometry of a lens as it stands, at any of its positions: per surface thickness
    > 0 and semi-diameter > 0 (finite) and the kind's own checks; no crossing of consecutive
    surfaces (module docstring); and a paraxial image (a lens that images nothing, a window or
    a stop alone, is refused here, not by a division by zero in whatever first asks for its
    focal length). The first problem raises LensError."""
    surfaces = lens.surfaces
    for i, s in enumerate(surfaces):
        t = s.thickness_mm
        if not (math.isfinite(t) and t > 0.0):
            what = ("the distance from the last vertex to the design image plane"
                    if i == len(surfaces) - 1 else "the axial distance to the next vertex")
            raise where.error(f"thickness must be a finite number > 0 mm ({what}), got {t:g}",
                              surface=i, field="thickness", scaled=True)
        sd = s.semi_diameter_mm
        if not (math.isfinite(sd) and sd > 0.0):
            raise where.error(f"semi_diameter must be a finite number > 0 mm, got {sd:g}",
                              surface=i, field="semi_diameter", scaled=True)
        s.shape.check(sd, SurfaceFields(where, i))

    for i in range(len(surfaces) - 1):
        a, b = surfaces[i], surfaces[i + 1]
        r = np.linspace(0.0, min(a.semi_diameter_mm, b.semi_diameter_mm), CHECK_SAMPLES)
        with np.errstate(over="ignore", invalid="ignore"):
            # (z_i - sag_i) - (z_i+1 - sag_i+1) with z_i - z_i+1 = t_i
            gap = (a.thickness_mm - a.shape.sag(0.0, r, clamp=True)
                   + b.shape.sag(0.0, r, clamp=True))
        bad = ~(gap > -OVERLAP_TOLERANCE_MM)
        if np.any(bad):
            k = int(np.argmax(bad))
            raise where.error(
                f"surfaces {i + 1} and {i + 2} cross: at r = {r[k]:.4g} mm surface {i + 2} lies "
                f"{-gap[k]:.4g} mm in front of surface {i + 1}; increase thickness of surface "
                f"{i + 1} or reduce the semi_diameters", surface=i, field="thickness",
                scaled=True)

    from ..errors import LensError
    from ..paraxial import paraxial_data
    try:
        paraxial_data(lens, catalog=catalog)
    except LensError as exc:
        raise where.error(exc.message, field="surface") from None
    except GlassError as exc:
        raise where.error(str(exc), field="material") from None
    except ArithmeticError as exc:
        # (a pupil of zero size or at a ratio 0 / 0: every user of the lens asks for its
        # first-order data, so a lens without them is refused here, in one line)
        raise where.error(f"its first-order data cannot be worked out ({type(exc).__name__}: "
                          f"{exc}): are its thicknesses and semi-diameters in mm?",
                          field="surface") from None
