"""Reading a glass catalog file (TOML, docs/glass-catalog.md), and the shipped catalog.

Each [[glass]] entry names its glass, manufacturer, formula ("sellmeier": B1..B3, C1..C3;
"schott": A0..A5), listed n_d and V_d, source, optional wavelength range and note. With
`check`, the formula must reproduce the listed values: |n_d - n_d(formula)| <= ND_TOLERANCE and
|V_d - V_d(formula)| <= VD_TOLERANCE (catches typing errors in coefficients). Every problem
raises GlassError naming the file and the entry.
"""

from __future__ import annotations

import math
import tomllib
from functools import lru_cache
from pathlib import Path

from ..errors import GlassError
from .catalog import GlassCatalog
from .formulas import Glass

#: A catalog entry must reproduce its listed n_d and V_d to these tolerances.
ND_TOLERANCE = 2e-5
VD_TOLERANCE = 0.1

#: the shipped catalogue: a folder of TOML files, one per maker (data/glass/*.toml)
DEFAULT_CATALOG_PATH = Path(__file__).resolve().parents[1] / "data" / "glass"


_ENTRY_KEYS = frozenset({"name", "manufacturer", "formula", "B1", "B2", "B3", "C1", "C2", "C3",
                         "A0", "A1", "A2", "A3", "A4", "A5", "nd", "vd", "wavelength_range_nm",
                         "source", "note"})


#: glass catalogs larger than this are refused before parsing
MAX_CATALOG_BYTES = 16 << 20


def _entry_error(path, i, name, message) -> GlassError:
    label = f"entry {i + 1}" + (f" ('{name}')" if name else "")
    return GlassError(f"{path}: glass catalog {label}: {message}")


def _number(entry, key, path, i, name, *, required=True):
    if key not in entry:
        if required:
            raise _entry_error(path, i, name, f"missing field '{key}'")
        return None
    v = entry[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise _entry_error(path, i, name, f"field '{key}' must be a finite number, got {v!r}")
    return float(v)


def load_catalog(path=None, *, check: bool = True) -> GlassCatalog:
    """Read a TOML glass catalog (format: docs/glass-catalog.md), or every `*.toml` file of a
    folder into one catalogue (the shipped one: a file per maker).

    With `check`, each glass must reproduce its listed n_d to ND_TOLERANCE and V_d to
    VD_TOLERANCE (catches typing errors in coefficients). Any problem raises GlassError naming
    the file and the entry.
    """
    path = Path(path) if path is not None else DEFAULT_CATALOG_PATH
    if path.is_dir():
        files = sorted(path.glob("*.toml"))
        if not files:
            raise GlassError(f"{path}: no glass catalog files (*.toml) in the folder")
        catalog = GlassCatalog(path=str(path))
        for f in files:
            _load_file(f, check, catalog)
        return catalog
    return _load_file(path, check, GlassCatalog(path=str(path)))


def _load_file(path: Path, check: bool, catalog: GlassCatalog) -> GlassCatalog:
    """Add the glasses of one catalog file to `catalog`."""
    from ..safe_io import UnreadableFile, read_regular
    try:
        data = tomllib.loads(read_regular(path, MAX_CATALOG_BYTES, "glass catalog")
                             .decode("utf-8"))
    except (UnreadableFile, UnicodeDecodeError) as exc:
        raise GlassError(f"{path}: cannot read glass catalog: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise GlassError(f"{path}: glass catalog is not valid TOML: {exc}") from exc
    entries = data.get("glass")
    if not isinstance(entries, list) or not entries:
        raise GlassError(f"{path}: glass catalog needs at least one [[glass]] table")
    for i, e in enumerate(entries):
        if not isinstance(e, dict):
            raise _entry_error(path, i, None, "must be a table")
        name = e.get("name")
        if not isinstance(name, str) or not name.strip():
            raise _entry_error(path, i, None, "missing or empty field 'name'")
        manufacturer = e.get("manufacturer", "")
        if not isinstance(manufacturer, str):
            raise _entry_error(path, i, name, "field 'manufacturer' must be a string")
        source = e.get("source")
        if not isinstance(source, str) or not source.strip():
            raise _entry_error(path, i, name, "missing field 'source' (where the coefficients "
                                              "come from)")
        unknown = sorted(set(e) - _ENTRY_KEYS)
        if unknown:
            raise _entry_error(path, i, name, "unknown field(s) " + ", ".join(map(repr, unknown))
                               + "; allowed: " + ", ".join(sorted(_ENTRY_KEYS)))
        formula = e.get("formula", "sellmeier")
        if formula not in ("sellmeier", "schott"):
            raise _entry_error(path, i, name, f"field 'formula' must be 'sellmeier' or 'schott', "
                                              f"got {formula!r}")
        if formula == "sellmeier":
            B = [_number(e, f"B{k}", path, i, name) for k in (1, 2, 3)]
            C = [_number(e, f"C{k}", path, i, name) for k in (1, 2, 3)]
            A = None
        else:
            A = [_number(e, f"A{k}", path, i, name) for k in range(6)]
            B = C = None
        nd = _number(e, "nd", path, i, name)
        vd = _number(e, "vd", path, i, name)
        rng = e.get("wavelength_range_nm", [380.0, 780.0])
        if (not isinstance(rng, list) or len(rng) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in rng)
                or not 0 < rng[0] < rng[1]):
            raise _entry_error(path, i, name, "field 'wavelength_range_nm' must be "
                                              f"[min, max] with 0 < min < max, got {rng!r}")
        try:
            glass = Glass(name, manufacturer, B, C, A=A, formula=formula, nd=nd, vd=vd,
                          source=source, wavelength_range_nm=(rng[0], rng[1]))
        except GlassError as exc:
            raise _entry_error(path, i, name, str(exc)) from exc
        note = e.get("note", "")
        if not isinstance(note, str):
            raise _entry_error(path, i, name, "field 'note' must be a string")
        glass.note = note
        if check:
            cnd, cvd = glass.abbe_from_index()
            if not (abs(cnd - nd) <= ND_TOLERANCE and abs(cvd - vd) <= VD_TOLERANCE):
                raise _entry_error(
                    path, i, name,
                    f"the {formula} coefficients give n_d = {cnd:.6f}, V_d = {cvd:.3f} but the "
                    f"entry lists n_d = {nd}, V_d = {vd} (tolerance {ND_TOLERANCE:g}, "
                    f"{VD_TOLERANCE:g}); check the coefficients")
        try:
            catalog.add(glass)
        except GlassError as exc:
            raise _entry_error(path, i, name, str(exc)) from exc
    return catalog


@lru_cache(maxsize=1)
def default_catalog() -> GlassCatalog:
    """The shipped catalog (data/glass/*.toml, a file per maker), loaded once."""
    return load_catalog(DEFAULT_CATALOG_PATH)
