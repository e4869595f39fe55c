"""Lens files: our TOML prescription format (read and write) and pbrt-v3/v4 `.dat` lens files.

Public API
- `load_lens(path)`: read a `.toml` (our format) or `.dat` (pbrt RealisticCamera) file.
- `loads_lens(text, path=None)`: parse our TOML format from a string.
- `dump_lens(lens)`: TOML text that `loads_lens` turns back into an equal `Lens`.
- `load_pbrt_dat(path)` / `loads_pbrt_dat(text, path=None)`: import a pbrt lens file.
- `validate_lens(lens, path=None)`: the value checks every loaded lens passes (usable on a
  `Lens` built in code).

The format, its conventions and every validation rule are documented in `docs/lens-format.md`.
Every problem raises `LensError` naming the file, the 1-based surface number and the field.
Pure Python + numpy; never imports bpy.
"""

from __future__ import annotations

import difflib
import math
import os
import re
import tomllib
from pathlib import Path

import numpy as np

from .errors import GlassError, LensError
from .prescription import Lens, Material, Surface

__all__ = [
    "MAX_FILE_BYTES", "MAX_SURFACES", "OVERLAP_TOLERANCE_MM",
    "load_lens", "loads_lens", "dump_lens", "load_pbrt_dat", "loads_pbrt_dat", "validate_lens",
]

#: Files (or strings) larger than this are refused before parsing.
MAX_FILE_BYTES = 1 << 20
#: Lenses with more surfaces than this are refused (before parsing where the text shows it).
MAX_SURFACES = 256
#: Consecutive surfaces may touch but not cross by more than this (mm).
OVERLAP_TOLERANCE_MM = 1e-9
#: Radii sampled in [0, min(sd_i, sd_i+1)] by the overlap check.
_OVERLAP_SAMPLES = 33
#: Dotted keys longer than this are refused before parsing: tomllib is quadratic in them.
_MAX_KEY_PARTS = 16

_TOP_REQUIRED = ("name", "source", "focal_length_mm", "f_number", "surface")
_TOP_OPTIONAL = ("field_of_view_deg", "scale", "notes")
_SURFACE_REQUIRED = ("radius", "thickness", "material", "semi_diameter")
_SURFACE_OPTIONAL = ("conic", "aspheric", "stop")
_MATERIAL_KEYS = ("nd", "vd")
_ASPHERIC_POWERS = tuple(range(2, 21, 2))
_ASPHERIC_KEYS = tuple(f"a{p}" for p in _ASPHERIC_POWERS)

_SURFACE_HEADER_RE = re.compile(r"^[ \t]*\[\[[ \t]*surface[ \t]*\]\]", re.MULTILINE)
_KEY_PART = r"""(?:[\w-]++|"[^"\n]*+"|'[^'\n]*+')"""
_LONG_DOTTED_KEY_RE = re.compile(
    r"""(?<![\w"'.-])""" + _KEY_PART
    + r"(?:[ \t]*+\.[ \t]*+" + _KEY_PART + r"){" + str(_MAX_KEY_PARTS) + "}")
_TOML_LINE_RE = re.compile(r"at line (\d+)")


# =============================================================================================
# error context
# =============================================================================================
class _Where:
    """Where errors point: the file, how surfaces map to lines, and how fields are spelt."""

    def __init__(self, path, *, surface_lines=None, fields=None, line_word="starts at line",
                 scale=1.0):
        self.path = None if path is None else str(path)
        self.surface_lines = surface_lines  # 0-based surface index -> 1-based line, or None
        self.fields = fields or {}
        self.line_word = line_word
        self.scale = scale

    def field(self, name):
        return self.fields.get(name, name)

    def error(self, message, *, surface=None, field=None, scaled=False):
        """A LensError; `surface` is the 0-based index (reported 1-based)."""
        hints = []
        if surface is not None and self.surface_lines and 0 <= surface < len(self.surface_lines):
            hints.append(f"surface {surface + 1} {self.line_word} {self.surface_lines[surface]}")
        if scaled and self.scale != 1.0:
            hints.append(f"lengths shown after scale = {self.scale:g}")
        if hints:
            message = f"{message} ({'; '.join(hints)})"
        return LensError(message, path=self.path,
                         surface=None if surface is None else surface + 1,
                         field=None if field is None else self.field(field))


def _describe(value) -> str:
    """A value's TOML type in words, with the value when short."""
    if isinstance(value, bool):
        kind = "a boolean"
    elif isinstance(value, int):
        kind = "an integer"
    elif isinstance(value, float):
        kind = "a float"
    elif isinstance(value, str):
        kind = "a string"
    elif isinstance(value, dict):
        return "a table"
    elif isinstance(value, list):
        return "an array"
    else:
        return f"a {type(value).__name__}"
    text = repr(value) if not isinstance(value, bool) else str(value).lower()
    if len(text) > 40:
        text = text[:37] + "..."
    return f"{kind} ({text})"


def _unknown_key_message(key, allowed, what) -> str:
    close = difflib.get_close_matches(str(key), list(allowed), n=1, cutoff=0.6)
    hint = f"; did you mean '{close[0]}'?" if close else ""
    return (f"unknown key '{key}' in {what}{hint} (allowed: {', '.join(allowed)})")


# =============================================================================================
# reading files
# =============================================================================================
def _read_text(path) -> str:
    """The file as text; size, read and decode problems become LensError naming the file."""
    where = _Where(path)
    try:
        size = os.stat(path).st_size
    except OSError as exc:
        raise where.error(f"cannot read the lens file: {exc.strerror or exc}") from None
    if size > MAX_FILE_BYTES:
        raise where.error(f"file is {size} bytes; lens files are limited to {MAX_FILE_BYTES} "
                          "bytes (1 MiB), refusing to parse it")
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise where.error(f"cannot read the lens file: {exc.strerror or exc}") from None
    if len(data) > MAX_FILE_BYTES:
        raise where.error(f"file is larger than {MAX_FILE_BYTES} bytes (1 MiB), refusing to "
                          "parse it")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise where.error(f"file is not UTF-8 text: undecodable byte 0x{data[exc.start]:02x} at "
                          f"line {line} (byte offset {exc.start})") from None
    return text[1:] if text.startswith("\ufeff") else text


def load_lens(path) -> Lens:
    """Load a lens file: `.toml` is our format, `.dat` a pbrt RealisticCamera lens file."""
    suffix = Path(path).suffix.lower()
    if suffix == ".toml":
        return loads_lens(_read_text(path), path=str(path))
    if suffix == ".dat":
        return load_pbrt_dat(path)
    raise LensError(f"unknown lens file extension '{suffix}': expected .toml (NeuroLens "
                    "prescription) or .dat (pbrt lens file)", path=str(path))


# =============================================================================================
# our TOML format
# =============================================================================================
def _precheck_text(text: str, where: _Where) -> list[int]:
    """Refuse oversize input before parsing; return the lines of the [[surface]] headers."""
    if len(text) > MAX_FILE_BYTES or len(text.encode("utf-8", "surrogatepass")) > MAX_FILE_BYTES:
        raise where.error(f"lens text is larger than {MAX_FILE_BYTES} bytes (1 MiB), refusing "
                          "to parse it")
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


def _parse_toml(text: str, where: _Where) -> dict:
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


def _number(value, where, *, surface=None, field, allow_inf=False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise where.error(f"expected a number, got {_describe(value)}", surface=surface,
                          field=field)
    try:
        x = float(value)
    except OverflowError:
        raise where.error(f"number {value} is too large", surface=surface, field=field) from None
    if math.isnan(x) or (math.isinf(x) and not allow_inf):
        raise where.error(f"expected a finite number, got {x}", surface=surface, field=field)
    return x


def _string(value, where, *, field, nonempty=True) -> str:
    if not isinstance(value, str):
        raise where.error(f"expected a string, got {_describe(value)}", field=field)
    if nonempty and not value.strip():
        raise where.error("expected a non-empty string", field=field)
    return value


def _check_keys(table, allowed, required, where, what, *, surface=None):
    for key in table:
        if key not in allowed:
            raise where.error(_unknown_key_message(key, allowed, what), surface=surface,
                              field=str(key))
    for key in required:
        if key not in table:
            raise where.error(f"missing required key '{key}' in {what}", surface=surface,
                              field=key)


def _radius(value, where, i) -> float:
    if isinstance(value, str):
        if value.strip().lower() in ("flat", "inf", "infinity"):
            return math.inf
        raise where.error(f"expected a number (mm) or \"flat\", got {_describe(value)}",
                          surface=i, field="radius")
    r = _number(value, where, surface=i, field="radius", allow_inf=True)
    if r == 0.0:
        raise where.error("radius 0 is not allowed: write radius = \"flat\" for a plane",
                          surface=i, field="radius")
    return math.inf if math.isinf(r) else r


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
                raise where.error(_unknown_key_message(key, _MATERIAL_KEYS, "the material table"),
                                  surface=i, field="material")
        if "nd" not in value:
            raise where.error("material table needs 'nd' (refractive index at the d line); "
                              "'vd' (Abbe number) is optional", surface=i, field="material")
        nd = _number(value["nd"], where, surface=i, field="material")
        vd = None
        if "vd" in value:
            vd = _number(value["vd"], where, surface=i, field="material")
        return Material.from_abbe(nd, vd)
    raise where.error("expected \"air\", a catalog glass name or { nd = ..., vd = ... }, got "
                      + _describe(value), surface=i, field="material")


def _aspheric(value, where, i, scale) -> tuple[tuple[int, float], ...]:
    if not isinstance(value, dict):
        raise where.error(f"expected a table like {{ a4 = 1e-5, a6 = -3e-8 }}, got "
                          f"{_describe(value)}", surface=i, field="aspheric")
    terms = []
    for key, coeff in value.items():
        if key not in _ASPHERIC_KEYS:
            raise where.error(f"unknown aspheric term '{key}': expected even terms "
                              f"{', '.join(_ASPHERIC_KEYS)} (coefficient of r^n)",
                              surface=i, field="aspheric")
        a = _number(coeff, where, surface=i, field="aspheric")
        p = int(key[1:])
        if a != 0.0:
            # a_n r^n has units mm^(1-n): scaling every length by s gives a_n s^(1-n).
            try:
                a_scaled = a * scale ** (1 - p)
            except OverflowError:
                a_scaled = math.inf
            if not math.isfinite(a_scaled) or a_scaled == 0.0:
                raise where.error(f"coefficient {key} = {a:g} is out of range after scale = "
                                  f"{scale:g}", surface=i, field="aspheric")
            terms.append((p, a_scaled))
    return tuple(sorted(terms))


def _surface_from_table(table, where, i, scale) -> Surface:
    if not isinstance(table, dict):
        raise where.error(f"expected a [[surface]] table, got {_describe(table)}", surface=i,
                          field="surface")
    _check_keys(table, _SURFACE_REQUIRED + _SURFACE_OPTIONAL, _SURFACE_REQUIRED, where,
                "a [[surface]] table", surface=i)
    radius = _radius(table["radius"], where, i)
    thickness = _number(table["thickness"], where, surface=i, field="thickness")
    material = _material(table["material"], where, i)
    sd = _number(table["semi_diameter"], where, surface=i, field="semi_diameter")
    conic = _number(table.get("conic", 0.0), where, surface=i, field="conic")
    aspheric = _aspheric(table.get("aspheric", {}), where, i, scale)
    if math.isfinite(radius) and math.isinf(radius * scale):
        raise where.error(f"radius {radius:g} is out of range after scale = {scale:g}",
                          surface=i, field="radius")
    stop = table.get("stop", False)
    if not isinstance(stop, bool):
        raise where.error(f"expected true or false, got {_describe(stop)}", surface=i,
                          field="stop")
    return Surface(radius_mm=radius * scale, thickness_mm=thickness * scale, material=material,
                   semi_diameter_mm=sd * scale, conic=conic + 0.0, aspheric=aspheric, stop=stop)


def loads_lens(text: str, path=None) -> Lens:
    """Parse a lens prescription in our TOML format (see docs/lens-format.md)."""
    where = _Where(path)
    if not isinstance(text, str):
        raise where.error(f"expected the lens file's text as a string, got {_describe(text)}")
    surface_lines = _precheck_text(text, where)
    doc = _parse_toml(text, where)

    _check_keys(doc, _TOP_REQUIRED + _TOP_OPTIONAL, _TOP_REQUIRED, where, "the lens file")
    name = _string(doc["name"], where, field="name")
    source = _string(doc["source"], where, field="source")
    focal = _number(doc["focal_length_mm"], where, field="focal_length_mm")
    f_number = _number(doc["f_number"], where, field="f_number")
    fov = None
    if "field_of_view_deg" in doc:
        fov = _number(doc["field_of_view_deg"], where, field="field_of_view_deg")
    scale = 1.0
    if "scale" in doc:
        scale = _number(doc["scale"], where, field="scale")
        if scale <= 0.0:
            raise where.error(f"scale must be > 0, got {scale:g}", field="scale")
    notes = _string(doc["notes"], where, field="notes", nonempty=False) if "notes" in doc else ""

    rows = doc["surface"]
    if not isinstance(rows, list):
        raise where.error(f"expected an array of [[surface]] tables, got {_describe(rows)} "
                          "(write each surface as a [[surface]] table, front to back)",
                          field="surface")
    if len(rows) > MAX_SURFACES:
        raise where.error(f"{len(rows)} surfaces; at most {MAX_SURFACES} are allowed",
                          field="surface")
    if len(surface_lines) != len(rows):
        surface_lines = None  # surfaces written some other way: no line hints
    where = _Where(path, surface_lines=surface_lines, scale=scale)
    surfaces = [_surface_from_table(row, where, i, scale) for i, row in enumerate(rows)]

    lens = Lens(name=name, source=source, focal_length_mm=focal, f_number=f_number,
                surfaces=tuple(surfaces), field_of_view_deg=fov, notes=notes,
                path=None if path is None else str(path))
    canonical = _validate(lens, where)
    if canonical != list(lens.surfaces):
        lens = lens.with_surfaces(canonical)
    return lens


# ---- writing --------------------------------------------------------------------------------
def _toml_string(s: str) -> str:
    out = ['"']
    for ch in s:
        o = ord(ch)
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\t":
            out.append("\\t")
        elif ch == "\r":
            out.append("\\r")
        elif o < 0x20 or o == 0x7F:
            out.append(f"\\u{o:04x}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def _toml_float(x) -> str:
    x = float(x)
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return repr(x)


def dump_lens(lens: Lens) -> str:
    """TOML text of `lens` in our format (scale 1) that `loads_lens` reads back equal."""
    out = ["# NeuroLens lens prescription (format: docs/lens-format.md)",
           "# lens space: mm, +z to the scene, design image plane at z = 0",
           f"name = {_toml_string(lens.name)}",
           f"source = {_toml_string(lens.source)}",
           f"focal_length_mm = {_toml_float(lens.focal_length_mm)}",
           f"f_number = {_toml_float(lens.f_number)}"]
    if lens.field_of_view_deg is not None:
        out.append(f"field_of_view_deg = {_toml_float(lens.field_of_view_deg)}")
    if lens.notes:
        out.append(f"notes = {_toml_string(lens.notes)}")
    for s in lens.surfaces:
        out += ["", "[[surface]]"]
        r = float(s.radius_mm)
        out.append('radius = "flat"' if math.isinf(r) else f"radius = {_toml_float(r)}")
        out.append(f"thickness = {_toml_float(s.thickness_mm)}")
        m = s.material
        if m.is_air:
            out.append('material = "air"')
        elif m.nd is not None:
            parts = [f"nd = {_toml_float(m.nd)}"]
            if m.vd is not None:
                parts.append(f"vd = {_toml_float(m.vd)}")
            out.append("material = { " + ", ".join(parts) + " }")
        else:
            out.append(f"material = {_toml_string(m.name)}")
        out.append(f"semi_diameter = {_toml_float(s.semi_diameter_mm)}")
        if s.conic != 0.0:
            out.append(f"conic = {_toml_float(s.conic)}")
        if s.aspheric:
            terms = ", ".join(f"a{int(p)} = {_toml_float(a)}" for p, a in s.aspheric)
            out.append(f"aspheric = {{ {terms} }}")
        if s.stop:
            out.append("stop = true")
    return "\n".join(out) + "\n"


# =============================================================================================
# validation (values, on a Lens)
# =============================================================================================
def _glass_catalog():
    """The default glass catalog, or None while core/glass.py is not available."""
    try:
        from .glass import default_catalog
    except ImportError:
        return None
    return default_catalog()


def _sag(s: Surface, r: np.ndarray) -> np.ndarray:
    """Sag along the propagation direction (lens space z = vertex_z - sag)."""
    c = s.curvature
    arg = np.maximum(1.0 - (1.0 + s.conic) * c * c * r * r, 0.0)
    with np.errstate(over="ignore", invalid="ignore"):
        z = c * r * r / (1.0 + np.sqrt(arg))
        for p, a in s.aspheric:
            z = z + a * r ** p
    return z


def validate_lens(lens: Lens, path=None) -> None:
    """Check the values of a `Lens` (the same rules `loads_lens` applies); raise LensError."""
    _validate(lens, _Where(path if path is not None else lens.path))


def _validate(lens: Lens, where: _Where) -> list[Surface]:
    """Raise LensError for the first problem; return the surfaces with catalog names canonical."""
    for field, value in (("focal_length_mm", lens.focal_length_mm), ("f_number", lens.f_number)):
        if not (math.isfinite(value) and value > 0.0):
            raise where.error(f"must be a finite number > 0, got {value:g}", field=field)
    fov = lens.field_of_view_deg
    if fov is not None and not (math.isfinite(fov) and 0.0 < fov <= 360.0):
        raise where.error(f"must be in (0, 360] degrees, got {fov:g}", field="field_of_view_deg")
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
        r = s.radius_mm
        if math.isnan(r) or r == 0.0:
            raise where.error(f"radius must be non-zero (\"flat\" for a plane), got {r:g}",
                              surface=i, field="radius")
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
        if not math.isfinite(s.conic):
            raise where.error(f"conic must be finite, got {s.conic:g}", surface=i, field="conic")
        for p, a in s.aspheric:
            if p not in _ASPHERIC_POWERS or not math.isfinite(a):
                raise where.error(f"aspheric term a{p} = {a:g}: expected even powers 2..20 with "
                                  "finite coefficients", surface=i, field="aspheric")
        c = s.curvature
        if 1.0 - (1.0 + s.conic) * c * c * sd * sd < -1e-12:
            r_max = 1.0 / (abs(c) * math.sqrt(1.0 + s.conic))
            shape = (f"a sphere of radius {abs(r):g} mm" if s.conic == 0.0
                     else f"a conic with radius {r:g} mm and k = {s.conic:g}")
            raise where.error(f"semi_diameter {sd:g} mm is larger than the surface allows: "
                              f"{shape} has no points beyond r = {r_max:g} mm "
                              "(1 - (1+k) c^2 r^2 < 0)", surface=i, field="semi_diameter",
                              scaled=True)
        if s.aspheric:
            sag = _sag(s, np.linspace(0.0, sd, _OVERLAP_SAMPLES))
            if not np.all(np.isfinite(sag)):
                raise where.error("aspheric sag is not finite within the semi_diameter: "
                                  "coefficients too large", surface=i, field="aspheric")

        m = s.material
        if m.is_air:
            pass
        elif m.nd is not None:
            if not (math.isfinite(m.nd) and m.nd >= 1.0):
                raise where.error(f"refractive index nd must be >= 1, got {m.nd:g}", surface=i,
                                  field="material")
            if m.vd is not None and not (math.isfinite(m.vd) and m.vd > 0.0):
                raise where.error(f"Abbe number vd must be > 0 (or left out for a "
                                  f"non-dispersive material), got {m.vd:g}", surface=i,
                                  field="material")
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
                canonical = getattr(glass, "name", None)
                if isinstance(canonical, str) and canonical != m.name and canonical in catalog:
                    surfaces[i] = Surface(s.radius_mm, s.thickness_mm, Material(canonical),
                                          s.semi_diameter_mm, s.conic, s.aspheric, s.stop)

    stops = [i for i, s in enumerate(surfaces) if s.stop]
    if not stops:
        raise where.error("no aperture stop: mark exactly one surface with stop = true",
                          field="stop")
    if len(stops) > 1:
        raise where.error(f"more than one aperture stop (surfaces "
                          f"{', '.join(str(j + 1) for j in stops)}): exactly one surface may "
                          "have stop = true", surface=stops[1], field="stop")
    if not surfaces[-1].material.is_air:
        raise where.error(f"the last surface must be followed by air (the medium up to the "
                          f"image plane), got '{surfaces[-1].material.name}'",
                          surface=len(surfaces) - 1, field="material")

    for i in range(len(surfaces) - 1):
        a, b = surfaces[i], surfaces[i + 1]
        r = np.linspace(0.0, min(a.semi_diameter_mm, b.semi_diameter_mm), _OVERLAP_SAMPLES)
        with np.errstate(over="ignore", invalid="ignore"):
            # (z_i - sag_i) - (z_i+1 - sag_i+1) with z_i - z_i+1 = t_i
            gap = a.thickness_mm - _sag(a, r) + _sag(b, r)
        bad = ~(gap > -OVERLAP_TOLERANCE_MM)
        if np.any(bad):
            k = int(np.argmax(bad))
            raise where.error(
                f"surfaces {i + 1} and {i + 2} cross: at r = {r[k]:.4g} mm surface {i + 2} lies "
                f"{-gap[k]:.4g} mm in front of surface {i + 1}; increase thickness of surface "
                f"{i + 1} or reduce the semi_diameters", surface=i, field="thickness",
                scaled=True)
    return surfaces


# =============================================================================================
# pbrt .dat lens files
# =============================================================================================
_PBRT_FIELDS = {"radius": "radius", "thickness": "thickness", "material": "index",
                "semi_diameter": "aperture_diameter"}
_PBRT_COLUMNS = ("radius", "thickness", "index", "aperture_diameter")


def _paraxial_marginal(surfaces) -> tuple[list[float], float]:
    """y-nu trace at n_d of the ray from infinity at height 1: heights at each surface, n'u'.

    Sign convention as the prescription: light travels towards the sensor, c = 1/R with R > 0
    when the centre of curvature is on the sensor side; the paraxial curvature includes a2.
    """
    heights = []
    y, nu, n = 1.0, 0.0, 1.0
    for j, s in enumerate(surfaces):
        m = s.material
        n2 = 1.0 if m.is_air else float(m.nd)
        c = s.curvature + 2.0 * dict(s.aspheric).get(2, 0.0)
        heights.append(y)
        nu = nu - y * (n2 - n) * c
        if j < len(surfaces) - 1:
            y = y + s.thickness_mm * nu / n2
        n = n2
    return heights, nu


def load_pbrt_dat(path) -> Lens:
    """Import a pbrt-v3/v4 RealisticCamera lens file (see docs/lens-format.md)."""
    return loads_pbrt_dat(_read_text(path), path=str(path))


def loads_pbrt_dat(text: str, path=None) -> Lens:
    """Parse the text of a pbrt `.dat` lens file; `path` names it in errors and the lens name."""
    where = _Where(path, fields=_PBRT_FIELDS, line_word="is on line")
    if not isinstance(text, str):
        raise where.error(f"expected the lens file's text as a string, got {_describe(text)}")
    if len(text) > MAX_FILE_BYTES or len(text.encode("utf-8", "surrogatepass")) > MAX_FILE_BYTES:
        raise where.error(f"lens text is larger than {MAX_FILE_BYTES} bytes (1 MiB), refusing "
                          "to parse it")
    rows, lines, comments = [], [], []
    for lineno, raw in enumerate(text.splitlines(), 1):
        body, hash_, comment = raw.partition("#")
        if hash_ and comment.strip() and not rows:
            comments.append(comment.strip())
        tokens = body.split()
        if not tokens:
            continue
        if len(tokens) != 4:
            raise where.error(f"line {lineno}: expected 4 numbers (radius thickness index "
                              f"aperture_diameter, in mm), got {len(tokens)} values")
        values = []
        for col, tok in zip(_PBRT_COLUMNS, tokens):
            try:
                v = float(tok)
            except ValueError:
                v = None
            if v is None or not math.isfinite(v):
                shown = tok if len(tok) <= 20 else tok[:17] + "..."
                raise where.error(f"line {lineno}: expected a finite number for {col}, got "
                                  f"'{shown}'", surface=len(rows), field=col)
            values.append(v)
        rows.append(values)
        lines.append(lineno)
        if len(rows) > MAX_SURFACES:
            raise where.error(f"line {lineno}: more than {MAX_SURFACES} surfaces, refusing the "
                              "file", field="surface")
    if not rows:
        raise where.error("no surface rows: expected rows of 'radius thickness index "
                          "aperture_diameter' (mm), front to back", field="surface")
    where = _Where(path, surface_lines=lines, fields=_PBRT_FIELDS, line_word="is on line")

    surfaces = []
    stop_rows = []
    for i, (radius, thickness, index, diameter) in enumerate(rows):
        if diameter <= 0.0:
            raise where.error(f"aperture_diameter must be > 0 mm, got {diameter:g}", surface=i,
                              field="semi_diameter")
        is_stop = radius == 0.0
        if index in (0.0, 1.0):
            material = Material.air()
        elif is_stop:
            raise where.error(f"an aperture stop (radius 0) must be in air: index 0 or 1, got "
                              f"{index:g}", surface=i, field="material")
        elif index < 1.0:
            raise where.error(f"index must be >= 1 (0 or 1 means air), got {index:g}",
                              surface=i, field="material")
        else:
            material = Material.from_abbe(index, None)
        if is_stop:
            stop_rows.append(i)
        surfaces.append(Surface(radius_mm=math.inf if is_stop else radius,
                                thickness_mm=thickness, material=material,
                                semi_diameter_mm=diameter / 2.0, stop=is_stop))
    if not stop_rows:
        raise where.error("no aperture stop: pbrt marks it with a row of radius 0",
                          field="stop")
    if not surfaces[-1].material.is_air:
        raise where.error("the last row must be followed by air (index 0 or 1)",
                          surface=len(surfaces) - 1, field="material")
    for i, s in enumerate(surfaces[:-1]):
        if not s.thickness_mm > 0.0:
            raise where.error(f"thickness must be > 0 mm (the axial distance to the next row), "
                              f"got {s.thickness_mm:g}", surface=i, field="thickness")

    heights, nu = _paraxial_marginal(surfaces)
    if not (math.isfinite(nu) and nu < 0.0):
        kind = "afocal" if nu == 0.0 else "diverging (negative focal length)"
        raise where.error(f"the lens is {kind} at n_d: it forms no real image of a distant "
                          "object", field="radius")
    efl = -1.0 / nu
    bfd = -heights[-1] / nu
    if not (math.isfinite(bfd) and bfd > 0.0):
        raise where.error(f"the paraxial image lies {-bfd:g} mm inside the last surface "
                          "(back focal distance <= 0)", surface=len(surfaces) - 1,
                          field="thickness")
    # The aperture stop is the radius-0 row that limits the axial bundle; any other radius-0
    # rows stay flat clipping apertures without stop = true.
    ratios = [surfaces[i].semi_diameter_mm / abs(heights[i]) if heights[i] != 0.0 else math.inf
              for i in stop_rows]
    stop = stop_rows[int(np.argmin(ratios))]
    if not math.isfinite(ratios[stop_rows.index(stop)]):
        raise where.error("the axial marginal ray crosses the stop at height 0", surface=stop,
                          field="radius")
    entrance_pupil_radius = ratios[stop_rows.index(stop)]
    f_number = efl / (2.0 * entrance_pupil_radius)
    surfaces = [Surface(s.radius_mm, s.thickness_mm, s.material, s.semi_diameter_mm,
                        stop=(i == stop)) for i, s in enumerate(surfaces)]
    file_last = surfaces[-1].thickness_mm
    last = surfaces[-1]
    surfaces[-1] = Surface(last.radius_mm, bfd, last.material, last.semi_diameter_mm,
                           stop=last.stop)

    file_name = Path(path).name if path is not None else "<text>"
    lens_name = Path(path).stem if path is not None else "pbrt lens"
    notes = [f"Imported from the pbrt RealisticCamera lens file {file_name}.",
             "pbrt gives one refractive index per medium and no dispersion: materials are "
             "index-only (n_d, no V_d), so there is no chromatic aberration.",
             f"Last thickness set to the paraxial back focal distance {bfd:.6g} mm (the file's "
             f"{file_last:g} is pbrt's focus placeholder); focal length {efl:.6g} mm and "
             f"f-number {f_number:.4g} (= efl / entrance-pupil diameter, object at infinity) "
             "from a paraxial marginal-ray trace at n_d."]
    if len(stop_rows) > 1:
        notes.append(f"Several radius-0 rows (lines {', '.join(str(lines[i]) for i in stop_rows)}"
                     f"); the one on line {lines[stop]} limits the axial beam and is the stop.")
    if comments:
        notes.append("File comments: " + " | ".join(comments))
    lens = Lens(name=lens_name, source=f"pbrt .dat file {file_name}", focal_length_mm=efl,
                f_number=f_number, surfaces=tuple(surfaces), field_of_view_deg=None,
                notes=" ".join(notes), path=None if path is None else str(path))
    _validate(lens, where)
    return lens
