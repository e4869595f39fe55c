"""Zemax OpticStudio sequential lens files (`.zmx`): import and export.

A `.zmx` file is text (UTF-8, or UTF-16 with a byte-order mark as OpticStudio writes it), one
keyword and its values a line. System lines: `NAME text`, `UNIT MM|CM|IN|METER ...` (lengths
are scaled to mm), `NOTE n text`, `MNUM n` (configurations). Surfaces are blocks opened by
`SURF i`, surface 0 the object and the last the image; between them the lens, front to back:
    TYPE STANDARD | EVENASPH   the kind (any other type is refused by name)
    CURV c                     curvature 1 / R (0: flat); R = 1 / c rounded to 15 significant
                               digits, so a radius written with fewer comes back exactly (our
                               export also keeps R itself: `COMM neurolens radius R`)
    CONI k                     conic constant
    PARM i a                   EVENASPH: the coefficient of r^(2i), i = 1..8 (mm^(1-2i))
    DISZ t                     axial distance to the next surface (INFINITY for the object)
    GLAS NAME s p nd vd ...    the medium after the surface: a catalogue glass by name, or the
                               model glass ___BLANK (n_d, V_d in fields 4 and 5; V_d 0: index
                               only); no GLAS line: air; MIRROR is refused
    DIAM sd                    semi-diameter
    STOP                       the aperture stop
The system lines GCAT (glass catalogues), FTYP, XFLN/YFLN (fields), WAVM/PWAV (wavelengths)
and ENPD are read and written by zemax_system (`loads_zmx_system` gives them): GCAT decides
which maker's glass a name is (in its order), angle fields give a file without our notes its
field of view (twice the largest), and an ENPD the stop does not give (beyond ENPD_AGREES) is
noted. Other keywords (solves, coatings, merit function...) are ignored. The thickness after
the last lens surface is the distance to the image plane, the prescription's last thickness.
A glass name our catalogue lacks becomes its (n_d, V_d) model when the line gives them, with a
note; without them it is an error naming the glass; a legacy name is read as its successor
with a note, as the TOML reader does (SK16 -> N-SK16). Several configurations (`MNUM` > 1)
with multi-configuration `THIC` records are read as a [focus] or [zoom] table (zemax_configs),
and written from ours.

Focal length and f-number: the file's `NOTE` lines that `dump_zmx` writes (`neurolens KEY
VALUE`, VALUE a JSON literal) carry ours (name, source, notes, focal length, f-number, field
of view (null: none stated), closest focus, the [focus] and [zoom] tables), so TOML -> zmx ->
TOML gives the same lens; without them the focal length and f-number come from a paraxial
trace at n_d (core.paraxial) and the name from NAME. A NOTE value is read as the TOML reader
reads the same key (checks.lens_values: booleans are not numbers, NaN and infinities are
refused; gap_tables.gap_table for the tables); its nesting is bounded (MAX_NOTE_DEPTH) before
it is parsed, and a key given twice (two NOTE lines, or twice in one JSON object) is refused.

Hostile text: a line may not hold a control character (a NUL in place of a line break would
merge two surfaces) and numbers are ASCII (lensfile.tokens); MNUM is bounded before anything
is made per configuration (zemax_configs); a surface block that repeats a keyword it is read
for (TYPE, CURV, CONI, DISZ, GLAS, DIAM, STOP) is refused. Every problem is a LensError naming
the file, the line and the field. The ENPD written is the entrance pupil
the stop gives (paraxial, at n_d), not f / N: other tools read the f-number the stop makes.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import replace
from pathlib import Path

from ..errors import LensError
from ..lensfields import Where
from ..prescription import Lens, Material, Surface
from ..surfaces.asphere import rotational
from ..variable_gaps import VariableGaps
from .checks import (_glass_catalog, check_lens, is_named_model, lens_values,
                     renamed_glass_notes)
from .gap_tables import ZOOM_COLUMNS, check_disjoint, gap_table, gap_table_json
from .source import MAX_SURFACES, check_text, read_bytes
from .tokens import check_lines, shown, to_float, to_int
from .zemax_configs import INFINITE_MM, read_configurations, write_configurations
from .zemax_system import (ZmxSystem, catalogue_material, makers, read_system,
                           system_lines)

#: lens units -> mm
UNITS = {"MM": 1.0, "CM": 10.0, "IN": 25.4, "METER": 1000.0}
SUPPORTED_TYPES = ("STANDARD", "EVENASPH")
#: EVENASPH carries the coefficients of r^2 .. r^16
MAX_EVENASPH_POWER = 16
MODEL_GLASS = "___BLANK"
#: a file's ENPD agrees with the stop's paraxial entrance pupil within this fraction
ENPD_AGREES = 1e-2
#: our lens fields kept in NOTE lines
META = ("name", "source", "notes", "focal_length_mm", "f_number", "field_of_view_deg",
        "back_focus_mm", "closest_focus_mm", "focus_gaps", "zoom_gaps")
#: a NOTE line's JSON value nests at most this deep (a gap table: {"thickness_mm": [[...]]}),
#: checked before it is parsed
MAX_NOTE_DEPTH = 4
#: the surface keywords read; a block that repeats one is refused (which would count?)
_ONCE = ("TYPE", "CURV", "CONI", "DISZ", "GLAS", "DIAM", "STOP")
_FIELDS = {"radius": "CURV", "thickness": "DISZ", "material": "GLAS",
           "semi_diameter": "DIAM", "conic": "CONI", "aspheric": "PARM"}


def decode_zmx(data: bytes, where: Where) -> str:
    """A .zmx file's bytes as text: UTF-16 when it starts with a byte-order mark, else
    UTF-8."""
    try:
        if data[:2] in (b"\xff\xfe", b"\xfe\xff"):
            return data.decode("utf-16")
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise where.error(f"file is neither UTF-16 (with a byte-order mark) nor UTF-8 text: "
                          f"undecodable byte at offset {exc.start}") from None
    return text[1:] if text.startswith("\ufeff") else text


def load_zmx(path) -> Lens:
    """Import a Zemax sequential `.zmx` file (module docstring)."""
    return loads_zmx(decode_zmx(read_bytes(path), Where(path)), path=str(path))


def _number(token: str, where: Where, lineno: int, what: str, surface=None, field=None,
            allow_inf=False) -> float:
    v = to_float(token, allow_inf=allow_inf)
    if v is None or not (math.isfinite(v) or (allow_inf and v == math.inf)):
        raise where.error(f"line {lineno}: expected a finite number for {what}, got "
                          f"'{shown(token)}'", surface=surface, field=field)
    return v


def _blocks(text: str, where: Where):
    """(system keywords {KEY: [(line, tokens)]}, surface blocks [{KEY: (line, tokens)}])."""
    system: dict = {}
    blocks: list = []
    for lineno, raw in enumerate(text.splitlines(), 1):
        tokens = raw.split()
        if not tokens:
            continue
        key = tokens[0].upper()
        if key == "SURF":
            if len(blocks) > MAX_SURFACES + 2:
                raise where.error(f"line {lineno}: more than {MAX_SURFACES} surfaces, refusing "
                                  "the file", field="surface")
            blocks.append({"SURF": (lineno, tokens[1:])})
        elif raw[:1].isspace() and blocks:
            block = blocks[-1]
            if key == "PARM":
                block.setdefault("PARM", []).append((lineno, tokens[1:]))
            elif key in _ONCE and key in block:
                raise where.error(f"line {lineno}: a second {key} in the surface block of "
                                  f"line {block['SURF'][0]} (the first is on line "
                                  f"{block[key][0]})", field=key)
            else:
                block.setdefault(key, (lineno, tokens[1:]))
        else:
            system.setdefault(key, []).append((lineno, tokens[1:]))
    return system, blocks


def _kept_radius(block, c: float) -> float | None:
    """The exact radius `dump_zmx` keeps in the surface's comment (`COMM neurolens radius R`),
    when it agrees with the curvature: 1 / (1 / R) need not give R back in floating point."""
    comm = block.get("COMM")
    if comm is None or len(comm[1]) != 3 or comm[1][:2] != ["neurolens", "radius"]:
        return None
    try:
        r = float(comm[1][2])
    except ValueError:
        return None
    return r if math.isfinite(r) and r != 0 and abs(1.0 / r - c) <= 1e-12 * abs(c) else None


def _material(block, where: Where, i: int, notes: list, catalog, gcat) -> Material:
    if "GLAS" not in block:
        return Material.air()
    lineno, tok = block["GLAS"]
    if not tok:
        raise where.error(f"line {lineno}: GLAS without a glass name", surface=i,
                          field="material")
    name = tok[0]
    if name.upper() == "MIRROR":
        raise where.error(f"line {lineno}: mirrors are not supported (a lens here is "
                          "refractive, front to back)", surface=i, field="material")
    nd = _number(tok[3], where, lineno, "n_d", i, "material") if len(tok) > 3 else 0.0
    vd = _number(tok[4], where, lineno, "V_d", i, "material") if len(tok) > 4 else 0.0
    if vd < 0.0:
        raise where.error(f"line {lineno}: V_d must be > 0 (or 0: index only), got {vd:g}",
                          surface=i, field="material")
    if name.upper() == MODEL_GLASS:
        if not nd >= 1.0:
            raise where.error(f"line {lineno}: the model glass needs n_d >= 1, got {nd:g}",
                              surface=i, field="material")
        return Material.from_abbe(nd, vd if vd > 0 else None)
    if catalog is not None:
        found = catalogue_material(name, nd, gcat, catalog, f"surface {i + 1}", notes)
        if found is not None:
            return found
    if nd >= 1.0:
        notes.append(f"glass {name} (surface {i + 1}) is not in the catalogue: modelled by its "
                     f"n_d {nd:g} and V_d {vd:g} from the file")
        return Material(name, nd=nd, vd=vd if vd > 0 else None)
    raise where.error(f"line {lineno}: glass '{name}' is not in the catalogue and the line "
                      "gives no n_d, V_d to model it", surface=i, field="material")


def _surface(block, where: Where, i: int, unit: float, notes: list, catalog,
             gcat=()) -> Surface:
    lineno = block["SURF"][0]
    kind = block.get("TYPE", (lineno, ["STANDARD"]))[1]
    kind = kind[0].upper() if kind else "STANDARD"
    if kind not in SUPPORTED_TYPES:
        raise where.error(f"line {block['TYPE'][0]}: surface type {kind} is not supported "
                          f"(only {' and '.join(SUPPORTED_TYPES)})", surface=i, field="kind")
    c = 0.0
    if "CURV" in block:
        ln, tok = block["CURV"]
        c = _number(tok[0] if tok else "", where, ln, "the curvature", i, "radius") / unit
    radius = math.inf if c == 0.0 else float(f"{1.0 / c:.15g}")
    kept = _kept_radius(block, c)
    if kept is not None:
        radius = kept
    conic = 0.0
    if "CONI" in block:
        ln, tok = block["CONI"]
        conic = _number(tok[0] if tok else "", where, ln, "the conic", i, "conic")
    terms = []
    if kind == "EVENASPH":
        for ln, tok in block.get("PARM", []):
            if len(tok) < 2:
                raise where.error(f"line {ln}: PARM needs an index and a value", surface=i,
                                  field="aspheric")
            k = to_int(tok[0])
            if k is None:
                raise where.error(f"line {ln}: expected an integer PARM index, got "
                                  f"'{shown(tok[0])}'", surface=i, field="aspheric")
            a = _number(tok[1], where, ln, f"PARM {k}", i, "aspheric")
            if not 1 <= k <= MAX_EVENASPH_POWER // 2:
                continue                    # other PARMs of EVENASPH are unused
            if a != 0.0:
                power = 2 * k
                terms.append((power, a * unit ** (1 - power)))
    thickness = 0.0
    if "DISZ" in block:
        ln, tok = block["DISZ"]
        thickness = _number(tok[0] if tok else "", where, ln, "the thickness", i, "thickness",
                            allow_inf=True) * unit
    if "DIAM" not in block:
        raise where.error(f"line {lineno}: no DIAM (semi-diameter)", surface=i,
                          field="semi_diameter")
    ln, tok = block["DIAM"]
    sd = _number(tok[0] if tok else "", where, ln, "the semi-diameter", i,
                 "semi_diameter") * unit
    return Surface(shape=rotational(radius, conic, tuple(sorted(terms))),
                   thickness_mm=thickness,
                   material=_material(block, where, i, notes, catalog, gcat),
                   semi_diameter_mm=sd, stop="STOP" in block)


def _json_depth(raw: str) -> int:
    """How deep a JSON text's arrays and objects nest (brackets inside strings skipped)."""
    depth = deepest = 0
    for m in _JSON_BRACKETS.finditer(raw):
        c = m.group()
        if c in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif c in "]}":
            depth -= 1
    return deepest


_JSON_BRACKETS = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{}]')


class _NotJson(ValueError):
    """A NOTE value with NaN or Infinity (JSON has neither) or a key twice in one object."""


def _refuse_constant(name: str):
    raise _NotJson(f"{name} is not a JSON number")


def _unique_keys(pairs):
    seen = set()
    for k, _ in pairs:
        if k in seen:
            raise _NotJson(f"the key \"{k}\" is given twice")
        seen.add(k)
    return dict(pairs)


def _note_value(raw: str, where: Where, lineno: int, key: str):
    """A NOTE line's JSON value: nesting bounded before it is parsed, NaN, Infinity and keys
    given twice refused (the value's own checks follow: checks.lens_values, _gaps)."""
    if _json_depth(raw) > MAX_NOTE_DEPTH:
        raise where.error(f"line {lineno}: the value of neurolens {key} nests deeper than "
                          f"{MAX_NOTE_DEPTH} levels (ours never do)", field=key)
    try:
        return json.loads(raw, parse_constant=_refuse_constant, object_pairs_hook=_unique_keys)
    except _NotJson as exc:
        raise where.error(f"line {lineno}: the value of neurolens {key}: {exc}",
                          field=key) from None
    except (ValueError, RecursionError):   # (not JSON; an integer of over 4300 digits)
        raise where.error(f"line {lineno}: the value of neurolens {key} is not a JSON literal",
                          field=key) from None


def _meta(system, where: Where) -> dict:
    """Our NOTE lines' values {key: parsed JSON}; a key given twice is refused."""
    out, lines = {}, {}
    for lineno, tok in system.get("NOTE", []):
        if len(tok) >= 3 and tok[1] == "neurolens" and tok[2] in META:
            key = tok[2]
            if key in out:
                raise where.error(f"line {lineno}: neurolens {key} is given twice (first on "
                                  f"line {lines[key]})", field=key)
            out[key], lines[key] = _note_value(" ".join(tok[3:]), where, lineno, key), lineno
    return out


def _unit(system, where: Where) -> float:
    """mm per lens unit (UNIT; mm without it)."""
    if "UNIT" not in system:
        return 1.0
    lineno, tok = system["UNIT"][0]
    name = tok[0].upper() if tok else ""
    if name not in UNITS:
        raise where.error(f"line {lineno}: lens unit '{name}' is not supported (MM, CM, "
                          "IN or METER)", field="UNIT")
    return UNITS[name]


def loads_zmx_system(text: str, path=None) -> ZmxSystem:
    """A `.zmx` text's glass catalogues, fields, wavelengths and entrance pupil, as `loads_zmx`
    reads them (zemax_system)."""
    where = Where(path, fields=_FIELDS, line_word="starts at line")
    check_text(text, where)
    check_lines(text, where)
    system, _ = _blocks(text, where)
    return read_system(system, where, _unit(system, where), _glass_catalog())[0]


def loads_zmx(text: str, path=None) -> Lens:
    """Parse the text of a `.zmx` file; `path` names it in errors and notes."""
    where = Where(path, fields=_FIELDS, line_word="starts at line")
    check_text(text, where)
    check_lines(text, where)
    system, blocks = _blocks(text, where)
    if len(blocks) < 3:
        raise where.error("no lens surfaces: expected SURF blocks (object, lens surfaces, "
                          "image)", field="surface")
    unit = _unit(system, where)
    catalog = _glass_catalog()
    zsys, notes = read_system(system, where, unit, catalog)
    have = makers(catalog)
    gcat = tuple(c for c in zsys.catalogs if c in have)
    lens_blocks = blocks[1:-1]
    where = Where(path, surface_lines=[b["SURF"][0] for b in lens_blocks], fields=_FIELDS,
                  line_word="starts at line")
    surfaces = [_surface(b, where, i, unit, notes, catalog, gcat)
                for i, b in enumerate(lens_blocks)]
    if not any(s.stop for s in surfaces):
        raise where.error("no aperture stop: mark its surface with STOP", field="stop")
    meta = _meta(system, where)
    values = lens_values(meta, where)        # (the TOML reader's checks of the same values)
    object_mm = _object_distance(blocks[0], where, unit)
    focus = zoom = None
    if "focus_gaps" not in meta and "zoom_gaps" not in meta:
        focus, zoom, surfaces, said = read_configurations(
            system, where, unit, surfaces, object_mm,
            lambda s: _paraxial_efl(s, catalog))
        notes += said
    if focus is None and math.isfinite(object_mm):
        notes.append("the file's object distance is ignored: a lens here images from "
                     "infinity to the sensor, and focusing is the camera's")
    file_name = Path(path).name if path is not None else "<text>"
    name = values.get("name")
    if name is None:
        given = " ".join(system.get("NAME", [(0, [])])[0][1])
        name = given or (Path(path).stem if path is not None else "Zemax lens")
    lens = Lens(name=name, source=values.get("source", f"Zemax file {file_name}"),
                focal_length_mm=1.0, f_number=1.0, surfaces=tuple(surfaces),
                field_of_view_deg=(values.get("field_of_view_deg")
                                   if "field_of_view_deg" in meta else _fov(zsys, notes)),
                notes=values.get("notes", ""), path=None if path is None else str(path),
                closest_focus_mm=values.get("closest_focus_mm"),
                back_focus_mm=values.get("back_focus_mm"), focus_gaps=focus, zoom_gaps=zoom)
    for key in ("focus_gaps", "zoom_gaps"):
        if meta.get(key) is not None:
            lens = replace(lens, **{key: _gaps(meta[key], where, key, surfaces,
                                               values.get("f_number"))})
    check_disjoint(lens.focus_gaps, lens.zoom_gaps, where)
    from ..paraxial import paraxial_data
    if "focal_length_mm" in values and "f_number" in values:
        lens = replace(lens, focal_length_mm=values["focal_length_mm"],
                       f_number=values["f_number"])
    else:
        try:
            p = paraxial_data(lens, catalog=catalog)
        except Exception as exc:          # a lens that forms no image: one line, the file's
            raise where.error(f"no paraxial image at n_d ({exc})", field="radius") from None
        if not (math.isfinite(p.efl_mm) and p.efl_mm > 0 and p.f_number > 0):
            raise where.error("the lens forms no real image of a distant object at n_d",
                              field="radius")
        lens = replace(lens, focal_length_mm=p.efl_mm, f_number=p.f_number)
        notes.append(f"focal length {p.efl_mm:.6g} mm and f-number {p.f_number:.4g} from a "
                     "paraxial trace at n_d")
    canonical = check_lens(lens, where)
    notes += renamed_glass_notes(lens.surfaces, canonical)   # (SK16 -> N-SK16, as in TOML)
    lens = lens.with_surfaces(canonical)
    enpd = zsys.entrance_pupil_mm
    if enpd is not None:
        stop_gives = paraxial_data(lens, catalog=catalog).entrance_pupil.diameter_mm
        if not abs(enpd - stop_gives) <= ENPD_AGREES * stop_gives:
            notes.append(f"the file's entrance pupil (ENPD {enpd:.6g} mm) is not the one its "
                         f"stop gives ({stop_gives:.6g} mm, paraxial at n_d): the stop's "
                         "semi-diameter is kept")
    if notes:
        joined = f"Imported from {file_name}: " + "; ".join(notes) + "."
        lens = replace(lens, notes=(lens.notes + " " + joined).strip())
    return lens


def _fov(zsys: ZmxSystem, notes: list) -> float | None:
    """The field of view a file without ours states: twice its largest field angle."""
    half = zsys.largest_field_deg()
    if not half or not 0.0 < half < 90.0:
        return None
    notes.append(f"field of view {2.0 * half:.6g} deg: twice the file's largest field angle")
    return 2.0 * half


def _object_distance(block, where: Where, unit: float) -> float:
    """The object surface's DISZ in mm (inf for INFINITY, none, or >= 1e9)."""
    disz = block.get("DISZ")
    if disz is None or not disz[1] or disz[1][0].upper() == "INFINITY":
        return math.inf
    d = _number(disz[1][0], where, disz[0], "the object distance", None, "thickness",
                allow_inf=True)
    return math.inf if d >= INFINITE_MM else d * unit


def _paraxial_efl(surfaces, catalog) -> float:
    from ..paraxial import paraxial_data
    lens = Lens(name="configuration", source="-", focal_length_mm=1.0, f_number=1.0,
                surfaces=tuple(surfaces))
    try:
        return paraxial_data(lens, catalog=catalog).efl_mm
    except Exception:                     # a configuration that forms no image
        return math.nan


def _gaps(value, where: Where, key: str, surfaces, f_number=None) -> VariableGaps:
    """A focus or zoom table from its NOTE line (the layout dump_zmx writes: positions, the
    0-based surfaces and their thickness_mm columns), checked by the code that checks the
    TOML format's [focus] and [zoom] tables (gap_tables.gap_table): only the layout is read
    here."""
    kind = key.split("_")[0]
    allowed = ("positions", "surfaces", "thickness_mm") + (tuple(ZOOM_COLUMNS)
                                                            if kind == "zoom" else ())
    if not isinstance(value, dict) or not all(k in value for k in allowed[:3]) or \
            any(k not in allowed for k in value):
        raise where.error(f"neurolens {key}: expected an object with {', '.join(allowed)}",
                          field=key)
    positions, numbers, cols = value["positions"], value["surfaces"], value["thickness_mm"]
    if not (isinstance(numbers, list) and isinstance(cols, list)
            and len(numbers) == len(cols)):
        raise where.error(f"neurolens {key}: expected as many thickness_mm columns as "
                          "surfaces", field=key)
    if not all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < len(surfaces)
               for i in numbers):
        raise where.error(f"neurolens {key}: surfaces are 0-based surface numbers (integers "
                          f"0 to {len(surfaces) - 1})", field=key)
    if isinstance(positions, list):        # (JSON has no infinity: ours write "inf")
        positions = [math.inf if p == "inf" else p for p in positions]
    # surface i as the TOML key i + 1: the same checks of number, range and repetition
    columns = [(str(i + 1), col) for i, col in zip(numbers, cols)]
    return gap_table(kind, positions, columns, {k: value[k] for k in ZOOM_COLUMNS if k in value},
                     where, surfaces, f_number)


def _fmt(x: float) -> str:
    return repr(float(x))


def dump_zmx(lens: Lens) -> str:
    """The lens as a sequential `.zmx` text (UTF-8, lengths in mm) that OpticStudio opens
    and `loads_zmx` reads back into an equal lens."""
    for i, s in enumerate(lens.surfaces):
        if not s.shape.rotationally_symmetric:
            raise LensError(f"surface {i + 1} is a {s.shape.kind} surface: the .zmx writer "
                            "writes surfaces of revolution only (STANDARD, EVENASPH)",
                            path=lens.path, surface=i + 1, field="kind")
    catalog = _glass_catalog()
    # (the NAME line is for other tools: what does not print is left out, a line may hold no
    # control character; the name itself travels in a NOTE line, JSON-escaped)
    shown_name = " ".join("".join(c if c.isprintable() else " " for c in lens.name).split())
    out = ["VERS 190500 0 0", "MODE SEQ", f"NAME {shown_name}",
           "UNIT MM X W X CM MR CPMR"]
    out += system_lines(lens, catalog, _fmt)
    for k, key in enumerate(META):
        value = getattr(lens, key)
        if isinstance(value, VariableGaps):
            value = gap_table_json(value)
        if value is not None or key == "field_of_view_deg":
            # (null: the lens states no field; the file's fields are the full frame's)
            out.append(f"NOTE {k} neurolens {key} {json.dumps(value)}")
    out += write_configurations(lens, _fmt)
    out += ["SURF 0", "  TYPE STANDARD", "  CURV 0.0 0 0 0 0 \"\"", "  DISZ INFINITY"]
    for i, s in enumerate(lens.surfaces, 1):
        terms = dict(s.aspheric)
        if any(p > MAX_EVENASPH_POWER for p in terms):
            raise ValueError(f"{lens.name}: surface {i} has terms above r^{MAX_EVENASPH_POWER}, "
                             "which Zemax's EVENASPH cannot hold")
        out.append(f"SURF {i}")
        if s.stop:
            out.append("  STOP")
        out.append(f"  TYPE {'EVENASPH' if terms else 'STANDARD'}")
        c = 0.0 if math.isinf(s.radius_mm) else 1.0 / s.radius_mm
        out.append(f"  CURV {_fmt(c)} 0 0 0 0 \"\"")
        if c:
            out.append(f"  COMM neurolens radius {_fmt(s.radius_mm)}")
        if s.conic:
            out.append(f"  CONI {_fmt(s.conic)}")
        for k in range(1, MAX_EVENASPH_POWER // 2 + 1) if terms else ():
            out.append(f"  PARM {k} {_fmt(terms.get(2 * k, 0.0))}")
        out.append(f"  DISZ {_fmt(s.thickness_mm)}")
        m = s.material
        if not m.is_air:
            if m.is_catalog:
                g = catalog.get(m.name) if catalog is not None and m.name in catalog else None
                nd = g.nd if g is not None else 0.0
                vd = g.vd if g is not None else 0.0
                # the maker's own name ("CDGM F2" is F2 with CDGM in GCAT)
                label = g.name if g is not None else m.name
                out.append(f"  GLAS {label} 0 0 {_fmt(nd)} {_fmt(vd)} 0 0 0 0 0 0")
            else:
                # a named glass modelled by its numbers keeps its name (read back the same way)
                label = (m.name if is_named_model(m) and len(m.name.split()) == 1
                         and m.name.isprintable() else MODEL_GLASS)
                out.append(f"  GLAS {label} {1 if label == MODEL_GLASS else 0} 0 {_fmt(m.nd)} "
                           f"{_fmt(m.vd if m.vd is not None else 0.0)} 0 0 0 0 0 0")
        out.append(f"  DIAM {_fmt(s.semi_diameter_mm)} 1 0 0 1 \"\"")
    n = len(lens.surfaces) + 1
    out += [f"SURF {n}", "  TYPE STANDARD", "  CURV 0.0 0 0 0 0 \"\"", "  DISZ 0.0",
            f"  DIAM {_fmt(lens.surfaces[-1].semi_diameter_mm)} 0 0 0 1 \"\""]
    return "\n".join(out) + "\n"
