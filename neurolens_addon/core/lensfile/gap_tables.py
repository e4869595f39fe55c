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
"""

from __future__ import annotations

import math

from ..lensfields import check_keys, describe, number, toml_float
from ..variable_gaps import VariableGaps

#: table -> (its positions key, what a position is)
KINDS = {"focus": ("distances_mm", "an object distance from the sensor in mm"),
         "zoom": ("focal_lengths_mm", "a focal length in mm")}


def read_gap_table(doc: dict, kind: str, where, surfaces) -> VariableGaps | None:
    """The `[focus]` or `[zoom]` table of a parsed lens file, checked, or None."""
    if kind not in doc:
        return None
    table = doc[kind]
    pos_key, what = KINDS[kind]
    if not isinstance(table, dict):
        raise where.error(f"expected a [{kind}] table, got {describe(table)}", field=kind)
    check_keys(table, (pos_key, "thickness"), (pos_key, "thickness"), where, f"[{kind}]")
    raw = table[pos_key]
    if not isinstance(raw, list) or len(raw) < 2:
        raise where.error(f"expected a list of at least 2 positions ({what} each), got "
                          f"{describe(raw)}", field=f"{kind}.{pos_key}")
    scale = where.scale
    positions = [number(v, where, field=f"{kind}.{pos_key}", allow_inf=(kind == "focus"))
                 * scale for v in raw]
    if kind == "focus":
        if not math.isinf(positions[0]):
            raise where.error("the first focus position must be inf (the design at infinity, "
                              "as its [[surface]] thicknesses are)", field=f"focus.{pos_key}")
        rest = positions[1:]
        if not all(p > 0 and math.isfinite(p) for p in rest) or \
                any(b >= a for a, b in zip(rest, rest[1:])):
            raise where.error("after inf, focus distances must be finite, > 0 and decreasing "
                              "(nearer and nearer)", field=f"focus.{pos_key}")
    elif not all(p > 0 for p in positions) or any(b <= a for a, b in zip(positions,
                                                                        positions[1:])):
        raise where.error("focal lengths must be > 0 and increasing", field=f"zoom.{pos_key}")
    gaps = table["thickness"]
    if not isinstance(gaps, dict) or not gaps:
        raise where.error("expected a table of surface number = [thickness per position]",
                          field=f"{kind}.thickness")
    indices, values = [], []
    for key, column in gaps.items():
        field = f"{kind}.thickness.{key}"
        if not (key.isdigit() and 1 <= int(key) <= len(surfaces)):
            raise where.error(f"'{key}' is not a surface number (1 to {len(surfaces)})",
                              field=field)
        i = int(key) - 1
        if not isinstance(column, list) or len(column) != len(positions):
            raise where.error(f"expected {len(positions)} thicknesses (one per position), got "
                              f"{describe(column)}", surface=i, field=field)
        col = [number(v, where, surface=i, field=field) * scale for v in column]
        if not all(v > 0 for v in col):
            raise where.error("every thickness must be > 0 mm", surface=i, field=field)
        own = surfaces[i].thickness_mm
        if not math.isclose(col[0], own, rel_tol=1e-12, abs_tol=1e-12):
            raise where.error(f"the first position's thickness {col[0]:g} differs from the "
                              f"surface's own thickness {own:g}: the [[surface]] tables hold "
                              "the first position", surface=i, field=field)
        indices.append(i)
        values.append(tuple(col))
    order = sorted(range(len(indices)), key=indices.__getitem__)
    return VariableGaps(tuple(positions), tuple(indices[k] for k in order),
                        tuple(values[k] for k in order))


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
    return ["", f"[{kind}]",
            f"{pos_key} = [{', '.join(toml_float(p) for p in table.positions)}]",
            f"thickness = {{ {cols} }}"]
