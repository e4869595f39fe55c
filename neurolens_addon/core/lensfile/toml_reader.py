"""Reading our TOML lens format (docs/lens-format.md) into a `Lens`.

Order: size, surface count and dotted-key depth are checked on the raw text (before the TOML
parser sees it), then the TOML syntax, the top-level keys, each [[surface]] table (its kind
reads its own keys: core.surfaces), and finally every value (checks.py).
"""

from __future__ import annotations

import dataclasses

import re
import tomllib

from ..lensfields import (SurfaceFields, Where, check_keys, describe, number, string,
                          unknown_key_message)
from ..prescription import Lens, Material, Surface
from ..surfaces import DEFAULT_KIND, kind_class
from .checks import check_lens, lens_values, renamed_glass_notes, unknown_glass_notes
from .gap_tables import check_disjoint, read_gap_table
from .source import MAX_SURFACES, check_text

#: Dotted keys longer than this are refused before parsing: tomllib is quadratic in them.
_MAX_KEY_PARTS = 16

_TOP_REQUIRED = ("name", "source", "focal_length_mm", "f_number", "surface")
_TOP_OPTIONAL = ("field_of_view_deg", "back_focus_mm", "scale", "notes", "focus", "zoom")
#: keys of every [[surface]] table, whatever its kind
_SURFACE_REQUIRED = ("thickness", "material", "semi_diameter")
_SURFACE_OPTIONAL = ("stop", "kind")
_MATERIAL_KEYS = ("name", "nd", "vd")

_SURFACE_HEADER_RE = re.compile(r"^[ \t]*\[\[[ \t]*surface[ \t]*\]\]", re.MULTILINE)
_KEY_PART = r"""(?:[\w-]++|"[^"\n]*+"|'[^'\n]*+')"""
_LONG_DOTTED_KEY_RE = re.compile(
    r"""(?<![\w"'.-])""" + _KEY_PART
    + r"(?:[ \t]*+\.[ \t]*+" + _KEY_PART + r"){" + str(_MAX_KEY_PARTS) + "}")
_TOML_LINE_RE = re.compile(r"at line (\d+)")


def _precheck_text(text: str, where: Where) -> list[int]:
    """Refuse oversize input before parsing; return the lines of the [[surface]] headers."""
    check_text(text, where)
    headers = [m.start() for m in _SURFACE_HEADER_RE.finditer(text)]
    if len(headers) > MAX_SURFACES:
        raise where.error(f"{len(headers)} [[surface]] tables; at most {MAX_SURFACES} surfaces "
                          "are allowed, refusing to parse it", field="surface")
    m = _LONG_DOTTED_KEY_RE.search(text)
    if m:
        line = text.count("\n", 0, m.start()) + 1
        raise where.error(f"line {line}: a dotted key with more than {_MAX_KEY_PARTS} parts; the "
                          "lens format never nests that deep, refusing to parse it")
    lines, pos, line = [], 0, 1
    for start in headers:
        line += text.count("\n", pos, start)
        pos = start
        lines.append(line)
    return lines


def _parse_toml(text: str, where: Where) -> dict:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        m = _TOML_LINE_RE.search(msg)
        if m:
            n = int(m.group(1))
            all_lines = text.splitlines()
            shown = all_lines[n - 1].strip() if 0 < n <= len(all_lines) else ""
            if len(shown) > 60:
                shown = shown[:57] + "..."
            raise where.error(f"invalid TOML at line {n}: {msg}"
                              + (f"; the line reads: {shown}" if shown else "")) from None
        raise where.error(f"invalid TOML: {msg}") from None
    except RecursionError:
        raise where.error("invalid lens file: arrays or tables nested too deeply") from None
    except ValueError:      # (an integer of over 4300 digits: Python reads no more)
        raise where.error("invalid TOML: an integer of more than 4300 digits") from None


def _material(value, where, i) -> Material:
    if isinstance(value, str):
        name = value.strip()
        if not name:
            raise where.error("expected \"air\", a catalog glass name or { nd = ..., vd = ... }, "
                              "got an empty string", surface=i, field="material")
        if name.lower() == "air":
            return Material.air()
        return Material(name)
    if isinstance(value, dict):
        for key in value:
            if key not in _MATERIAL_KEYS:
                raise where.error(unknown_key_message(key, _MATERIAL_KEYS, "the material table"),
                                  surface=i, field="material")
        if "nd" not in value:
            raise where.error("material table needs 'nd' (refractive index at the d line); "
                              "'vd' (Abbe number) is optional", surface=i, field="material")
        nd = number(value["nd"], where, surface=i, field="material")
        vd = None
        if "vd" in value:
            vd = number(value["vd"], where, surface=i, field="material")
        if "name" in value:
            # a glass named with its (n_d, V_d): the catalogue's glass when it has the name,
            # else the two numbers model it under its name (checks.py notes which)
            name = string(value["name"], where, field="material").strip()
            return Material(name, nd=float(nd), vd=None if vd is None else float(vd))
        return Material.from_abbe(nd, vd)
    raise where.error("expected \"air\", a catalog glass name or { nd = ..., vd = ... }, got "
                      + describe(value), surface=i, field="material")


def _surface_from_table(table, where: Where, i: int) -> Surface:
    if not isinstance(table, dict):
        raise where.error(f"expected a [[surface]] table, got {describe(table)}", surface=i,
                          field="surface")
    fields = SurfaceFields(where, i)
    named = "kind" in table
    kind = kind_class(table["kind"] if named else DEFAULT_KIND, error=fields.error)
    what = f"a [[surface]] table of kind '{kind.kind}'" if named else "a [[surface]] table"
    required = kind.required_keys + _SURFACE_REQUIRED
    check_keys(table, required + kind.optional_keys + _SURFACE_OPTIONAL, required, where, what,
               surface=i)
    shape = kind.from_table(table, fields)
    thickness = number(table["thickness"], where, surface=i, field="thickness")
    material = _material(table["material"], where, i)
    sd = number(table["semi_diameter"], where, surface=i, field="semi_diameter")
    stop = table.get("stop", False)
    if not isinstance(stop, bool):
        raise where.error(f"expected true or false, got {describe(stop)}", surface=i,
                          field="stop")
    scale = where.scale
    return Surface(shape=shape, thickness_mm=thickness * scale, material=material,
                   semi_diameter_mm=sd * scale, stop=stop)


def loads_lens(text: str, path=None) -> Lens:
    """Parse a lens prescription in our TOML format (see docs/lens-format.md)."""
    where = Where(path)
    surface_lines = _precheck_text(text, where)
    doc = _parse_toml(text, where)

    check_keys(doc, _TOP_REQUIRED + _TOP_OPTIONAL, _TOP_REQUIRED, where, "the lens file")
    values = lens_values(doc, where)        # (the .zmx NOTE reader's checks of the same values)
    scale = 1.0
    if "scale" in doc:
        scale = number(doc["scale"], where, field="scale")
        if scale <= 0.0:
            raise where.error(f"scale must be > 0, got {scale:g}", field="scale")

    rows = doc["surface"]
    if not isinstance(rows, list):
        raise where.error(f"expected an array of [[surface]] tables, got {describe(rows)} "
                          "(write each surface as a [[surface]] table, front to back)",
                          field="surface")
    if len(rows) > MAX_SURFACES:
        raise where.error(f"{len(rows)} surfaces; at most {MAX_SURFACES} are allowed",
                          field="surface")
    if len(surface_lines) != len(rows):
        surface_lines = None  # surfaces written some other way: no line hints
    where = Where(path, surface_lines=surface_lines, scale=scale)
    surfaces = [_surface_from_table(row, where, i) for i, row in enumerate(rows)]

    lens = Lens(name=values["name"], source=values["source"],
                focal_length_mm=values["focal_length_mm"], f_number=values["f_number"],
                surfaces=tuple(surfaces), field_of_view_deg=values.get("field_of_view_deg"),
                notes=values.get("notes", ""), back_focus_mm=values.get("back_focus_mm"),
                path=None if path is None else str(path),
                focus_gaps=read_gap_table(doc, "focus", where, surfaces),
                zoom_gaps=read_gap_table(doc, "zoom", where, surfaces))
    check_disjoint(lens.focus_gaps, lens.zoom_gaps, where)
    canonical = check_lens(lens, where)
    said = renamed_glass_notes(lens.surfaces, canonical)
    if canonical != list(lens.surfaces):
        lens = lens.with_surfaces(canonical)
    said += unknown_glass_notes(lens.surfaces)
    if said:
        lens = dataclasses.replace(lens, notes=(lens.notes + " " + "; ".join(said)
                                                + ".").strip())
    return lens
