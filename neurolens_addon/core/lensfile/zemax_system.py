"""A `.zmx` file's system data: glass catalogues, wavelengths, fields and entrance pupil.

Read (`read_system`, from the system lines zemax.py collects; ENPD in lens units, scaled to mm):
    GCAT name ...             the glass catalogues, in the order OpticStudio searches them
    FTYP t n nf nw ...        the field type t (0: angles in degrees, 1: object height,
                              2: paraxial image height, 3: real image height, 4: theodolite
                              angles) and how many fields (nf) and wavelengths (nw) are in use
    XFLN / YFLN v ...         the fields' x and y (OpticStudio pads the lines to 12 values);
    XFLD / YFLD v ...         older files: one value a field
    WAVM i w weight           wavelength i in micrometres; older files: WAVL w ... (WWGT weights)
    PWAV i                    the primary wavelength (1-based)
    ENPD d                    the entrance pupil diameter (the aperture type ENPD)
Without FTYP the counts are those of the lines. A value that is not a number (or not an
integer where one is due: at most 9 ASCII digits, lensfile.tokens) is a one-line error naming
the file, the line and the keyword; a
catalogue we do not have is kept and noted (its glass names are looked up in all of ours).

Glass names (`catalogue_material`): a name is looked up in the file's catalogues that we have,
in GCAT order ("CDGM F2" before Schott's F2 when GCAT puts CDGM first); where several of them
list it, the one whose n_d agrees with the GLAS line's (within ND_AGREES) is taken. A name none
of them lists is looked up in our whole catalogue, with a note; a legacy name (SK16) stays as
written so that the lens check reads it as its successor (N-SK16) and says so, as the TOML
reader does. A GLAS line whose n_d is off the catalogue glass's by more than ND_AGREES is noted.

Written (`system_lines`):
    ENPD    the paraxial entrance pupil diameter at n_d: the stop seen through the surfaces
            before it (core.paraxial), so other tools read the f-number the stop gives
    GCAT    the makers of the lens's catalogue glasses, ordered so that each glass name finds
            its own maker's glass first (where some order does)
    FTYP, XFLN, YFLN, FWGN   three field angles 0, 0.7 and 1 times the half field: half the
            stated field of view, else that of a full-frame diagonal at the focal length
            (core.field.half_field_deg), at most MAX_FIELD_DEG (Zemax's angles stay below 90)
    WAVM, PWAV   the F, d and C lines, d the primary (the index data are at n_d)
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

from ..glass.medium import WAVELENGTH_C_NM, WAVELENGTH_F_NM
from ..prescription import WAVELENGTH_D_NM, Lens, Material
from .tokens import shown, to_float, to_int

#: the GLAS line's n_d and the catalogue glass's agree within this
ND_AGREES = 1e-3
#: the largest field angle written (degrees)
MAX_FIELD_DEG = 89.9
#: the wavelengths written (nm): F, d, C; PRIMARY is d (1-based)
WAVELENGTHS_NM = (WAVELENGTH_F_NM, WAVELENGTH_D_NM, WAVELENGTH_C_NM)
PRIMARY = 2
#: OpticStudio writes 12 values on XFLN, YFLN and FWGN
FIELD_SLOTS = 12
_FIELD_TYPES = {0: "angle", 1: "object height", 2: "paraxial image height",
                3: "real image height", 4: "theodolite angle"}


@dataclass(frozen=True)
class ZmxSystem:
    """What a .zmx file says of its glass catalogues, fields, wavelengths and aperture."""

    catalogs: tuple[str, ...] = ()          # GCAT, upper case, in the file's order
    field_type: int | None = None           # FTYP's first value (0: angles in degrees)
    fields_x: tuple[float, ...] = ()
    fields_y: tuple[float, ...] = ()
    wavelengths_um: tuple[float, ...] = ()
    weights: tuple[float, ...] = ()
    primary: int | None = None              # 1-based index into wavelengths_um
    entrance_pupil_mm: float | None = None  # ENPD, in mm

    def largest_field_deg(self) -> float | None:
        """The largest field angle (degrees from the axis; x and y combined as OpticStudio
        does, tan^2 = tan^2 x + tan^2 y), for angle fields; None otherwise."""
        xs = self.fields_x + (0.0,) * (len(self.fields_y) - len(self.fields_x))
        if self.field_type != 0 or not self.fields_y or \
                any(abs(v) >= 90.0 for v in xs + self.fields_y):
            return None
        tans = [math.hypot(math.tan(math.radians(x)), math.tan(math.radians(y)))
                for x, y in zip(xs, self.fields_y)]
        return math.degrees(math.atan(max(tans)))


def _value(token: str, where, lineno: int, key: str, *, integer=False) -> float:
    v = to_int(token) if integer else to_float(token)
    if v is None or not math.isfinite(v):
        what = "an integer" if integer else "a finite number"
        raise where.error(f"line {lineno}: {key}: expected {what}, got '{shown(token)}'",
                          field=key)
    return v


def _row(system, key):
    """(line, tokens) of the keyword's first line, or None."""
    rows = system.get(key)
    return rows[0] if rows else None


def _values(system, key, where, count=None) -> tuple[float, ...]:
    row = _row(system, key)
    if row is None:
        return ()
    lineno, tok = row
    tok = tok if count is None else tok[:count]
    return tuple(_value(t, where, lineno, key) for t in tok)


def read_system(system, where, unit: float, catalog) -> tuple[ZmxSystem, list[str]]:
    """(the file's ZmxSystem, notes) from its system lines {KEY: [(line, tokens)]}."""
    notes: list[str] = []
    catalogs = tuple(t.upper() for _, tok in system.get("GCAT", []) for t in tok)
    if "GCAT" in system:
        known = makers(catalog)
        unknown = [c for c in catalogs if c not in known]
        if not catalogs:
            notes.append("GCAT names no glass catalogue")
        elif unknown:
            listed = ", ".join(shown(c) for c in unknown[:5]) + (", ..." if len(unknown) > 5
                                                                 else "")
            notes.append(f"glass catalogue(s) {listed} (GCAT) are not among ours "
                         f"({', '.join(known)}): their glass names are looked up in ours")

    field_type = n_fields = n_waves = None
    row = _row(system, "FTYP")
    if row is not None:
        lineno, tok = row
        got = [_value(t, where, lineno, "FTYP", integer=True) for t in tok[:4]]
        field_type = got[0] if got else None
        if field_type is not None and field_type not in _FIELD_TYPES:
            raise where.error(f"line {lineno}: FTYP: field type {field_type} is not one of "
                              + ", ".join(f"{k} ({v})" for k, v in _FIELD_TYPES.items()),
                              field="FTYP")
        n_fields = got[2] if len(got) > 2 else None
        n_waves = got[3] if len(got) > 3 else None
        if any(n is not None and n < 0 for n in (n_fields, n_waves)):
            raise where.error(f"line {lineno}: FTYP: negative counts of fields or wavelengths",
                              field="FTYP")
    new = "YFLN" in system or "XFLN" in system
    fields_y = _values(system, "YFLN" if new else "YFLD", where, n_fields)
    fields_x = _values(system, "XFLN" if new else "XFLD", where, len(fields_y))
    if fields_y and field_type is None:
        field_type = 0                      # OpticStudio's default: angles

    waves, weights = _wavelengths(system, where, n_waves)
    primary = None
    row = _row(system, "PWAV")
    if row is not None:
        lineno, tok = row
        primary = _value(tok[0] if tok else "", where, lineno, "PWAV", integer=True)
        if primary < 1 or (waves and primary > len(waves)):
            raise where.error(f"line {lineno}: PWAV {primary}: the file has wavelengths 1 to "
                              f"{len(waves)}" if waves else f"line {lineno}: PWAV {primary}: "
                              "expected a wavelength number >= 1", field="PWAV")
    enpd = None
    row = _row(system, "ENPD")
    if row is not None:
        lineno, tok = row
        enpd = _value(tok[0] if tok else "", where, lineno, "ENPD") * unit
        if not enpd > 0.0:
            raise where.error(f"line {lineno}: ENPD: expected a diameter > 0, got "
                              f"'{shown(tok[0])}'", field="ENPD")
    return ZmxSystem(catalogs, field_type, fields_x, fields_y, waves, weights, primary,
                     enpd), notes


def _wavelengths(system, where, count):
    """(wavelengths um, weights): WAVM records (OpticStudio 13 on), else WAVL and WWGT."""
    found: dict[int, tuple[float, float]] = {}
    for lineno, tok in system.get("WAVM", []):
        if len(tok) < 2:
            raise where.error(f"line {lineno}: WAVM needs an index and a wavelength",
                              field="WAVM")
        i = _value(tok[0], where, lineno, "WAVM", integer=True)
        w = _value(tok[1], where, lineno, "WAVM")
        weight = _value(tok[2], where, lineno, "WAVM") if len(tok) > 2 else 1.0
        if i < 1 or w <= 0.0 or weight < 0.0:
            raise where.error(f"line {lineno}: WAVM {i}: expected an index >= 1, a wavelength "
                              "> 0 and a weight >= 0", field="WAVM")
        found.setdefault(i, (w, weight))
    if found:
        pairs = [found[i] for i in sorted(found) if count is None or i <= count]
    else:
        waves = _values(system, "WAVL", where, count)
        weights = _values(system, "WWGT", where, len(waves))
        pairs = [(w, weights[k] if k < len(weights) else 1.0) for k, w in enumerate(waves)]
        bad = [w for w, _ in pairs if w <= 0.0]
        if bad:
            raise where.error(f"line {system['WAVL'][0][0]}: WAVL: expected wavelengths > 0, "
                              f"got {bad[0]:g}", field="WAVL")
    return tuple(w for w, _ in pairs), tuple(g for _, g in pairs)


def makers(catalog) -> tuple[str, ...]:
    """Our catalogue's makers as Zemax names its catalogues (SCHOTT, OHARA, ...), in the order
    a bare name shared by two makers prefers them."""
    if catalog is None:
        return ()
    from ..glass.catalog import MAKER_PRECEDENCE
    have = {g.manufacturer.upper() for g in catalog}
    order = [m.upper() for m in MAKER_PRECEDENCE if m.upper() in have]
    return tuple(order + sorted(have - set(order)))


def _in(catalog, maker: str, name: str):
    q = f"{maker} {name}"
    return catalog.get(q) if q in catalog else None


def catalogue_material(name: str, nd: float, ours, catalog, label: str,
                       notes: list) -> Material | None:
    """The Material a GLAS name gives (module docstring), or None when no catalogue glass of
    ours answers to it. `ours`: the file's catalogues that we have (GCAT order), `nd` the
    line's n_d (0: none), `label` names the surface in notes."""
    default = catalog.get(name) if name in catalog else None
    hits: list = []
    for maker in ours:
        g = _in(catalog, maker, name)
        if g is not None and g not in hits:
            hits.append(g)
    if hits:
        agree = [g for g in hits if nd >= 1.0 and abs(g.nd - nd) <= ND_AGREES]
        glass = (agree or hits)[0]
    elif default is not None:
        glass = default
        if ours:
            notes.append(f"glass {name} ({label}) is in none of the file's catalogues "
                         f"({' '.join(ours)}): {glass.name} ({glass.manufacturer}) is used")
    else:
        return None
    if nd >= 1.0 and abs(glass.nd - nd) > ND_AGREES:
        notes.append(f"glass {name} ({label}): the file's n_d {nd:g} is not the catalogue's "
                     f"{glass.nd:g} ({glass.name}, {glass.manufacturer}); the catalogue's "
                     "glass is used")
    if glass is default:
        return Material(name)       # as written: the lens check names a successor (SK16)
    canonical = catalog.canonical_name(glass)
    if _bare(canonical) != _bare(name) and _bare(glass.name) != _bare(name):
        notes.append(f"glass {name} ({label}) is read as {canonical}")
    return Material(canonical)


def _bare(name: str) -> str:
    import re
    return re.sub(r"[\s\-_./]+", "", name).upper()


def gcat_order(lens: Lens, catalog) -> tuple[str, ...]:
    """The makers of the lens's catalogue glasses, ordered so that every glass's name finds its
    own maker's glass first (the first such order of MAKER_PRECEDENCE's permutations; that
    order itself where none does)."""
    if catalog is None:
        return ()
    used = []
    for s in lens.surfaces:
        m = s.material
        if m.is_catalog and m.name in catalog:
            g = catalog.get(m.name)
            if g not in used:
                used.append(g)
    present = {g.manufacturer.upper() for g in used}
    base = [m for m in makers(catalog) if m in present]

    def first_hit(order, g):
        return next((h for h in (_in(catalog, m, g.name) for m in order) if h is not None),
                    None)
    if len(base) > 1:
        for order in itertools.permutations(base):
            if all(first_hit(order, g) is g for g in used):
                return tuple(order)
    return tuple(base)


def _num(x: float) -> str:
    return f"{x:.12g}"


def system_lines(lens: Lens, catalog, fmt) -> list[str]:
    """ENPD, GCAT, field and wavelength lines for the lens (module docstring)."""
    from ..field import half_field_deg
    from ..paraxial import paraxial_data
    out = [f"ENPD {fmt(paraxial_data(lens, catalog=catalog).entrance_pupil.diameter_mm)}"]
    gcat = gcat_order(lens, catalog)
    if gcat:
        out.append("GCAT " + " ".join(gcat))
    h = min(half_field_deg(lens), MAX_FIELD_DEG)
    fields = [0.0, 0.7 * h, h]
    pad = FIELD_SLOTS - len(fields)
    out += [f"FTYP 0 0 {len(fields)} {len(WAVELENGTHS_NM)} 0 0 0",
            "XFLN " + " ".join(["0"] * FIELD_SLOTS),
            "YFLN " + " ".join([_num(v) for v in fields] + ["0"] * pad),
            "FWGN " + " ".join(["1"] * FIELD_SLOTS)]
    out += [f"WAVM {k} {_num(nm / 1000.0)} 1" for k, nm in enumerate(WAVELENGTHS_NM, 1)]
    out.append(f"PWAV {PRIMARY}")
    return out
