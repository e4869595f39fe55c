"""A glass catalog (`GlassCatalog`): glasses by name, and the nearest glass to (n_d, V_d).

Lookup ignores case, spaces, hyphens, underscores, dots and slashes, and a manufacturer given
before or after the name ("Schott N-BK7", "OHARA:S-BSL7", "N-BK7 (Schott)"); a name without
its maker's prefix ("BK7") finds the one prefixed glass that has it ("N-BK7"), and a name
several prefixed glasses share is refused as ambiguous. `nearest` minimises
    (n_d - n_d')^2 + ((V_d - V_d') / 100)^2.
"""

from __future__ import annotations

import difflib
import math
import re
from typing import Iterable

from ..errors import GlassError
from .formulas import Glass

_KNOWN_MANUFACTURERS = ("schott", "ohara", "hoya", "cdgm", "sumita", "hikari")


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
