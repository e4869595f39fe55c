"""The `[focus]` and `[zoom]` tables of our lens format: gaps that move (core.variable_gaps).

    [focus]                                   # internal focusing
    distances_mm = [inf, 850.0]               # object distances from the sensor, inf first,
                                              # then nearer and nearer (the last: closest focus)
    thickness = { 12 = [4.51, 9.7], 16 = [20.0, 14.81] }   # surface number -> per distance

    [zoom]
    focal_lengths_mm = [24.7, 50.0, 82.5]     # the stated focal lengths, ascending
    thickness = { 5 = [2.47, 16.71, 29.31] }

Each moving surface's own `thickness` in its [[surface]] table is the table's first position
(infinity, or the shortest focal length), so a reader that ignores these tables still has a
working lens. Lengths are multiplied by `scale` like every other length.

A [zoom] table may also carry, one value per focal length,
    stop_semi_diameter = [9.0114, 11.0392, 12.6069]  # the stop's semi-diameter (mm; the first
                                                   # is the stop surface's own semi_diameter)
    f_numbers = [2.91, 2.91, 2.91]                 # the stated f-numbers (the first is the
                                                   # file's f_number)
(core.variable_gaps: the iris of a constant-aperture zoom opens as it zooms).

A table holds at most MAX_POSITIONS positions (core.variable_gaps), counted before any value
is converted. A surface key is 1 to the number of surfaces in ASCII digits: "06" is surface 6,
and a surface named twice ("6" and "06") is refused, as are "\u00b3", "\u0666" and "+6". The
same function (`gap_table`) checks a table read from TOML and one read from a .zmx NOTE line
(zemax._gaps); checks.check_lens then validates the lens at every position of the table.
"""

from __future__ import annotations

import math

from ..lensfields import check_keys, describe, number, toml_float
from ..variable_gaps import MAX_POSITIONS, VariableGaps

#: table -> (its positions key, what a position is)
KINDS = {"focus": ("distances_mm", "an object distance from the sensor in mm"),
         "zoom": ("focal_lengths_mm", "a focal length in mm")}
#: the [zoom] table's optional per-position columns: key -> (VariableGaps field, a length?)
ZOOM_COLUMNS = {"f_numbers": ("f_numbers", False),
                "stop_semi_diameter": ("stop_semi_diameter_mm", True)}


def read_gap_table(doc: dict, kind: str, where, surfaces) -> VariableGaps | None:
    """The `[focus]` or `[zoom]` table of a parsed lens file, checked, or None."""
    if kind not in doc:
        return None
    table = doc[kind]
    pos_key, _ = KINDS[kind]
    if not isinstance(table, dict):
        raise where.error(f"expected a [{kind}] table, got {describe(table)}", field=kind)
    optional = tuple(ZOOM_COLUMNS) if kind == "zoom" else ()
    check_keys(table, (pos_key, "thickness") + optional, (pos_key, "thickness"), where,
               f"[{kind}]")
    gaps = table["thickness"]
    if not isinstance(gaps, dict) or not gaps:
        raise where.error("expected a table of surface number = [thickness per position]",
                          field=f"{kind}.thickness")
    f_number = doc.get("f_number")     # (checked by the lens's checks; a number or not here)
    return gap_table(kind, table[pos_key], list(gaps.items()),
                     {k: table[k] for k in optional if k in table}, where, surfaces,
                     f_number if isinstance(f_number, (int, float))
                     and not isinstance(f_number, bool) else None)


def _surface_number(key, where, kind: str, n_surfaces: int) -> int:
    """The 0-based surface a table key names: 1 to n_surfaces in ASCII digits ("06" is 6;
    "\u00b3", "\u0663" and "+6" are not surface numbers)."""
    field = f"{kind}.thickness.{key}"
    text = key if isinstance(key, str) else ""
    if not (0 < len(text) <= 9 and text.isascii() and text.isdigit()
            and 1 <= int(text) <= n_surfaces):
        raise where.error(f"'{key}' is not a surface number (1 to {n_surfaces})",
                          field=field)
    return int(text) - 1


def gap_table(kind: str, raw_positions, columns, extra: dict, where, surfaces,
              f_number=None) -> VariableGaps:
    """A `[focus]` or `[zoom]` table, checked, from its parts as a file gives them (the TOML
    reader's table, a .zmx NOTE line: zemax._gaps): the positions, the columns as
    [(surface key, thicknesses)], the [zoom] table's optional columns `extra`, and the file's
    f-number (None: not known). Lengths are counted before anything is converted: at most
    MAX_POSITIONS positions (core.variable_gaps), one column per surface."""
    pos_key, what = KINDS[kind]
    if not isinstance(raw_positions, list) or len(raw_positions) < 2:
        raise where.error(f"expected a list of at least 2 positions ({what} each), got "
                          f"{describe(raw_positions)}", field=f"{kind}.{pos_key}")
    if len(raw_positions) > MAX_POSITIONS:
        raise where.error(f"{len(raw_positions)} positions; a table holds at most "
                          f"{MAX_POSITIONS}", field=f"{kind}.{pos_key}")
    scale = where.scale
    positions = [number(v, where, field=f"{kind}.{pos_key}", allow_inf=(kind == "focus"))
                 * scale for v in raw_positions]
    if kind == "focus":
        if not math.isinf(positions[0]):
            raise where.error("the first focus position must be inf (the design at infinity, "
                              "as its [[surface]] thicknesses are)", field=f"focus.{pos_key}")
        rest = positions[1:]
        if not all(p > 0 and math.isfinite(p) for p in rest) or \
                any(b >= a for a, b in zip(rest, rest[1:])):
            raise where.error("after inf, focus distances must be finite, > 0 and decreasing "
                              "(nearer and nearer)", field=f"focus.{pos_key}")
    elif not all(0 < p < math.inf for p in positions) or \
            any(b <= a for a, b in zip(positions, positions[1:])):
        raise where.error("focal lengths must be finite, > 0 and increasing",
                          field=f"zoom.{pos_key}")
    if not columns:
        raise where.error("expected a table of surface number = [thickness per position]",
                          field=f"{kind}.thickness")
    if len(columns) > len(surfaces):
        raise where.error(f"{len(columns)} columns for a lens of {len(surfaces)} surfaces",
                          field=f"{kind}.thickness")
    indices, values, keys = [], [], {}
    for key, column in columns:
        field = f"{kind}.thickness.{key}"
        i = _surface_number(key, where, kind, len(surfaces))
        if i in keys:
            # "3" and "03" name one surface: which column would count?
            raise where.error(f"'{key}' and '{keys[i]}' are both surface {i + 1}"
                              if key != keys[i] else f"surface {i + 1} is given twice",
                              surface=i, field=field)
        keys[i] = key
        if not isinstance(column, list) or len(column) != len(positions):
            raise where.error(f"expected {len(positions)} thicknesses (one per position), got "
                              f"{describe(column)}", surface=i, field=field)
        col = [number(v, where, surface=i, field=field) * scale for v in column]
        if not all(0 < v < math.inf for v in col):
            raise where.error("every thickness must be finite and > 0 mm", surface=i,
                              field=field)
        own = surfaces[i].thickness_mm
        if not math.isclose(col[0], own, rel_tol=1e-12, abs_tol=1e-12):
            raise where.error(f"the first position's thickness {col[0]:g} differs from the "
                              f"surface's own thickness {own:g}: the [[surface]] tables hold "
                              "the first position", surface=i, field=field)
        indices.append(i)
        values.append(tuple(col))
    order = sorted(range(len(indices)), key=indices.__getitem__)
    extra_columns = {}
    for key, raw in extra.items():
        name, is_length = ZOOM_COLUMNS[key]
        extra_columns[name] = _column(raw, len(positions), where, f"zoom.{key}",
                                      scale if is_length else 1.0)
    out = VariableGaps(tuple(positions), tuple(indices[k] for k in order),
                       tuple(values[k] for k in order), **extra_columns)
    if kind == "zoom":
        check_zoom_columns(out, surfaces, f_number, where)
    return out


def _column(raw, n: int, where, field: str, scale: float) -> tuple[float, ...]:
    """A per-position column of a [zoom] table: n finite numbers > 0, times scale."""
    if not isinstance(raw, list) or len(raw) != n:
        raise where.error(f"expected {n} values (one per focal length), got {describe(raw)}"
                          + (f" of {len(raw)}" if isinstance(raw, list) else ""), field=field)
    values = tuple(number(v, where, field=field) * scale for v in raw)
    if not all(0.0 < v < math.inf for v in values):
        raise where.error("every value must be finite and > 0", field=field)
    return values


def check_zoom_columns(table: VariableGaps | None, surfaces, f_number, where, *,
                       first=True) -> None:
    """The [zoom] table's per-position columns: one value per position, each > 0; with
    `first`, the stop's first semi-diameter is the stop surface's own and the first stated
    f-number the file's f_number (None: not checked), as a file holds them (a moved lens,
    core.variable_gaps.lens_at, stands elsewhere: checks.check_lens checks the columns only)."""
    if table is None:
        return
    n = table.count
    for name, key in (("stop_semi_diameter_mm", "stop_semi_diameter"),
                      ("f_numbers", "f_numbers")):
        col = getattr(table, name)
        if col is not None and (len(col) != n or not all(
                isinstance(v, (int, float)) and math.isfinite(v) and v > 0.0 for v in col)):
            raise where.error(f"expected {n} finite values > 0 (one per focal length), got "
                              f"{list(col)!r}", field=f"zoom.{key}")
    if not first:
        return
    stops = [i for i, sf in enumerate(surfaces) if sf.stop]
    if table.stop_semi_diameter_mm is not None and len(stops) == 1:   # (else check_lens says)
        stop = stops[0]
        r0, own = table.stop_semi_diameter_mm[0], surfaces[stop].semi_diameter_mm
        if not math.isclose(r0, own, rel_tol=1e-12, abs_tol=1e-12):
            raise where.error(f"the first position's stop semi-diameter {r0:g} differs from the "
                              f"stop surface's own semi_diameter {own:g}: the [[surface]] "
                              "tables hold the first position", surface=stop,
                              field="zoom.stop_semi_diameter")
    if table.f_numbers is not None and f_number is not None and \
            not math.isclose(table.f_numbers[0], f_number, rel_tol=1e-9):
        raise where.error(f"the first position's f-number {table.f_numbers[0]:g} differs from "
                          f"the file's f_number {f_number:g} (the stated f-number of the first "
                          "position)", field="zoom.f_numbers")


def check_disjoint(focus: VariableGaps | None, zoom: VariableGaps | None, where) -> None:
    """A gap is either focused or zoomed: a surface in both tables is refused (the focus
    table's thicknesses would overwrite the zoom's)."""
    if focus is None or zoom is None:
        return
    both = sorted(set(focus.surfaces) & set(zoom.surfaces))
    if both:
        raise where.error(f"surface {both[0] + 1} is in both the [focus] and the [zoom] table: "
                          "a gap moves for one of them", surface=both[0],
                          field="focus.thickness")


def write_gap_table(kind: str, table: VariableGaps) -> list[str]:
    """TOML lines of a `[focus]` or `[zoom]` table."""
    pos_key, _ = KINDS[kind]
    cols = ", ".join(f"{i + 1} = [{', '.join(toml_float(v) for v in t)}]"
                     for i, t in zip(table.surfaces, table.thickness_mm))
    out = ["", f"[{kind}]",
           f"{pos_key} = [{', '.join(toml_float(p) for p in table.positions)}]"]
    for key, (name, _) in ZOOM_COLUMNS.items():
        col = getattr(table, name)
        if col is not None:
            out.append(f"{key} = [{', '.join(toml_float(v) for v in col)}]")
    return out + [f"thickness = {{ {cols} }}"]


def gap_table_json(table: VariableGaps) -> dict:
    """A table as the JSON value of a .zmx NOTE line (zemax.dump_zmx; read back by
    zemax._gaps through read_gap_table)."""
    out = {"positions": [p if math.isfinite(p) else "inf" for p in table.positions],
           "surfaces": list(table.surfaces),
           "thickness_mm": [list(t) for t in table.thickness_mm]}
    for key, (name, _) in ZOOM_COLUMNS.items():
        if getattr(table, name) is not None:
            out[key] = list(getattr(table, name))
    return out
