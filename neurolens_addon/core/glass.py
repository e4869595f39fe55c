"""Glass dispersion: refractive index as a function of wavelength.

Two models, one interface (`.index(wavelength_nm) -> float64 ndarray`, same shape as the input):

1. **Catalog glass** (`Glass`), from the manufacturer's published coefficients (shipped in
   ``data/glass_catalog.toml``; see ``docs/glass-catalog.md``), normally Sellmeier's law

       n(L)^2 = 1 + sum_{i=1..3} B_i L^2 / (L^2 - C_i),     L = wavelength in micrometres,

   with C_i in um^2, the convention of the Schott, Ohara and CDGM catalogues. Where a maker
   publishes the Schott power series instead (HOYA, a few CDGM glasses) that is used as is:

       n(L)^2 = A0 + A1 L^2 + A2 L^-2 + A3 L^-4 + A4 L^-6 + A5 L^-8.

2. **(n_d, V_d) model** (`AbbeGlass`), for prescriptions that give only the index and the Abbe
   number (patents usually do). A one-resonance dispersion law (L in micrometres)

       n(L) = A + B / (L^2 - L0^2)

   whose three parameters satisfy, exactly, the three conditions

       n(587.5618 nm) = n_d                                   (d line, helium)
       n_F - n_C      = (n_d - 1) / V_d                       (F 486.1327 nm, C 656.2725 nm)
       n_g - n_F      = P_gF (n_F - n_C),  P_gF = 0.6438 - 0.001682 V_d   (g 435.8343 nm)

   (L0^2 in closed form from the P_gF ratio, then B and A), i.e. n_d and V_d are reproduced
   exactly and the curvature follows Schott's "normal line" of partial dispersion. For glass-like
   V_d, L0^2 < 0.04 um^2 (a resonance deep in the ultraviolet; negative, i.e. no real pole, for
   fluor crowns), so n decreases monotonically and convexly through the visible like a real
   glass. Glasses off the normal line (dense flints,
   fluor crowns, KzFS: |dP_gF| up to ~0.03) differ by up to ~2e-3 at 400 nm; across the shipped
   catalog the model stays within 2.3e-3 of the real glass over 400-700 nm (typically 5e-4).
   If the pole would fall at or above 300 nm (only for V_d far outside glass values) the
   3-term Cauchy law n = A + B/L^2 + C/L^4 through the same three conditions is used.
   With ``vd=None`` the material is non-dispersive: n = n_d at every wavelength.

Air is the reference medium: lens data (and catalog indices) are relative to air, so air has
index exactly 1.0.

Wavelength handling (the ray tracer passes whole arrays, possibly with bad entries): a
wavelength that is not finite or not positive gives NaN for every medium (air included), never
an exception; the caller flags those rays. Finite positive wavelengths outside a glass's
``wavelength_range_nm`` are extrapolated with the same formula (and may give NaN inside an
absorption pole of the Sellmeier law, far outside the visible).

Pure numpy; this module never imports bpy.
"""

from __future__ import annotations

import difflib
import math
import re
import threading
import tomllib
from functools import lru_cache
from pathlib import Path
from typing import Iterable

import numpy as np

from .errors import GlassError
from .prescription import WAVELENGTH_D_NM, Material

#: Fraunhofer / spectral lines used by the (n_d, V_d) model (nm).
WAVELENGTH_F_NM = 486.1327
WAVELENGTH_C_NM = 656.2725
WAVELENGTH_G_NM = 435.8343

#: Schott's normal line of the partial dispersion P_gF = (n_g - n_F) / (n_F - n_C).
NORMAL_LINE_PGF = (0.6438, -0.001682)

#: A catalog entry must reproduce its listed n_d and V_d to these tolerances.
ND_TOLERANCE = 2e-5
VD_TOLERANCE = 0.1

DEFAULT_CATALOG_PATH = Path(__file__).resolve().parent / "data" / "glass_catalog.toml"

_KNOWN_MANUFACTURERS = ("schott", "ohara", "hoya", "cdgm", "sumita", "hikari")


def _as_wavelengths(wavelength_nm) -> np.ndarray:
    """float64 view of the wavelengths, at least 1-D (ufuncs with out= need real arrays)."""
    w = np.asarray(wavelength_nm, dtype=np.float64)
    return w.reshape(1) if w.ndim == 0 else w


#: Scratch arrays up to this many elements are kept per thread and reused between calls (a fresh
#: multi-megabyte temporary costs more in page faults than the arithmetic done in it).
_SCRATCH_MAX = 1 << 22
_tls = threading.local()


def _scratch(shape: tuple[int, ...], k: int) -> list[np.ndarray]:
    """k float64 work arrays of `shape`, reused per thread (fresh ones for huge inputs)."""
    size = math.prod(shape)
    if size > _SCRATCH_MAX:
        return [np.empty(shape) for _ in range(k)]
    bufs = getattr(_tls, "bufs", None)
    if bufs is None or len(bufs) < k or bufs[0].size < size:
        cap = max(size, 1024, 0 if bufs is None else bufs[0].size)
        bufs = [np.empty(cap) for _ in range(max(k, 0 if bufs is None else len(bufs)))]
        _tls.bufs = bufs
    return [b[:size].reshape(shape) for b in bufs[:k]]


def _output(out: np.ndarray | None, w: np.ndarray) -> np.ndarray:
    """The caller's `out` array (checked), or a fresh float64 array shaped like `w`."""
    if out is None:
        return np.empty(w.shape)
    if not isinstance(out, np.ndarray) or out.dtype != np.float64 or (
            out.shape != w.shape and not (out.ndim == 0 and w.shape == (1,))):
        raise ValueError(f"out must be a float64 array of shape {w.shape}, got "
                         f"{getattr(out, 'dtype', type(out).__name__)} "
                         f"{getattr(out, 'shape', '')}")
    if np.may_share_memory(out, w):
        raise ValueError("out must not share memory with the wavelength array")
    return out.reshape(w.shape)


def _shaped(n: np.ndarray, wavelength_nm) -> np.ndarray:
    """Give a scalar input its 0-d result back."""
    return n.reshape(()) if np.ndim(wavelength_nm) == 0 else n


def _nan_bad(n: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Set NaN where the wavelength is not finite or not positive (in place; returns n)."""
    if w.size == 0:
        return n
    lo, hi = w.min(), w.max()          # reductions: no temporaries; NaN propagates into both
    if lo > 0.0 and hi < math.inf:     # the usual case: all valid
        return n
    bad = ~(w > 0.0)                   # NaN, -inf, 0 and negatives
    bad |= np.isinf(w)
    n[bad] = np.nan
    return n


class _Medium:
    """Common interface: name, manufacturer, nd, vd, source, wavelength_range_nm, index()."""

    name: str
    manufacturer: str
    nd: float
    vd: float | None
    source: str
    wavelength_range_nm: tuple[float, float]

    def index(self, wavelength_nm, out: np.ndarray | None = None
              ) -> np.ndarray:  # pragma: no cover - abstract
        """Refractive index at `wavelength_nm` (any shape; float64 result of the same shape).

        `out`, if given, is a float64 array of that shape that receives the result.
        NaN where the wavelength is not finite or not positive.
        """
        raise NotImplementedError

    def __call__(self, wavelength_nm, out: np.ndarray | None = None) -> np.ndarray:
        return self.index(wavelength_nm, out)

    def abbe_from_index(self) -> tuple[float, float]:
        """(n_d, V_d) computed from this medium's own dispersion law."""
        n = self.index(np.array([WAVELENGTH_D_NM, WAVELENGTH_F_NM, WAVELENGTH_C_NM]))
        nd, nf, nc = (float(v) for v in n)
        vd = math.inf if nf == nc else (nd - 1.0) / (nf - nc)
        return nd, vd

    def __repr__(self) -> str:
        vd = "None" if self.vd is None else f"{self.vd:.2f}"
        return f"{type(self).__name__}({self.name!r}, nd={self.nd:.5f}, vd={vd})"


class Glass(_Medium):
    """A catalog glass: the manufacturer's dispersion formula and coefficients.

    `formula` is "sellmeier" (default; `B`, `C` with C in um^2):
        n^2 = 1 + sum_i B_i L^2 / (L^2 - C_i)
    or "schott" (the power series some catalogues, e.g. HOYA's, publish instead; `A` = A0..A5):
        n^2 = A0 + A1 L^2 + A2 L^-2 + A3 L^-4 + A4 L^-6 + A5 L^-8
    with L the wavelength in micrometres.
    """

    def __init__(self, name: str, manufacturer: str, B: Iterable[float] | None = None,
                 C: Iterable[float] | None = None, *, A: Iterable[float] | None = None,
                 formula: str = "sellmeier", nd: float | None = None,
                 vd: float | None = None, source: str = "",
                 wavelength_range_nm: tuple[float, float] = (380.0, 780.0)):
        self.name = str(name)
        self.manufacturer = str(manufacturer)
        self.formula = str(formula).lower()
        if self.formula == "sellmeier":
            if B is None or C is None:
                raise GlassError(f"glass '{name}': the Sellmeier formula needs B and C")
            self.B = tuple(float(b) for b in B)
            self.C = tuple(float(c) for c in C)
            if len(self.B) != len(self.C) or not self.B:
                raise GlassError(f"glass '{name}': Sellmeier needs as many B as C coefficients "
                                 f"(got {len(self.B)} B and {len(self.C)} C)")
            self.A = ()
            self._n2_offset = 1.0 + sum(self.B)
            self._poles = tuple((c, b * c) for b, c in zip(self.B, self.C))
        elif self.formula == "schott":
            if A is None:
                raise GlassError(f"glass '{name}': the Schott formula needs A0..A5")
            self.A = tuple(float(a) for a in A)
            if len(self.A) != 6:
                raise GlassError(f"glass '{name}': the Schott formula needs 6 coefficients "
                                 f"A0..A5, got {len(self.A)}")
            self.B = self.C = ()
        else:
            raise GlassError(f"glass '{name}': unknown dispersion formula '{formula}' "
                             f"(expected 'sellmeier' or 'schott')")
        self.source = str(source)
        self.note = ""
        lo, hi = wavelength_range_nm
        self.wavelength_range_nm = (float(lo), float(hi))
        # n_d, V_d as listed by the catalogue (the formula's own values when not given)
        cnd, cvd = self.abbe_from_index()
        self.nd = float(nd) if nd is not None else cnd
        self.vd = float(vd) if vd is not None else cvd

    def index(self, wavelength_nm, out: np.ndarray | None = None) -> np.ndarray:
        w = _as_wavelengths(wavelength_nm)
        n2 = _output(out, w)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            if self.formula == "sellmeier":
                L2, t = _scratch(w.shape, 2)
                np.multiply(w, w, out=L2)
                L2 *= 1e-6                       # nm^2 -> um^2
                # B L^2 / (L^2 - C) = B + B C / (L^2 - C): one pass fewer per term
                n2.fill(self._n2_offset)
                for c, bc in self._poles:
                    np.subtract(L2, c, out=t)
                    np.divide(bc, t, out=t)
                    n2 += t
            else:
                a0, a1, a2, a3, a4, a5 = self.A
                L2, inv = _scratch(w.shape, 2)
                np.multiply(w, w, out=L2)
                L2 *= 1e-6
                np.reciprocal(L2, out=inv)
                np.multiply(inv, a5, out=n2)     # Horner in 1/L^2
                for a in (a4, a3, a2):
                    n2 += a
                    n2 *= inv
                L2 *= a1
                n2 += L2
                n2 += a0
            np.sqrt(n2, out=n2)
        return _shaped(_nan_bad(n2, w), wavelength_nm)


class AbbeGlass(_Medium):
    """A glass known only by (n_d, V_d): see the module docstring for the model."""

    def __init__(self, nd: float, vd: float | None, name: str | None = None, *,
                 manufacturer: str = "(n_d, V_d) model", source: str = "",
                 wavelength_range_nm: tuple[float, float] = (380.0, 780.0)):
        nd = float(nd)
        if not math.isfinite(nd) or nd < 1.0:
            raise GlassError(f"glass '{name or nd}': n_d must be a finite number >= 1, got {nd}")
        if vd is not None:
            vd = float(vd)
            if not math.isfinite(vd) or vd <= 0.0:
                raise GlassError(f"glass '{name or nd}': V_d must be a finite number > 0, "
                                 f"got {vd}")
            if nd == 1.0:
                raise GlassError(f"glass '{name or nd}': n_d = 1 cannot have a finite V_d")
        self.nd = nd
        self.vd = vd
        self.name = name if name is not None else (
            f"nd={nd:g}" + (f",vd={vd:g}" if vd is not None else ""))
        self.manufacturer = manufacturer
        self.source = source or ("(n_d, V_d) model: n = A + B / (L^2 - L0^2) through n_d, V_d "
                                 "and Schott's normal line P_gF = 0.6438 - 0.001682 V_d")
        lo, hi = wavelength_range_nm
        self.wavelength_range_nm = (float(lo), float(hi))
        #: "constant" (vd None), "oscillator" (the normal case) or "cauchy" (fallback)
        self.law = "constant"
        self.coefficients = (nd, 0.0, 0.0)
        if vd is not None:
            self.law, self.coefficients = _abbe_law(nd, vd)

    @property
    def partial_dispersion_gF(self) -> float | None:
        if self.vd is None:
            return None
        return NORMAL_LINE_PGF[0] + NORMAL_LINE_PGF[1] * self.vd

    def index(self, wavelength_nm, out: np.ndarray | None = None) -> np.ndarray:
        w = _as_wavelengths(wavelength_nm)
        n = _output(out, w)
        a, b, c = self.coefficients
        if self.law == "constant":
            n.fill(a)
            return _shaped(_nan_bad(n, w), wavelength_nm)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            np.multiply(w, w, out=n)
            n *= 1e-6                         # L^2 in um^2
            if self.law == "oscillator":      # n = a + b / (L^2 - c)
                n -= c
                np.divide(b, n, out=n)
                n += a
            else:                             # n = a + b / L^2 + c / L^4
                (x,) = _scratch(w.shape, 1)
                np.reciprocal(n, out=x)
                np.multiply(x, c, out=n)
                n += b
                n *= x
                n += a
        return _shaped(_nan_bad(n, w), wavelength_nm)


def _abbe_law(nd: float, vd: float) -> tuple[str, tuple[float, float, float]]:
    """Coefficients of the (n_d, V_d) model (see the module docstring).

    With x = L^2 (um^2) and f(x) = 1 / (x - x0), the conditions on n_F - n_C and n_g - n_F fix
    x0 in closed form (their ratio P_gF is a ratio of linear functions of x0), then B and A
    follow. A pole x0 at or above (300 nm)^2 would bend the curve inside the visible: there
    (only for V_d far outside glass values) the 3-term Cauchy law through the same three
    conditions is used instead.
    """
    dFC = (nd - 1.0) / vd
    pgf = NORMAL_LINE_PGF[0] + NORMAL_LINE_PGF[1] * vd
    xd, xf, xc, xg = ((v * 1e-3) ** 2 for v in (WAVELENGTH_D_NM, WAVELENGTH_F_NM,
                                                WAVELENGTH_C_NM, WAVELENGTH_G_NM))
    # (f(g) - f(F)) / (f(F) - f(C)) = (xF - xg)(xC - x0) / ((xC - xF)(xg - x0)) = P_gF
    m, k = xf - xg, xc - xf
    den = m - pgf * k
    if den != 0.0:
        x0 = (m * xc - pgf * k * xg) / den
        if math.isfinite(x0) and x0 < 0.09:
            B = dFC / (1.0 / (xf - x0) - 1.0 / (xc - x0))
            A = nd - B / (xd - x0)
            return "oscillator", (A, B, x0)
    rows = np.array([[1.0, 1.0 / x, 1.0 / (x * x)] for x in (xd, xf, xc, xg)])
    M = np.array([rows[0], rows[1] - rows[2], rows[3] - rows[1]])
    rhs = np.array([nd, dFC, pgf * dFC])
    return "cauchy", tuple(float(v) for v in np.linalg.solve(M, rhs))


class _Air(_Medium):
    """The reference medium: index exactly 1 (NaN only where the wavelength is invalid)."""

    def __init__(self):
        self.name = "air"
        self.manufacturer = ""
        self.nd = 1.0
        self.vd = None
        self.source = "reference medium (lens data are relative to air)"
        self.wavelength_range_nm = (0.0, math.inf)

    def index(self, wavelength_nm, out: np.ndarray | None = None) -> np.ndarray:
        w = _as_wavelengths(wavelength_nm)
        n = _output(out, w)
        n.fill(1.0)
        return _shaped(_nan_bad(n, w), wavelength_nm)


AIR = _Air()


# ---- catalog -----------------------------------------------------------------------------------

def _normalise(name: str) -> str:
    """Upper case, without spaces, hyphens, underscores, dots or slashes."""
    return re.sub(r"[\s\-_./]+", "", str(name)).upper()


def _strip_manufacturer(name: str) -> str:
    """'Schott N-BK7', 'OHARA:S-BSL7', 'N-BK7 (Schott)' -> the bare glass name."""
    s = str(name).strip()
    s = re.sub(r"\s*\((%s)\)\s*$" % "|".join(_KNOWN_MANUFACTURERS), "", s, flags=re.I)
    s = re.sub(r"^(%s)\s*[:\s]\s*" % "|".join(_KNOWN_MANUFACTURERS), "", s, flags=re.I)
    return s


def _unprefixed(name: str) -> str | None:
    """'N-BK7' -> 'BK7', 'S-BSL7' -> 'BSL7', 'H-ZF52' -> 'ZF52', 'E-FD1' -> 'FD1'."""
    m = re.match(r"^([A-Za-z]{1,2})[-\s]+(.+)$", name.strip())
    return m.group(2) if m else None


class GlassCatalog:
    """Glasses by name; lookup ignores case, spaces, hyphens and manufacturer prefixes."""

    def __init__(self, glasses: Iterable[Glass] = (), path: str | None = None):
        self.path = path
        self._glasses: dict[str, Glass] = {}          # normalised full name -> glass
        self._aliases: dict[str, list[str]] = {}      # normalised bare name -> full keys
        for g in glasses:
            self.add(g)

    def add(self, glass: Glass) -> None:
        key = _normalise(glass.name)
        if key in self._glasses:
            raise GlassError(f"{self.path or 'glass catalog'}: glass '{glass.name}' is listed "
                             f"twice")
        self._glasses[key] = glass
        bare = _unprefixed(glass.name)
        if bare:
            self._aliases.setdefault(_normalise(bare), []).append(key)

    def names(self) -> list[str]:
        return [g.name for g in self._glasses.values()]

    def glasses(self) -> list[Glass]:
        return list(self._glasses.values())

    def __len__(self) -> int:
        return len(self._glasses)

    def __iter__(self):
        return iter(self._glasses.values())

    def _find(self, name: str) -> Glass | None:
        """Exact (normalised) name first, then a unique maker-prefixed glass ('BK7' -> N-BK7).

        A name that several prefixed glasses share raises GlassError listing them.
        """
        if not isinstance(name, str):
            return None
        for candidate in (name, _strip_manufacturer(name)):
            key = _normalise(candidate)
            if key in self._glasses:
                return self._glasses[key]
            targets = self._aliases.get(key, [])
            if len(targets) == 1:
                return self._glasses[targets[0]]
            if len(targets) > 1:
                names = ", ".join(f"'{self._glasses[t].name}' ({self._glasses[t].manufacturer})"
                                  for t in targets)
                raise GlassError(f"glass name '{name}' is ambiguous: {names}; give the full "
                                 f"name")
        return None

    def __contains__(self, name) -> bool:
        try:
            return self._find(name) is not None
        except GlassError:              # ambiguous: several glasses answer to it
            return False

    def get(self, name: str) -> Glass:
        glass = self._find(name)
        if glass is not None:
            return glass
        raise GlassError(self._unknown_message(name))

    def _unknown_message(self, name: str) -> str:
        key = _normalise(_strip_manufacturer(name))
        by_key = {k: g.name for k, g in self._glasses.items()}
        by_key.update({k: self._glasses[v[0]].name for k, v in self._aliases.items()
                       if len(v) == 1 and k not in by_key})
        close = difflib.get_close_matches(key, list(by_key), n=5, cutoff=0.6)
        suggestions = list(dict.fromkeys(by_key[k] for k in close))
        where = f" in {self.path}" if self.path else ""
        msg = f"unknown glass '{name}'{where}"
        if suggestions:
            msg += "; did you mean " + ", ".join(f"'{s}'" for s in suggestions) + "?"
        else:
            msg += (f"; the catalog has {len(self)} glasses (GlassCatalog.names()); give n_d and "
                    f"V_d instead if the glass is not listed")
        return msg

    def nearest(self, nd: float, vd: float | None = None) -> Glass:
        """The catalog glass closest in (n_d, V_d / 100) space (n_d only when vd is None).

        Ties (e.g. N-BK7, BSC7, H-K9L all at 1.5168) go to the first glass in catalog order.
        """
        if not self._glasses:
            raise GlassError("glass catalog is empty")
        best, best_d = None, math.inf
        for g in self._glasses.values():
            d = (g.nd - nd) ** 2
            if vd is not None:
                d += ((g.vd - vd) / 100.0) ** 2
            if d < best_d:
                best, best_d = g, d
        return best

    def __repr__(self) -> str:
        return f"GlassCatalog({len(self)} glasses, path={self.path!r})"


_ENTRY_KEYS = frozenset({"name", "manufacturer", "formula", "B1", "B2", "B3", "C1", "C2", "C3",
                         "A0", "A1", "A2", "A3", "A4", "A5", "nd", "vd", "wavelength_range_nm",
                         "source", "note"})


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
    """Read a TOML glass catalog (format: docs/glass-catalog.md).

    With `check`, each glass must reproduce its listed n_d to ND_TOLERANCE and V_d to
    VD_TOLERANCE (catches typing errors in coefficients). Any problem raises GlassError naming
    the file and the entry.
    """
    path = Path(path) if path is not None else DEFAULT_CATALOG_PATH
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except OSError as exc:
        raise GlassError(f"{path}: cannot read glass catalog: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise GlassError(f"{path}: glass catalog is not valid TOML: {exc}") from exc
    entries = data.get("glass")
    if not isinstance(entries, list) or not entries:
        raise GlassError(f"{path}: glass catalog needs at least one [[glass]] table")
    catalog = GlassCatalog(path=str(path))
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
    """The shipped catalog (data/glass_catalog.toml), loaded once."""
    return load_catalog(DEFAULT_CATALOG_PATH)


# ---- media of a prescription ---------------------------------------------------------------

def resolve_medium(material: Material, catalog: GlassCatalog | None = None) -> _Medium:
    """The dispersion law of a prescription medium, resolved once: an object with .index(wl).

    air -> index exactly 1; a catalog name (material.nd is None) -> that catalog glass;
    (n_d, V_d) -> AbbeGlass (non-dispersive when V_d is None), even if the name is also a catalog
    name: given numbers win. An unknown name raises GlassError. The returned objects are shared
    (catalog glasses, AIR, cached AbbeGlass): call .index(), never mutate them.
    """
    if material.is_air:
        return AIR
    if material.nd is None:
        cat = catalog if catalog is not None else default_catalog()
        return cat.get(material.name)
    key = (material.nd, material.vd, material.name)
    medium = _ABBE_CACHE.get(key)
    if medium is None:
        medium = AbbeGlass(material.nd, material.vd, name=material.name)
        if len(_ABBE_CACHE) < 4096:
            _ABBE_CACHE[key] = medium
    return medium


_ABBE_CACHE: dict = {}


def medium_index(material: Material, wavelength_nm, catalog: GlassCatalog | None = None
                 ) -> np.ndarray:
    """Refractive index (relative to air) of a prescription medium at the given wavelengths."""
    return resolve_medium(material, catalog).index(wavelength_nm)


__all__ = [
    "AIR", "AbbeGlass", "DEFAULT_CATALOG_PATH", "Glass", "GlassCatalog", "ND_TOLERANCE",
    "VD_TOLERANCE", "WAVELENGTH_C_NM", "WAVELENGTH_F_NM", "WAVELENGTH_G_NM", "default_catalog",
    "load_catalog", "medium_index", "resolve_medium",
]
