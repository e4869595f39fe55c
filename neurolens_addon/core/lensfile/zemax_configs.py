"""Zemax multi-configuration thickness operands: a `.zmx` file's focus and zoom positions.

OpticStudio keeps a lens's focus or zoom positions as configurations: `MNUM n active` gives
their number, and each multi-configuration `THIC` record one surface's thickness in one of them,

    THIC s c value 0 0 0 1 1 1 0 0 "" 0      surface s (0: the object distance), configuration c

listed operand by operand (all configurations of one surface together). The surface blocks'
own `DISZ` hold the active configuration. `SDIA s c value ...` records, in the same layout,
give a surface's semi-diameter per configuration: the stop's is a zoom's iris opening.

Read: MNUM's count is refused (one line naming it) unless it is 1 to MAX_CONFIGURATIONS (64,
the most positions a table holds: core.variable_gaps.MAX_POSITIONS), before anything is made
per configuration. With several configurations and no table of ours in the NOTE lines, the
records become
    [focus]  when the object distance changes from one configuration to another (and no gap
             changes between two configurations at the same distance): the positions are the
             object distances from the sensor, object distance + the lens's length in that
             configuration (infinity: `INFINITY` or >= 1e9 mm), infinity first;
    [zoom]   when the object distance stays and gaps change: the positions are the paraxial
             focal lengths of the configurations, ascending.
The surfaces take the first position's thicknesses. A [zoom] whose stop surface has SDIA records
that differ between configurations gets the stop's semi-diameter per position (its
`stop_semi_diameter` column; the stop surface takes the first). A file whose configurations
change both, or that has no configuration at infinity, is read as its active configuration,
with a note.

Write: a lens's [zoom] table as its configurations (object at infinity; SDIA records of the
stop when the table has a stop column); otherwise its [focus] table, with the object distance
per configuration. A lens with both tables writes its zoom positions; its focus table travels
in the NOTE lines only (so the file round-trips, and OpticStudio shows the zoom).
"""

from __future__ import annotations

import math
from dataclasses import replace

from ..variable_gaps import MAX_POSITIONS, VariableGaps
from .tokens import shown, to_float, to_int

#: object distances at or beyond this (mm) are infinity (OpticStudio writes 1e10)
INFINITE_MM = 1e9
#: the most configurations (MNUM) a file may have: each may become a table's position
MAX_CONFIGURATIONS = MAX_POSITIONS
_RECORD_TAIL = '0 0 0 1 1 1 0 0 "" 0'


def _count(system, where) -> tuple[int, int]:
    """(configurations, active one) from MNUM; (1, 1) without it. The count is checked
    against MAX_CONFIGURATIONS before anything is made per configuration."""
    rows = system.get("MNUM")
    if not rows:
        return 1, 1
    if len(rows) > 1:
        raise where.error(f"line {rows[1][0]}: a second MNUM (the first is on line "
                          f"{rows[0][0]})", field="MNUM")
    lineno, tok = rows[0]
    n = to_int(tok[0]) if tok else None
    if n is None or not 1 <= n <= MAX_CONFIGURATIONS:
        raise where.error(f"line {lineno}: MNUM: expected a number of configurations from 1 to "
                          f"{MAX_CONFIGURATIONS}, got '{shown(tok[0]) if tok else ''}'",
                          field="MNUM")
    active = to_int(tok[1]) if len(tok) > 1 else 1
    if active is None:
        raise where.error(f"line {lineno}: MNUM: expected the active configuration's number, "
                          f"got '{shown(tok[1])}'", field="MNUM")
    return n, min(max(active, 1), n)


def _records(system, where, n_configs: int, n_surfaces: int, unit: float, op: str = "THIC"):
    """{surface: {configuration: value mm}} from THIC (thickness; surface 0: the object) or
    SDIA (semi-diameter) records."""
    out: dict[int, dict[int, float]] = {}
    field, what = {"THIC": ("thickness", "a thickness"),
                   "SDIA": ("semi_diameter", "a semi-diameter")}[op]
    for lineno, tok in system.get(op, []):
        if len(tok) < 3:
            raise where.error(f"line {lineno}: {op} needs a surface, a configuration and a "
                              "value", field=field)
        s, c = to_int(tok[0]), to_int(tok[1])
        if s is None or c is None:
            raise where.error(f"line {lineno}: {op} surface and configuration must be "
                              "integers", field=field)
        first = 0 if op == "THIC" else 1
        if not (first <= s <= n_surfaces and 1 <= c <= n_configs):
            raise where.error(f"line {lineno}: {op} names surface {s}, configuration {c}; the "
                              f"file has surfaces {first} to {n_surfaces} and {n_configs} "
                              "configurations", field=field)
        value = to_float(tok[2], allow_inf=True)
        if value is None or not value > 0.0:
            raise where.error(f"line {lineno}: {op} {s} {c}: expected {what} > 0, got "
                              f"'{shown(tok[2])}'", surface=s - 1 if s else None, field=field)
        if not math.isinf(value):
            value = math.inf if s == 0 and value >= INFINITE_MM else value * unit
        elif s > 0:
            raise where.error(f"line {lineno}: {op} {s} {c}: an infinite value",
                              surface=s - 1, field=field)
        out.setdefault(s, {})[c] = value
    return out


def read_configurations(system, where, unit: float, surfaces, object_mm: float, paraxial_efl):
    """(focus VariableGaps | None, zoom VariableGaps | None, surfaces, notes) from a file's
    configurations (module docstring). `object_mm` is the object block's own distance;
    `paraxial_efl(surfaces)` gives a configuration's focal length."""
    n, active = _count(system, where)
    if n < 2:
        return None, None, surfaces, []
    records = _records(system, where, n, len(surfaces), unit)
    configs = range(1, n + 1)
    gaps = {s: [col.get(c, surfaces[s - 1].thickness_mm) for c in configs]
            for s, col in records.items() if s > 0}
    moving = {s: col for s, col in gaps.items() if len(set(col)) > 1}
    obj = [records.get(0, {}).get(c, object_mm) for c in configs]
    obj = [math.inf if v >= INFINITE_MM else v for v in obj]
    as_active = [f"{n} configurations: configuration {active} (the active one) is read"]
    if not moving:
        return None, None, surfaces, as_active

    def thicknesses(c):
        return {s - 1: col[c] for s, col in moving.items()}

    def at(c):
        th = thicknesses(c)
        return [replace(sf, thickness_mm=th.get(i, sf.thickness_mm))
                for i, sf in enumerate(surfaces)]

    focus_like = len(set(obj)) > 1
    if focus_like:
        by_distance: dict[float, list[int]] = {}
        for c in range(n):
            by_distance.setdefault(obj[c], []).append(c)
        if any(len({tuple(thicknesses(c).values()) for c in cs}) > 1
               for cs in by_distance.values()):
            return None, None, surfaces, as_active + ["the configurations change both the "
                                                      "object distance and the gaps"]
        if not any(math.isinf(d) for d in obj):
            return None, None, surfaces, as_active + ["no configuration has its object at "
                                                      "infinity"]
        order = sorted({d: cs[0] for d, cs in by_distance.items()}.items(),
                       key=lambda kv: -kv[0])
        chosen = [c for _, c in order]
        positions = [d if math.isinf(d) else d + sum(s.thickness_mm for s in at(c))
                     for d, c in order]
        near = positions[1:]
        if not all(math.isfinite(p) and p > 0 for p in near) or \
                any(b >= a for a, b in zip(near, near[1:])):
            # (as the [focus] table requires: gap_tables.read_gap_table)
            return None, None, surfaces, as_active + ["the configurations' distances from the "
                                                      "sensor are not nearer and nearer"]
    else:
        efl = {c: paraxial_efl(at(c)) for c in range(n)}
        chosen = sorted(range(n), key=efl.__getitem__)
        positions = [efl[c] for c in chosen]
        if not all(math.isfinite(p) and p > 0 for p in positions) or \
                any(b <= a for a, b in zip(positions, positions[1:])):
            return None, None, surfaces, as_active + ["the configurations' focal lengths are "
                                                      "not distinct and positive"]
    keys = sorted(moving)
    stop_col = None
    if not focus_like:
        stop = next((i for i, sf in enumerate(surfaces) if sf.stop), None)
        sdia = _records(system, where, n, len(surfaces), unit, "SDIA")
        if stop is not None and stop + 1 in sdia:
            own = surfaces[stop].semi_diameter_mm
            col = [sdia[stop + 1].get(c + 1, own) for c in chosen]
            stop_col = tuple(col) if len(set(col)) > 1 else None
    table = VariableGaps(tuple(positions), tuple(s - 1 for s in keys),
                         tuple(tuple(moving[s][c] for c in chosen) for s in keys),
                         stop_semi_diameter_mm=stop_col)
    base = at(chosen[0])
    if stop_col is not None:
        base[stop] = replace(base[stop], semi_diameter_mm=stop_col[0])
    what = "focus distances" if focus_like else "zoom positions"
    note = [f"{n} configurations read as {len(positions)} {what} (THIC of surfaces "
            f"{', '.join(str(s) for s in keys)}"
            + (f"; SDIA of the stop, surface {stop + 1})" if stop_col is not None else ")")]
    return (table, None, base, note) if focus_like else (None, table, base, note)


def write_configurations(lens, fmt) -> list[str]:
    """MNUM and THIC records of the lens's zoom (else focus) positions; [] for a fixed lens."""
    table = lens.zoom_gaps if lens.zoom_gaps is not None else lens.focus_gaps
    if table is None:
        return []
    n = table.count
    out = [f"MNUM {n} 1"]
    if table is lens.focus_gaps:
        base_track = sum(s.thickness_mm for s in lens.surfaces)
        for c in range(n):
            d = table.positions[c]
            track = base_track + sum(col[c] - lens.surfaces[i].thickness_mm
                                     for i, col in zip(table.surfaces, table.thickness_mm))
            value = "1.0E+10" if math.isinf(d) else fmt(d - track)
            out.append(f"THIC 0 {c + 1} {value} {_RECORD_TAIL}")
    for i, col in zip(table.surfaces, table.thickness_mm):
        out += [f"THIC {i + 1} {c + 1} {fmt(col[c])} {_RECORD_TAIL}" for c in range(n)]
    if table is lens.zoom_gaps and table.stop_semi_diameter_mm is not None:
        stop = lens.stop_index + 1
        out += [f"SDIA {stop} {c + 1} {fmt(r)} {_RECORD_TAIL}"
                for c, r in enumerate(table.stop_semi_diameter_mm)]
    return out
