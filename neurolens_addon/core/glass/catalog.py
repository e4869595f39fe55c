"""A glass catalog (`GlassCatalog`): glasses by name, and the nearest glass to (n_d, V_d).

Lookup ignores case, spaces, hyphens, underscores, dots and slashes, and a manufacturer given
before or after the name ("Schott N-BK7", "OHARA:S-BSL7", "N-BK7 (Schott)"); a name without
its maker's prefix ("BK7") finds the one prefixed glass that has it ("N-BK7"), or among
several the one of a successor series (SUCCESSOR_PREFIXES: N-BK7 rather than the moulding
glass P-BK7), and a name several such glasses share is refused as ambiguous. Two makers may list the same name
(Schott's and CDGM's F2, the same glass type): the bare name finds the first maker of
MAKER_PRECEDENCE, the maker's name picks another ("CDGM F2"). `nearest` minimises
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
#: the prefixes of makers' lead- and arsenic-free successor series (Schott N-, Ohara S-,
#: CDGM H-, HOYA E-): a legacy name finds its successor among other prefixed variants
#: (BK7 -> N-BK7, not the moulding glass P-BK7)
SUCCESSOR_PREFIXES = ("N-", "S-", "H-", "E-")
#: which maker's glass a bare name shared by several makers finds
MAKER_PRECEDENCE = _KNOWN_MANUFACTURERS


def _rank(glass) -> int:
    maker = str(glass.manufacturer).lower()
    return MAKER_PRECEDENCE.index(maker) if maker in MAKER_PRECEDENCE else len(MAKER_PRECEDENCE)


def _normalise(name: str) -> str:
    """Upper case, without spaces, hyphens, underscores, dots or slashes."""
    return re.sub(r"[\s\-_./]+", "", str(name)).upper()


def _manufacturer_of(name: str) -> str | None:
    """The maker a name gives ('Schott N-BK7', 'N-BK7 (Schott)'), lower case, or None."""
    s = str(name).strip()
    makers = "|".join(_KNOWN_MANUFACTURERS)
    m = re.match(r"^(%s)\s*[:\s]" % makers, s, flags=re.I) or \
        re.search(r"\((%s)\)\s*$" % makers, s, flags=re.I)
    return m.group(1).lower() if m else None


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
        self._aliases: dict[str, list[Glass]] = {}    # normalised bare name -> glasses
        self._by_maker: dict[tuple, Glass] = {}      # (maker, normalised name) -> glass
        for g in glasses:
            self.add(g)

    def add(self, glass: Glass) -> None:
        key = _normalise(glass.name)
        maker = str(glass.manufacturer).lower()
        if (maker, key) in self._by_maker:
            raise GlassError(f"{self.path or 'glass catalog'}: glass '{glass.name}' is listed "
                             f"twice")
        self._by_maker[(maker, key)] = glass
        bare = _unprefixed(glass.name)
        if bare:
            self._aliases.setdefault(_normalise(bare), []).append(glass)
        held = self._glasses.get(key)
        if held is None or _rank(glass) < _rank(held):
            # another maker's glass of the same name: the bare name finds the preferred maker's
            self._glasses[key] = glass

    def names(self) -> list[str]:
        return [g.name for g in self._by_maker.values()]

    def glasses(self) -> list[Glass]:
        return list(self._by_maker.values())

    def __len__(self) -> int:
        return len(self._by_maker)

    def __iter__(self):
        return iter(self._by_maker.values())

    def _find(self, name: str) -> Glass | None:
        """Exact (normalised) name first, then a unique maker-prefixed glass ('BK7' -> N-BK7).

        A name that several prefixed glasses share raises GlassError listing them.
        """
        if not isinstance(name, str):
            return None
        maker = _manufacturer_of(name)
        if maker is not None:
            # a maker named is a maker meant: its glass, or its one prefixed glass, or none
            bare = _normalise(_strip_manufacturer(name))
            hit = self._by_maker.get((maker, bare))
            if hit is not None:
                return hit
            own = [t for t in self._aliases.get(bare, []) if t.manufacturer.lower() == maker]
            successors = [t for t in own if t.name.upper().startswith(SUCCESSOR_PREFIXES)]
            own = successors if len(own) > 1 and len(successors) == 1 else own
            return own[0] if len(own) == 1 else None
        for candidate in (name, _strip_manufacturer(name)):
            key = _normalise(candidate)
            if key in self._glasses:
                return self._glasses[key]
            # one glass per full name (the preferred maker's, as for a bare full name)
            targets = [t for t in self._aliases.get(key, [])
                       if self._glasses.get(_normalise(t.name)) is t]
            successors = [t for t in targets if t.name.upper().startswith(SUCCESSOR_PREFIXES)]
            if len(targets) > 1 and len(successors) == 1:
                targets = successors
            if len(targets) == 1:
                return targets[0]
            if len(targets) > 1:
                names = ", ".join(f"'{t.name}' ({t.manufacturer})" for t in targets)
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

    def canonical_name(self, glass: Glass) -> str:
        """The name that finds `glass` here: its own, or with its maker before it where another
        maker's glass answers to the bare name (CDGM's F2: 'CDGM F2')."""
        if self._find(glass.name) is glass:
            return glass.name
        qualified = f"{glass.manufacturer} {glass.name}"
        return qualified if self._find(qualified) is glass else glass.name

    def _unknown_message(self, name: str) -> str:
        key = _normalise(_strip_manufacturer(name))
        by_key = {k: g.name for k, g in self._glasses.items()}
        by_key.update({k: v[0].name for k, v in self._aliases.items()
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
        if not self._by_maker:
            raise GlassError("glass catalog is empty")
        best, best_d = None, math.inf
        for g in self._by_maker.values():
            d = (g.nd - nd) ** 2
            if vd is not None:
                d += ((g.vd - vd) / 100.0) ** 2
            if d < best_d:
                best, best_d = g, d
        return best

    def __repr__(self) -> str:
        return f"GlassCatalog({len(self)} glasses, path={self.path!r})"
